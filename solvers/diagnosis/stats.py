"""Tests of the diagnosis: residual against noise, score tests, information criterion.

Notation: rho = W r is the whitened residual of a fit (``solvers.diagnosis.extended``),
with covariance sigma^2 I under pure noise; J = d rho / dp the exact reduced
Jacobian (implicit function theorem through the equilibrium, eq. 22).

- **Residual test.** T = |rho|^2 / sigma^2 ~ chi^2(m - k) when the model is
  right (k estimated parameters not on a bound).
- **Score (Lagrange-multiplier) test** of a candidate effect with parameters phi
  at phi = 0, without refitting: with the nuisance columns J_N (the fitted
  parameters) and the candidate columns J_phi,

      A = (I - P_N) J_phi,          P_N = J_N (J_N^T J_N)^-1 J_N^T,
      T = rho^T A (A^T A)^+ A^T rho / sigma^2 ~ chi^2(rank A).

  A^T A / sigma^2 is the Gauss-Newton information of phi with x profiled out
  (the Schur complement I_pp - I_pn I_nn^-1 I_np), and A^T rho = J_phi^T rho is the
  score, because J_N^T rho = 0 at the fit. T is the squared length of the part
  of the residual that the candidate can explain beyond the fitted parameters.
  A parameter bounded below by 0 makes the test one-sided: T counts only when
  the one-step estimate -(A^T A)^+ A^T rho points into the allowed side, and the
  p-value is 1/2 P(chi^2_1 > T) (chi-bar-squared).
- **Family score** of an effect whose shape is chosen from a family (``stiffer_region``:
  a rectangle of cells): every member's one-sided T from one linearisation with a
  column per cell, the best member chosen, its p-value times the number of members
  (Bonferroni; ``family_score_test``, eq. S1).
- **BIC** = |rho|^2/sigma^2 + k log m (known sigma), k the effective degrees of freedom
  (``EffectFit.effective_dof``: the count of estimated parameters, fewer for an effect
  with a prior such as ``stiffness_field``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special, stats

from solvers.diagnosis.fit import EffectFit
from symbolic.effects.base import Effect

CONFOUNDED = 1e-6
"""A candidate direction shorter than this fraction of itself after projection is confounded."""


@dataclass
class ResidualTest:
    """chi^2 test of a fit's residual against the noise model."""

    statistic: float
    dof: int
    p_value: float

    def significant(self, level: float) -> bool:
        """True when the residual is significantly larger than the noise."""
        return self.p_value < level


@dataclass
class ScoreTest:
    """The score test of one candidate effect at theta = 0.

    Attributes
    ----------
    effect : str
        Candidate name.
    statistic : float
        T (dimensionless).
    dof : int
        Rank of the profiled candidate directions.
    p_value, log_p : float
        P-value and its natural logarithm (for ranking when it underflows).
    step : numpy.ndarray
        One Gauss-Newton step for theta from 0 (natural units): a start for the refit.
    distinct : float
        Smallest singular value of A over the largest of J_phi (0 = fully confounded).
    seconds : float
        Wall time of the test (build + one linearisation).
    note : str
        Why the test could not see the effect, if so.
    information : numpy.ndarray or None
        A^T A / sigma^2 on the test's ``dof`` directions, in theta's natural units: the
        profiled Fisher information, so that theta_1^T I theta_1 is the non-centrality
        of the test against theta_1 (eq. D2, linearised; ``solvers.diagnosis.blind``).
    detail : dict or None
        What a family test chose (``family_score_test``); None for an ordinary test.
    """

    effect: str
    statistic: float
    dof: int
    p_value: float
    log_p: float
    step: np.ndarray
    distinct: float
    seconds: float
    note: str = ""
    information: np.ndarray | None = None
    detail: dict | None = None


def residual_test(fit: EffectFit, sigma: float) -> ResidualTest:
    """T = |rho|^2 / sigma^2 against chi^2(m - k)."""
    dof = max(int(round(fit.whitened.size - fit.effective_dof())), 1)
    statistic = fit.cost / sigma**2
    return ResidualTest(float(statistic), int(dof), float(stats.chi2.sf(statistic, dof)))


