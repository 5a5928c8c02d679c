"""Checks every effect must pass on any base model: off at theta = 0, exact derivatives.

``setting`` is (ExtendedProblem without effects, its fitted EffectFit, the library):
``fitted_setting`` makes one of any base problem, ``simulated_setting`` the paper's.
"""

from __future__ import annotations

import numpy as np

from experiments.diagnosis.diagnose import BASE_NAMES
from experiments.phantom.simulate import simulate_with_effects
from experiments.problem.fitting import FitSettings, build_problem, dataset_loads
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from symbolic.effects.library import ALL_EFFECT_NAMES, effect_library


def fitted_setting(base, loads, names, energy: str | None = None) -> tuple:
    """The ``setting`` of a base problem: ``base`` with its ``loads`` extended by no
    effect, its fit (``solvers.diagnosis.fit``) and the library of the effects ``names``
    (those that extend ``energy`` when given, ``effect_library``)."""
    problem = ExtendedProblem(base, loads, [])
    return problem, fit(problem), effect_library(names, energy)


def simulated_setting() -> tuple:
    """The ``setting`` of a simulated dataset on the paper's energy (seed 3, no effect):
    its base problem on ``BASE_NAMES``, fitted, with every effect of the library."""
    dataset = simulate_with_effects({}, seed=3)
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    loads = dataset_loads(dataset, base.model.volume)
    return fitted_setting(base, loads, ALL_EFFECT_NAMES)


def _point(problem: ExtendedProblem, base_p: np.ndarray, factor: float) -> np.ndarray:
    """p with x from the base fit and theta = factor * scale (alternating signs)."""
    theta = problem.scale[len(base_p) :] * factor
    theta = theta * np.where(np.arange(theta.size) % 2, -1.0, 1.0)
    p = np.concatenate([base_p, theta])
    return np.clip(p, problem.lower, problem.upper)


def check_theta_zero(setting, name: str, solved_atol: float = 1e-13) -> None:
    """g and r of the base problem extended by ``name`` at theta = 0 are the base's.

    The solved residual agrees to ``solved_atol``: to rounding for a linear base model,
    to the Newton tolerance (1e-10 relative) for a nonlinear one.
    """
    problem, base_fit, library = setting
    extended = problem.with_effects([library[name]])
    p = np.concatenate([base_fit.p, np.zeros(len(extended.labels) - base_fit.p.size)])
    rng = np.random.default_rng(0)
    tail = 3 * problem.model.n_constraints  # the multipliers stay last
    for position in range(len(problem.positions)):
        n_base = problem.functions(position).n_state
        n_state = extended.functions(position).n_state
        state = rng.normal(0.0, 0.05, n_base)
        kept = np.r_[0 : n_base - tail, n_state - tail : n_state]
        added = np.r_[n_base - tail : n_state - tail]
        padded = np.zeros(n_state)
        padded[kept] = state
        g_base = problem.numeric(position, "equilibrium")(state, base_fit.p)[0].ravel()
        g = extended.numeric(position, "equilibrium")(padded, p)[0].ravel()
        np.testing.assert_allclose(g[kept], g_base, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(g[added], 0.0 * g[added])
        r_base = problem.numeric(position, "residual")(state, base_fit.p)[0].ravel()
        r = extended.numeric(position, "residual")(padded, p)[0].ravel()
        np.testing.assert_allclose(r, r_base, rtol=0, atol=1e-14)  # c + (p - c) rounds
    r_solved, _, _ = extended.evaluate(p)
    np.testing.assert_allclose(r_solved, base_fit.residual, rtol=0, atol=solved_atol)


def check_newton_jacobian(extended: ExtendedProblem, p: np.ndarray) -> None:
    """The Newton dg/ds (closed-form blocks of the base and linear effects) against AD of g."""
    import casadi as ca

    functions = extended.functions(0)
    rng = np.random.default_rng(1)
    state = rng.normal(0.0, 0.05, functions.n_state)
    reference = ca.Function(
        "g", [functions.s, functions.p], [ca.jacobian(functions.g, functions.s)]
    )
    expected = np.array(ca.densify(reference(state, p)))
    actual = extended.numeric(0, "newton")(state, p)[1].toarray()
    np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def check_derivatives(setting, name: str, theta_step: float = 1e-5) -> None:
    """d r / d p of the problem extended by ``name`` against central differences (steps of
    ``theta_step`` times an effect parameter's scale), and the Newton Jacobian dg/ds
    against automatic differentiation of g."""
    problem, base_fit, library = setting
    extended = problem.with_effects([library[name]])
    n_x = base_fit.p.size
    check_newton_jacobian(extended, _point(extended, base_fit.p, 0.7))
    for point in (_point(extended, base_fit.p, 0.0), _point(extended, base_fit.p, 0.7)):
        r, jacobian, _ = extended.evaluate(point)
        for j in range(point.size):
            step = extended.scale[j] * theta_step if j >= n_x else point[j] * 1e-6
            if point[j] - step < extended.lower[j]:  # one-sided at a lower bound of 0
                plus = extended.evaluate(point + step * np.eye(point.size)[j])[0]
                twice = extended.evaluate(point + 2 * step * np.eye(point.size)[j])[0]
                numeric = (4 * plus - 3 * r - twice) / (2 * step)
            else:
                plus = extended.evaluate(point + step * np.eye(point.size)[j])[0]
                minus = extended.evaluate(point - step * np.eye(point.size)[j])[0]
                numeric = (plus - minus) / (2 * step)
            scale = max(np.abs(jacobian[:, j]).max(), 1e-12)
            assert np.abs(numeric - jacobian[:, j]).max() < 1e-5 * scale, (name, j)
