"""The information a design gives: Fisher information and the power of score tests.

A design is the set of load cases of an ``ExtendedProblem``; ``base`` is a fit of its
base parameters x at the point where the design is judged (the current estimate, or
the truth of a phantom, on noise-free data). With the whitened residual rho = W r,
covariance sigma^2 I under pure noise (``solvers.inverse.noise``), and its exact Jacobian
J = d rho / dp (implicit function theorem through the equilibrium, one sparse LU per
load case: ``EffectFit.jacobian``; no finite differences):

- **Fisher information** of the estimated base parameters, natural units,

      F = J_x^T J_x / sigma^2,      cov(x_hat) ~ F^-1                              (D1)

  (the covariance the nested inverse reports, ``EffectFit.standard_errors``).
- **Non-centrality** of the score test of an effect with parameters theta at
  theta = 0 (``solvers.diagnosis.stats.score_test``) when the truth has theta_1:
  with A = (I - P_x) J_theta (P_x the projection onto J_x's columns: x refitted) and
  P_A the projection onto A's columns,

      lambda = |P_A (rho(x, theta_1) - rho(x, 0))|^2 / sigma^2,                    (D2)

  the noise-free score statistic: the test statistic is noncentral chi^2 with rank A
  degrees of freedom and non-centrality lambda. The effect's signal is solved
  exactly (one equilibrium at theta_1 per case), not linearised as J_theta theta_1:
  for base_compliance on the diagnosis design, J_theta theta_1 overstates lambda
  4-fold at 12.6 mm^3/N (5.39 against 1.36), while (D2) equals the noise-free score
  statistic to 4 digits (tests/test_design.py).
- **Power** at level a: P(chi^2_{d}(lambda) > c_a) with c_a the (1 - a) quantile of
  chi^2_d; an effect bounded below by 0 (one parameter) is tested one-sided, so
  c_a is the (1 - 2a) quantile and the sign must be right (the chi-bar-squared
  of the score test): P(Z + sqrt(lambda) > sqrt(c_a)), Z standard normal.       (D3)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.diagnosis.fit import EffectFit
from solvers.diagnosis.stats import (
    CONFOUNDED,
    candidate_jacobian,
    power,
)
from symbolic.effects.base import Effect


@dataclass(frozen=True)
class EffectPower:
    """The predicted power of one effect's score test (eq. D2, D3).

    Attributes
    ----------
    name : str
    magnitude : float
        The effect's magnitude (``Effect.default_magnitude`` units; |theta| for an
        effect given by its parameters).
    noncentrality : float
        lambda of eq. (D2) [1].
    dof : int
        rank A: the test's degrees of freedom.
    level : float
        Significance level a.
    one_sided : bool
    power : float
        Probability that the test rejects theta = 0 at level a.
    distinct : float
        |A theta_1| / |J_theta theta_1|: the part of the effect's signal that no refit of
        the base parameters absorbs (0: confounded with them).
    """

    name: str
    magnitude: float
    noncentrality: float
    dof: int
    level: float
    one_sided: bool
    power: float
    distinct: float


def fisher_information(base: EffectFit, sigma: float) -> tuple[list[str], np.ndarray]:
    """F of eq. (D1) over the estimated entries of ``base`` (natural units), and their labels."""
    chosen = base.estimated()
    sub = base.jacobian[:, chosen]
    labels = [label for label, keep in zip(base.problem.labels, chosen) if keep]
    return labels, sub.T @ sub / sigma**2


def effect_power(
    base: EffectFit, effect: Effect, magnitude: float, sigma: float, level: float = 0.01
) -> EffectPower:
    """Eq. (D2), (D3) for ``effect`` at ``magnitude`` on the design of ``base``.

    Costs the effect's columns at theta = 0 (one sparse LU per load case,
    ``candidate_jacobian``) and one equilibrium per case at theta_1; the base parameters
    are projected out as the score test does, so the power is the one after they are
    refitted.
    """
    problem, p, jacobian = candidate_jacobian(base, effect)
    block = problem.slice_of(effect.name)
    theta = np.asarray(effect.true_parameters(magnitude, len(problem.cases)), dtype=float)
    p[block] = theta
    signal = problem.whiten(problem.evaluate(p)[0]) - base.whitened
    nuisance = np.flatnonzero(base.estimated())
    columns = np.column_stack([jacobian[:, nuisance], jacobian[:, block], signal])
    q = theta.size
    projected, dof = projected_signal(
        columns.T @ columns,
        np.arange(nuisance.size),
        np.arange(nuisance.size, nuisance.size + q),
        nuisance.size + q,
        problem.scale[block],
    )
    total = float(signal @ signal)
    return effect_figures(effect, magnitude, projected, total, dof, sigma, level, q)


def effect_figures(
    effect: Effect, magnitude, projected, total, dof, sigma, level, size
) -> EffectPower:
    """The ``EffectPower`` of |P_A s|^2 = ``projected`` and |s|^2 = ``total`` [mm^2], for
    ``size`` parameters theta (one, bounded below by 0: tested one-sided)."""
    lower = np.asarray(effect.lower, dtype=float)
    one_sided = size == 1 and lower[0] == 0.0
    noncentrality = projected / sigma**2
    return EffectPower(
        effect.name,
        float(np.linalg.norm(magnitude)),
        noncentrality,
        dof,
        float(level),
        bool(one_sided),
        power(noncentrality, dof, level, one_sided) if dof else 0.0,
        float(np.sqrt(projected / max(total, 1e-300))),
    )


def scaled_inverse(gram: np.ndarray, index) -> tuple[np.ndarray, np.ndarray]:
    """(d, (D G D)^+) for the block G of ``gram`` on ``index``, D = diag(G)^-1/2: the
    columns scaled to unit norm first (Jacobi), so the pseudo-inverse's cut-off sees
    their angles, not their units. G^+ ~ D (D G D)^+ D."""
    block = gram[np.ix_(index, index)]
    unit = 1.0 / np.sqrt(np.maximum(np.diag(block), 1e-300))
    return unit, np.linalg.pinv(block * np.outer(unit, unit), rcond=1e-12, hermitian=True)


def projected_signal(gram, nuisance, block, signal: int, scale) -> tuple[float, int]:
    """|P_A s|^2 of eq. (D2) [mm^2] and rank A, from the Gram matrix of whitened columns.

    ``gram`` is C^T C with C = [J_x, J_theta, s] (whatever the column order: the index
    arrays say where each sits). A = (I - P_x) J_theta has A^T A the Schur complement
    G_tt - G_tx G_xx^-1 G_xt; its rank is counted on the columns scaled by ``scale``
    (the score test's rule: singular values above ``CONFOUNDED`` times |J_theta S|_2),
    and |P_A s|^2 = b^T (A^T A)^+ b with b = A^T s.
    """
    scale = np.asarray(scale, dtype=float)
    g_tt = gram[np.ix_(block, block)] * np.outer(scale, scale)
    g_ts = gram[block, signal] * scale
    a_ta, a_ts = g_tt, g_ts
    if len(nuisance):
        unit, inverse = scaled_inverse(gram, nuisance)
        g_tx = gram[np.ix_(block, nuisance)] * np.outer(scale, unit)
        g_xs = gram[nuisance, signal] * unit
        a_ta = g_tt - g_tx @ inverse @ g_tx.T
        a_ts = g_ts - g_tx @ inverse @ g_xs
    size = np.sqrt(max(float(np.linalg.eigvalsh(g_tt).max()), 0.0)) if len(block) else 0.0
    values, vectors = np.linalg.eigh(a_ta)
    singular = np.sqrt(np.maximum(values, 0.0))
    keep = singular > CONFOUNDED * max(size, 1e-300)
    coefficients = vectors[:, keep].T @ a_ts / singular[keep]
    return float(coefficients @ coefficients), int(keep.sum())
