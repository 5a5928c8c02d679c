"""The overfitting guard: does an added effect predict a left-out load case better?

The folds are the contact points when the cases press on two or more of them
(all forces at one contact are left out together: the model must predict the
response at a point it has not seen), else the single load cases. For every
fold h in turn, both the previous model and the model with the new effect are
fitted to the other cases, and then predict fold h with their shared
parameters fixed. Per-capture nuisance parameters of fold h (rigid motion,
measurement scale) cannot be predicted; they are fitted to fold h alone, and
since each such parameter lowers a pure-noise chi^2 by 1 on average, their
number is charged:

    improvement = sum_h (chi^2_before,h - chi^2_after,h) - (n_after - n_before),

with chi^2_h = |W_h r_h|^2 / sigma^2 of the prediction and n the number of
nuisance parameters fitted to the left-out cases. The effect passes when the
improvement is positive.

The refits are first taken as one Gauss-Newton step from the fit to every case
(``linearised_left_out``): without fold h the optimum moves by the step on the other
cases' rows, whitened with their own noise model, and fold h's residual by its rows of
the Jacobian times that step (its nuisance parameters re-solved the same way). That
needs no new equilibrium: the Jacobian is the fit's. It is exact for a residual linear
in p. Where the improvement it gives is within ``CLEAR_MARGIN`` of zero, the step is
taken again from where it lands (``refined_left_out``: every case evaluated there, one
factorisation of K(p) per fold), and where that improvement is still within
``REFINED_MARGIN`` of zero, or within ``STEP_FACTOR`` times what the second step changed,
the exact refits decide, started from the first step (docs/diagnosis.md gives the gaps
measured between the three).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from solvers.diagnosis.fit import STATISTICAL_TOLERANCE, EffectFit, fit

CLEAR_MARGIN = 10.0
"""A linearised improvement within this of zero (chi^2 units) is taken again, refined."""

REFINED_MARGIN = 2.0
"""A refined improvement within this of zero (chi^2 units) is decided by exact refits."""

STEP_FACTOR = 2.0
"""So is a refined improvement within this many times the second step's change of it
of zero: the steps converge slowly there (measured on 15 continuum checks: the refined
improvement was within 0.56 times that change of the refits', docs/diagnosis.md)."""


@dataclass
class PredictionCheck:
    """Left-out prediction of every load case, before and after adding an effect."""

    held_out: list[list[int]]
    chi2_before: list[float]
    chi2_after: list[float]
    nuisance_before: int
    nuisance_after: int
    method: str = "exact"
    linearised_improvement: float | None = None

    @property
    def improvement(self) -> float:
        """Drop of the summed prediction chi^2, less the extra nuisance parameters."""
        drop = float(np.sum(self.chi2_before) - np.sum(self.chi2_after))
        return drop - (self.nuisance_after - self.nuisance_before)

    @property
    def improves(self) -> bool:
        """True when the new model predicts the left-out cases better."""
        return self.improvement > 0.0

    def reason(self) -> str:
        """One line for reports."""
        return (
            f"left-out prediction chi2 {np.sum(self.chi2_before):.1f} -> "
            f"{np.sum(self.chi2_after):.1f} ({self.nuisance_after - self.nuisance_before} "
            f"nuisance parameters charged): {'better' if self.improves else 'not better'}"
        )

    def record(self) -> dict:
        """As in diagnosis.json."""
        return {
            "held_out": self.held_out,
            "chi2_before": self.chi2_before,
            "chi2_after": self.chi2_after,
            "nuisance_before": self.nuisance_before,
            "nuisance_after": self.nuisance_after,
            "improvement": self.improvement,
            "improves": self.improves,
            "method": self.method,
            "linearised_improvement": self.linearised_improvement,
        }


def _mapped(source_labels, source_p, target) -> tuple[np.ndarray, np.ndarray]:
    """p of ``target`` from a fit with other labels; unknown entries start at 0, free."""
    known = dict(zip(source_labels, source_p))
    start = target.start()
    free = np.ones(len(target.labels), dtype=bool)
    for i, label in enumerate(target.labels):
        if label in known:
            start[i] = known[label]
            free[i] = False
    return start, free


def folds(problem) -> list[list[int]]:
    """Positions left out together: those sharing a contact point, or single cases."""
    groups: dict = {}
    for position in problem.positions:
        uv = getattr(problem.loads[problem.indices[position]], "uv", None)
        key = position if uv is None else tuple(np.round(np.asarray(uv, dtype=float), 6))
        groups.setdefault(key, []).append(position)
    if len(groups) >= 2:
        return list(groups.values())
    return [[position] for position in problem.positions]


def predict_left_out(model_fit: EffectFit, held, sigma: float) -> tuple[float, int]:
    """chi^2 of the prediction of base cases ``held`` after fitting the other cases.

    ``held`` is one position or a list of them. The training fit starts from the
    Gauss-Newton step of ``linearised_left_out`` (exact for a residual linear in p, so
    the refit only corrects its curvature). Returns the chi^2 and the number of
    nuisance parameters fitted to the held cases.
    """
    held = [held] if np.isscalar(held) else list(held)
    problem = model_fit.problem
    train = [k for k in problem.positions if k not in held]
    train_problem = problem.with_effects(problem.effects, positions=train)
    moved = model_fit.p
    if model_fit.raw_jacobian is not None:
        moved = model_fit.p + _left_out_step(model_fit, held)[0]
    start, _ = _mapped(problem.labels, moved, train_problem)
    trained = fit(train_problem, start, tolerance=STATISTICAL_TOLERANCE)
    if not trained.success:  # the linear step led somewhere K(p) cannot go: from the fit
        start, _ = _mapped(problem.labels, model_fit.p, train_problem)
        trained = fit(train_problem, start, tolerance=STATISTICAL_TOLERANCE)
    test_problem = problem.with_effects(problem.effects, positions=held)
    start, free = _mapped(train_problem.labels, trained.p, test_problem)
    if free.any():
        predicted = fit(test_problem, start, free, tolerance=STATISTICAL_TOLERANCE)
        rho = predicted.whitened
    else:
        r, _, _ = test_problem.evaluate(start)
        rho = test_problem.whiten(r)
    return float(rho @ rho) / sigma**2, int(free.sum())


def _left_out_step(model_fit: EffectFit, held: list) -> tuple[np.ndarray, list, np.ndarray]:
    """The Gauss-Newton step of the fit without the cases ``held``, from the fit to all.

    Returns delta (natural units, clipped to the bounds; zero on the held cases'
    nuisance entries), those entries' columns and the held cases' rows of r. See
    ``linearised_left_out``.
    """
    problem = model_fit.problem
    train = [k for k in problem.positions if k not in held]
    train_problem = problem.with_effects(problem.effects, positions=train)
    test_problem = problem.with_effects(problem.effects, positions=held)
    offsets = np.cumsum([0] + [3 * c.n_observations for c in problem.cases])

    def rows(positions):
        order = [problem.positions.index(k) for k in positions]
        return np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in order])

    labels = list(problem.labels)
    estimated = model_fit.estimated()
    step_columns = [labels.index(name) for name in train_problem.labels]
    step_columns = [c for c in step_columns if estimated[c]]
    nuisance = [labels.index(n) for n in test_problem.labels if n not in train_problem.labels]
    r, jacobian = model_fit.residual, model_fit.raw_jacobian
    t_rows = rows(train)
    system = train_problem.whiten(jacobian[np.ix_(t_rows, step_columns)])
    right = train_problem.whiten(r[t_rows])
    if model_fit.prior is not None:
        system = np.vstack([system, model_fit.prior[:, step_columns]])
        right = np.concatenate([right, model_fit.prior @ model_fit.p])
    delta = np.zeros(len(labels))
    if step_columns:
        delta[step_columns] = -np.linalg.lstsq(system, right, rcond=None)[0]
        moved = np.clip(model_fit.p + delta, problem.lower, problem.upper)
        delta = moved - model_fit.p
    delta[nuisance] = 0.0
    return delta, nuisance, rows(held)