def log_chi2_sf(statistic: float, dof: int) -> float:
    """log P(chi^2_dof > statistic), finite even where the p-value underflows.

    scipy's ``chi2.logsf`` returns -inf once the p-value drops below about
    1e-308 (statistics of a few thousand), which would make the strongest
    candidates tie. There the leading terms of the asymptotic series of the
    upper incomplete gamma function are used, with s = dof/2, x = statistic/2:
    log Q(s, x) = (s - 1) log x - x - log Gamma(s) + log(1 + (s - 1)/x + ...).
    """
    value = float(stats.chi2.logsf(statistic, dof))
    return value if np.isfinite(value) else log_chi2_sf_series(statistic, dof)


def log_chi2_sf_series(statistic: float, dof: int) -> float:
    """The asymptotic series of ``log_chi2_sf`` (relative error O((dof/statistic)^3))."""
    s, x = 0.5 * dof, 0.5 * statistic
    series = 1.0 + (s - 1.0) / x + (s - 1.0) * (s - 2.0) / x**2
    return float((s - 1.0) * np.log(x) - x - special.gammaln(s) + np.log(series))


def bic(fit: EffectFit, sigma: float) -> float:
    """Bayesian information criterion with known sigma: chi^2 + k log m."""
    return fit.cost / sigma**2 + fit.effective_dof() * np.log(fit.whitened.size)


def robust_sigma(fit: EffectFit) -> float:
    """1.4826 median |rho|: a noise estimate that tolerates a localised misfit [mm]."""
    return float(1.4826 * np.median(np.abs(fit.whitened)))


def extended_linearisation(
    problem, p, states, state_jacobians, candidate: Effect, candidate_only: bool = False
):
    """``problem`` with ``candidate`` added, linearised at theta = 0 from solved states.

    With ``candidate_only`` the linear path solves for the candidate's columns alone
    and leaves the others zero (at theta = 0 they are the fitted problem's own).

    Costs one sensitivity evaluation per load case and one sparse LU where the
    candidate adds state (its new state starts at 0 and stays there); otherwise the
    cases' own ``state_jacobians`` serve. On the linear path the cases share one
    factorisation and one multi-column solve (``solvers.forward.linearpath``).

    Returns
    -------
    tuple
        The extended problem, p with theta = 0, the states padded to its size, and the
        raw stacked d r / dp (not whitened).
    """
    extended = problem.with_effects(problem.effects + [candidate])
    p = np.concatenate([p, np.zeros(len(extended.labels) - len(p))])
    n_state = extended.extended.n_state
    tail = 3 * problem.model.n_constraints  # the multipliers stay last (after new state)
    padded = [
        np.insert(state, state.size - tail, np.zeros(n_state - state.size)) for state in states
    ]
    same = [n_state == state.size for state in states]
    if extended.linear_state:  # one multi-column solve for every case (the linear path)
        factor = state_jacobians[0] if all(same) else None
        block = extended.slice_of(candidate.name)
        columns = np.arange(block.start, block.stop) if candidate_only else None
        return extended, p, padded, extended.linearise_all(p, padded, factor, columns)[1]
    jacobians = []
    for position, state in enumerate(padded):
        state_jacobian = state_jacobians[position] if same[position] else None
        jacobians.append(extended.linearise(position, p, state, state_jacobian)[1])
    return extended, p, padded, np.vstack(jacobians)


def candidate_jacobian(fit: EffectFit, candidate: Effect):
    """The extended problem, p at phi = 0, and the whitened d rho / dp there.

    The state at phi = 0 is the fitted one (``extended_linearisation``).
    """
    problem, p, _, jacobian = extended_linearisation(
        fit.problem, fit.p, fit.states, fit.state_jacobians, candidate, candidate_only=True
    )
    whitened = problem.whiten(jacobian)
    if problem.linear_state:  # the fitted columns are the fit's own (theta = 0)
        whitened[:, : fit.p.size] = fit.jacobian
    return problem, p, whitened