def linearised_left_out(model_fit: EffectFit, held, sigma: float) -> tuple[float, int]:
    """``predict_left_out`` by one Gauss-Newton step from the fit to every case.

    With r, J the fit's raw residual and Jacobian, T the training rows and H the held
    ones, each whitened with its own cases' noise model (W_T, W_H), the estimated
    entries move by

        delta = -argmin |W_T (r_T + J_T delta)|^2 + |P (p + delta)|^2

    (P the priors' rows), and the held cases' nuisance entries N (per-capture
    parameters the training cases do not have) by the least squares of
    W_H (r_H + J_H delta + J_H,N delta_N). Returns the chi^2 of that prediction and
    the number of nuisance parameters, as ``predict_left_out``.
    """
    held = [held] if np.isscalar(held) else list(held)
    problem = model_fit.problem
    test_problem = problem.with_effects(problem.effects, positions=held)
    delta, nuisance, h_rows = _left_out_step(model_fit, held)
    r, jacobian = model_fit.residual, model_fit.raw_jacobian
    rho = test_problem.whiten(r[h_rows] + jacobian[h_rows] @ delta)
    if nuisance:
        columns = test_problem.whiten(jacobian[np.ix_(h_rows, nuisance)])
        rho = rho - columns @ np.linalg.lstsq(columns, rho, rcond=None)[0]
    return float(rho @ rho) / sigma**2, len(nuisance)