def score_test(fit: EffectFit, candidate: Effect, sigma: float, family: bool = True) -> ScoreTest:
    """Score test of ``candidate`` at the fit (no refit; see the module docstring).

    An effect with a ``family`` of shapes (``stiffer_region``) is tested over the whole
    family (``family_score_test``), which chooses its member; ``family=False`` tests
    the effect as it stands.
    """
    if family and getattr(candidate, "family", None) is not None:
        return family_score_test(fit, candidate, sigma)
    begin = time.perf_counter()
    problem, p, jacobian = candidate_jacobian(fit, candidate)
    block = problem.slice_of(candidate.name)
    scale = problem.scale[block]
    nuisance = np.flatnonzero(fit.estimated())
    z_scale = problem.natural_derivative(problem.to_internal(p))
    basis = jacobian[:, nuisance] * z_scale[nuisance]
    direction = jacobian[:, block] * scale
    if basis.shape[1]:
        q, _ = np.linalg.qr(basis)
        projected = direction - q @ (q.T @ direction)
    else:
        projected = direction
    size = np.linalg.norm(direction, 2) if direction.size else 0.0
    u, singular, vt = np.linalg.svd(projected, full_matrices=False)
    rank = int(np.sum(singular > CONFOUNDED * max(size, 1e-300)))
    rho = fit.whitened
    note = ""
    if rank == 0:
        step = np.zeros(len(scale))
        statistic, dof, log_p = 0.0, max(len(scale), 1), 0.0
        note = "no influence beyond the fitted parameters (confounded)"
    else:
        coefficients = u[:, :rank].T @ rho
        statistic = float(coefficients @ coefficients) / sigma**2
        step = -(vt[:rank].T @ (coefficients / singular[:rank])) * scale
        dof = rank
        log_p = log_chi2_sf(statistic, dof)
        lower = np.asarray(candidate.lower, dtype=float)
        if len(scale) == 1 and lower[0] == 0.0:
            if step[0] <= 0.0:
                statistic, log_p, note = 0.0, 0.0, "points to theta < 0 (outside its bound)"
            else:
                log_p += np.log(0.5)
    distinct = float(singular[-1] / size) if size > 0 and singular.size else 0.0
    kept = vt[:rank].T * singular[:rank] / scale[:, None]  # A^T A = kept kept^T
    return ScoreTest(
        effect=candidate.name,
        statistic=float(statistic),
        dof=int(dof),
        p_value=float(np.exp(log_p)),
        log_p=float(log_p),
        step=np.asarray(step, dtype=float),
        distinct=distinct,
        seconds=time.perf_counter() - begin,
        note=note,
        information=kept @ kept.T / sigma**2,
    )


def family_columns(fit: EffectFit, candidate: Effect):
    """The cells of ``candidate``'s family at the fit, linearised once.

    Returns
    -------
    tuple
        The ``family`` (grid, boxes, per-cell effect); D, the whitened d rho / d theta_c
        of every cell in natural units, (m, n_cells); and the fitted parameters'
        columns J_N, (m, k) (``candidate_jacobian`` of the per-cell effect: on the
        linear path one multi-column solve).
    """
    family = candidate.family(fit.problem.model)
    problem, p, jacobian = candidate_jacobian(fit, family.cells)
    nuisance = np.flatnonzero(fit.estimated())
    z_scale = problem.natural_derivative(problem.to_internal(p))
    block = problem.slice_of(family.cells.name)
    return family, jacobian[:, block], jacobian[:, nuisance] * z_scale[nuisance]