def refined_left_out(model_fit: EffectFit, held, sigma: float) -> tuple[float, int]:
    """``linearised_left_out`` taken twice: every case is evaluated where the first
    Gauss-Newton step without ``held`` lands (one factorisation of K(p)), and the step
    and the prediction are taken again from there, with that point's residual and
    Jacobian. Returns what ``predict_left_out`` returns.
    """
    held = [held] if np.isscalar(held) else list(held)
    moved = model_fit.p + _left_out_step(model_fit, held)[0]
    there = fit(model_fit.problem, moved, np.zeros(moved.size, dtype=bool))
    return linearised_left_out(replace(there, free=model_fit.free), held, sigma)


def prediction_check(
    previous: EffectFit,
    new: EffectFit,
    sigma: float,
    cache: dict | None = None,
    exact: bool = False,
) -> PredictionCheck:
    """Leave-one-fold-out comparison of ``previous`` and ``new`` (see module docstring).

    By one Gauss-Newton step from each full fit, unless ``exact`` or the resulting
    improvement is within ``CLEAR_MARGIN`` of zero; then by two steps, unless that
    improvement is within ``REFINED_MARGIN`` of zero or within ``STEP_FACTOR`` times
    the second step's change of it: then by refits.
    """
    cache = {} if cache is None else cache
    linearised = None
    if not exact and previous.raw_jacobian is not None and new.raw_jacobian is not None:
        check = _check(previous, new, sigma, cache, linearised_left_out, "linearised")
        if abs(check.improvement) >= CLEAR_MARGIN:
            check.linearised_improvement = check.improvement
            return check
        linearised = check.improvement
        check = _check(previous, new, sigma, cache, refined_left_out, "refined")
        check.linearised_improvement = linearised
        moved = abs(check.improvement - linearised)  # what the second step changed
        if abs(check.improvement) >= max(REFINED_MARGIN, STEP_FACTOR * moved):
            return check
    check = _check(previous, new, sigma, cache, predict_left_out, "exact")
    check.linearised_improvement = linearised
    return check


def _check(previous, new, sigma, cache, predict, method: str) -> PredictionCheck:
    """The comparison with one way of predicting a fold (``predict``)."""
    held_out, before, after = [], [], []
    n_before = n_after = 0
    for held in folds(new.problem):
        # the base problem too: a revisit changes it under the same effect names
        base = id(previous.problem.base)
        key = (method, base, tuple(e.name for e in previous.problem.effects), tuple(held))
        if key not in cache:
            cache[key] = predict(previous, held, sigma)
        chi2_before, nuisance = cache[key]
        chi2_after, nuisance_after = predict(new, held, sigma)
        held_out.append([int(new.problem.indices[k]) for k in held])
        before.append(chi2_before)
        after.append(chi2_after)
        n_before += nuisance
        n_after += nuisance_after
    return PredictionCheck(held_out, before, after, n_before, n_after, method)