def family_score_test(fit: EffectFit, candidate: Effect, sigma: float) -> ScoreTest:
    """The one-sided score test of every member of ``candidate``'s family (the rectangles
    of cells of ``stiffer_region``) at once, and the best member chosen in the effect.

    With D the cells' columns (``family_columns``), A = (I - P_N) D and w_b the 0/1
    weight of box b's cells, box b's column is A w_b and

        T_b = (w_b^T A^T rho)^2 / (sigma^2 w_b^T A^T A w_b)                        (S1)

    for every box from the n_cells vector A^T rho and matrix A^T A by cumulative sums
    over the cells (``CellGrid.box_sums``, ``box_forms``). Only boxes whose one-step
    estimate -w_b^T A^T rho / w_b^T A^T A w_b is positive count (s >= 0), and those
    confounded (|A w_b| < CONFOUNDED |D w_b|) are not scored. The best box's log p is
    log(1/2 P(chi^2_1 > T_b)) plus the log of the number of boxes scored (Bonferroni).
    ``detail``: the box (i0, i1, j0, j1), its rectangle (u0, u1, v0, v1), T_b, the boxes
    scored, and the signed statistic of every single cell (n_u, n_v).
    """
    begin = time.perf_counter()
    family, columns, basis = family_columns(fit, candidate)
    projected = columns
    if basis.shape[1]:
        q, _ = np.linalg.qr(basis)
        projected = columns - q @ (q.T @ columns)
    grid, boxes, rho = family.grid, family.boxes, fit.whitened
    gradient, gram = projected.T @ rho, projected.T @ projected
    score = grid.box_sums(gradient, boxes)
    information = grid.box_forms(gram, boxes)
    size = np.sqrt(np.maximum(grid.box_forms(columns.T @ columns, boxes), 0.0))
    length = np.sqrt(np.maximum(information, 0.0))
    scored = length > CONFOUNDED * np.maximum(size, 1e-300)
    safe = np.where(scored, information, 1.0)
    statistic = np.where(scored, score**2 / (sigma**2 * safe), 0.0)
    step = np.where(scored, -score / safe, 0.0)
    single = np.diag(gram)
    cells = np.where(single > 0.0, -np.sign(gradient) * gradient**2 / (sigma**2 * single), 0.0)
    detail = {"n_boxes": int(scored.sum()), "cell_statistic": cells.reshape(grid.shape).tolist()}
    allowed = scored & (step > 0.0)
    candidates = np.where(allowed if allowed.any() else scored, statistic, -1.0)
    best = int(np.argmax(candidates)) if candidates.size else 0
    log_p, information_best, distinct = 0.0, None, 0.0
    if not scored.any():
        note = "no rectangle of cells with influence beyond the fitted parameters (confounded)"
    elif not allowed.any():
        note = "every rectangle points to s < 0 (outside its bound)"
    else:
        note = ""
        log_p = log_chi2_sf(statistic[best], 1) + np.log(0.5) + np.log(detail["n_boxes"])
        log_p = min(float(log_p), 0.0)
    if scored.any():
        box = boxes[best]
        candidate.choose(grid.rect(box))
        information_best = np.array([[information[best] / sigma**2]])
        distinct = float(length[best] / size[best])
        detail.update(
            box=[int(k) for k in box],
            rect_uv=list(grid.rect(box)),
            statistic=float(statistic[best]),
        )
    chosen = bool(allowed.any())
    return ScoreTest(
        effect=candidate.name,
        statistic=float(statistic[best]) if chosen else 0.0,
        dof=1,
        p_value=float(np.exp(log_p)),
        log_p=float(log_p),
        step=np.array([step[best] if chosen else 0.0]),
        distinct=distinct,
        seconds=time.perf_counter() - begin,
        note=note,
        information=information_best,
        detail=detail,
    )


def critical_value(level: float, dof: int, one_sided: bool) -> float:
    """The score test's critical value at ``level``: z for the one-sided test (compared
    with sqrt of the statistic), chi^2_dof otherwise.

    The search scores thousands of designs, so these and the tails below are scipy's
    special functions (ufuncs, about 1 us a call) rather than ``scipy.stats``
    distributions (about 70 us a call for the same numbers).
    """
    return float(-special.ndtri(level)) if one_sided else float(special.chdtri(dof, level))


def power(noncentrality: float, dof: int, level: float, one_sided: bool = False) -> float:
    """Eq. (D3): the probability that the score test rejects at level ``level``."""
    if dof == 0:
        return 0.0
    critical = critical_value(level, dof, one_sided)
    if one_sided:
        return float(special.ndtr(np.sqrt(noncentrality) - critical))
    return float(1.0 - special.chndtr(critical, dof, max(noncentrality, 1e-300)))


def needed_noncentrality(dof: int, level: float, one_sided: bool, goal: float) -> float:
    """The lambda at which the score test reaches power ``goal`` (eq. D3 inverted)."""
    if one_sided:
        return float((critical_value(level, dof, True) + special.ndtri(goal)) ** 2)
    critical = critical_value(level, dof, False)
    return float(
        optimize.brentq(lambda x: 1.0 - special.chndtr(critical, dof, x) - goal, 1e-9, 1e6)
    )
