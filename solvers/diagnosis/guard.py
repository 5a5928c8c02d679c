"""The overfitting guard: does an added effect predict left-out data better than chance?

The folds are the contact points when the cases press on two or more of them
(all forces at one contact are left out together: the model must predict the
response at a point it has not seen), else the single load cases. For every
fold h in turn, both the previous model and the model with the new effect are
fitted to the other cases, and then predict fold h with their shared
parameters fixed. Per-capture parameters of fold h (rigid motion, measurement
scale) cannot come from the other cases; they are predicted across the fold's own
markers instead: fitted to one half of its markers (two opposite quadrants about
their centroid, in the skin's principal axes) and predicting the other half, and
the other way round (``halves``). So every residual of the fold is predicted from data
it was not fitted on, and

    G = sum_h (chi^2_before,h - chi^2_after,h),                             (G1)

with chi^2_h = |W_h r_h|^2 / sigma^2 of the prediction (W_h couples a marker's rows
across the fold's cases only, so each half is whitened on its own).

**Better than chance.** A model with model error predicts its folds with the
dispersion phi >= 1 of ``solvers.diagnosis.leftout`` (G2). An improvement of G by
chance alone is at most about chi^2 with k degrees of freedom (k the shared parameters
the effect adds: G does not exceed their in-sample drop on average), in units of
phi sigma^2 (quasi-likelihood). The effect predicts better than chance when

    G / phi_after > chi^2_k(1 - level),                                     (G3)

phi_after the dispersion of the model with the effect, the larger model (as the
denominator of an F test).

The refits are first taken as one Gauss-Newton step from the fit to every case
(``linearised_left_out``): without fold h the optimum moves by the step on the other
cases' rows, whitened with their own noise model, and fold h's residual by its rows of
the Jacobian times that step (its nuisance parameters re-solved the same way). That
needs no new equilibrium: the Jacobian is the fit's. It is exact for a residual linear
in p. Where G lands within ``CLEAR_MARGIN`` of the boundary of (G3), the step is
taken again from where it lands (``refined_left_out``: every case evaluated there, one
factorisation of K(p) per fold), and where that is still within ``REFINED_MARGIN`` of
the boundary, or within ``STEP_FACTOR`` times what the second step changed, the exact
refits decide, started from the first step (docs/results/left-out-fits.md gives the gaps measured
between the three).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from solvers.diagnosis.fit import STATISTICAL_TOLERANCE, EffectFit, fit, statistical_tolerance
from solvers.diagnosis.leftout import LEVEL, LeftOut, PredictionCheck

CLEAR_MARGIN = 10.0
"""A linearised G within this of the boundary of (G3) (chi^2 units) is taken again, refined."""

REFINED_MARGIN = 2.0
"""A refined G within this of the boundary (chi^2 units) is decided by exact refits."""

STEP_FACTOR = 2.0
"""So is a refined G within this many times the second step's change of it of the
boundary: the steps converge slowly there (measured on 15 continuum checks: the refined
improvement was within 0.56 times that change of the refits', docs/results/left-out-fits.md)."""


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
    the refit only corrects its curvature); a model nonlinear in its state starts from
    the fit itself, its states warm, and stops at ``statistical_tolerance``. The held cases'
    per-capture parameters are
    fitted to them and predicted across their marker halves by one Gauss-Newton step from
    that fit (``across_halves``; exact where they enter linearly). Returns the chi^2 and
    the number of those parameters.
    """
    held = [held] if np.isscalar(held) else list(held)
    problem = model_fit.problem
    train = [k for k in problem.positions if k not in held]
    train_problem = problem.with_effects(problem.effects, positions=train)
    moved = model_fit.p
    if model_fit.raw_jacobian is not None and problem.linear_state:
        moved = model_fit.p + _left_out_step(model_fit, held)[0]
    start, _ = _mapped(problem.labels, moved, train_problem)
    states = None
    if not problem.linear_state:  # Newton: from the fit's own states, to what phi reads
        states = [model_fit.states[problem.positions.index(k)] for k in train]
    tolerance = statistical_tolerance(problem, model_fit.whitened.size)
    trained = fit(train_problem, start, states=states, tolerance=tolerance)
    if not trained.success:  # the linear step led somewhere K(p) cannot go: from the fit
        start, _ = _mapped(problem.labels, model_fit.p, train_problem)
        trained = fit(train_problem, start, tolerance=tolerance)
    test_problem = problem.with_effects(problem.effects, positions=held)
    start, free = _mapped(train_problem.labels, trained.p, test_problem)
    if free.any():  # fitted to the whole fold, then predicted across its halves
        predicted = fit(test_problem, start, free, tolerance=STATISTICAL_TOLERANCE)
        columns = predicted.jacobian[:, free]
        rho = across_halves(predicted.whitened, columns, halves(test_problem))
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
    offsets = np.cumsum([0] + problem.case_rows())

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
    W_H (r_H + J_H delta + J_H,N delta_N) over one half of the held markers, predicting
    the other half (``across_halves``). Returns the chi^2 of that prediction and the
    number of nuisance parameters, as ``predict_left_out``.
    """
    held = [held] if np.isscalar(held) else list(held)
    problem = model_fit.problem
    test_problem = problem.with_effects(problem.effects, positions=held)
    delta, nuisance, h_rows = _left_out_step(model_fit, held)
    r, jacobian = model_fit.residual, model_fit.raw_jacobian
    rho = test_problem.whiten(r[h_rows] + jacobian[h_rows] @ delta)
    if nuisance:
        columns = test_problem.whiten(jacobian[np.ix_(h_rows, nuisance)])
        rho = across_halves(rho, columns, halves(test_problem))
    return float(rho @ rho) / sigma**2, len(nuisance)


def halves(problem) -> np.ndarray:
    """Which whitened residual rows of ``problem``'s cases belong to the first half of the
    markers: two opposite quadrants about the markers' centroid, in the principal axes of
    their rest positions (the skin's plane), the same markers in every case. Rows are
    each case's blocks of observed components in turn, then its force rows
    (``solvers.diagnosis.observation``), so a marker's rows, which the whitening couples
    across cases, fall in one half; force rows, which no marker carries, go with the
    first."""
    points = np.vstack([case.rest_points for case in problem.cases])
    if len(points) < 2:  # force rows alone
        return np.ones(sum(problem.case_rows()), dtype=bool)
    centre = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - centre, full_matrices=False)
    width = len(problem.base.observed)
    masks = []
    for case, rows in zip(problem.cases, problem.case_rows()):
        a, b = ((case.rest_points - centre) @ axes[:2].T).T
        marker = np.tile(a * b >= 0.0, width)
        masks.append(np.concatenate([marker, np.ones(rows - marker.size, dtype=bool)]))
    return np.concatenate(masks)


def across_halves(rho: np.ndarray, columns: np.ndarray, first: np.ndarray) -> np.ndarray:
    """rho with the parameters of ``columns`` fitted to one half of the rows (``first``
    or not) and predicting the other, both ways: every row predicted from rows it was not
    fitted on (linear least squares, whitened)."""
    out = np.array(rho, dtype=float)
    for fitted in (first, ~first):
        step = np.linalg.lstsq(columns[fitted], rho[fitted], rcond=None)[0]
        out[~fitted] = rho[~fitted] - columns[~fitted] @ step
    return out


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


def added_dof(previous: EffectFit, new: EffectFit) -> float:
    """k of eq. (G3): the effective degrees of freedom ``new`` adds to ``previous`` that a
    left-out fold inherits, i.e. without the per-capture parameters (at least 1)."""
    known = {e.name for e in previous.problem.effects}
    per_case = sum(
        e.dim * len(new.problem.positions)
        for e in new.problem.effects
        if e.per_case and e.name not in known
    )
    return max(new.effective_dof() - previous.effective_dof() - per_case, 1.0)


def prediction_check(
    previous: EffectFit,
    new: EffectFit,
    sigma: float,
    cache: dict | None = None,
    exact: bool = False,
    level: float = LEVEL,
) -> PredictionCheck:
    """Leave-one-fold-out comparison of ``previous`` and ``new`` (see module docstring).

    By one Gauss-Newton step from each full fit, unless ``exact``, a model is nonlinear
    in its state, or G lands within ``CLEAR_MARGIN`` of the boundary of (G3); then by two
    steps, unless G is within ``REFINED_MARGIN`` of it or within ``STEP_FACTOR`` times
    the second step's change of it: then by refits.
    """
    cache = {} if cache is None else cache
    linearised = None
    k = added_dof(previous, new)
    # a model nonlinear in its state is not predicted by Gauss-Newton steps from the fit:
    # on the real skin's keloid the steps put a left-out frame's chi^2 at 1e9 for 2e7
    exact = exact or not (previous.problem.linear_state and new.problem.linear_state)
    if not exact and previous.raw_jacobian is not None and new.raw_jacobian is not None:
        check = _check(previous, new, sigma, cache, linearised_left_out, "linearised", k, level)
        if abs(check.distance) >= CLEAR_MARGIN:
            check.linearised_improvement = check.improvement
            return check
        linearised, first = check.improvement, check.distance
        check = _check(previous, new, sigma, cache, refined_left_out, "refined", k, level)
        check.linearised_improvement = linearised
        moved = abs(check.distance - first)  # what the second step changed
        if abs(check.distance) >= max(REFINED_MARGIN, STEP_FACTOR * moved):
            return check
    check = _check(previous, new, sigma, cache, predict_left_out, "exact", k, level)
    check.linearised_improvement = linearised
    return check


def _key(method: str, model_fit: EffectFit, held) -> tuple:
    """A left-out prediction's cache key: the base problem too, as a revisit changes it
    under the same effect names."""
    names = tuple(e.name for e in model_fit.problem.effects)
    return (method, id(model_fit.problem.base), names, tuple(held))


def _predicted(cache: dict, method: str, predict, model_fit: EffectFit, held, sigma):
    """``predict(model_fit, held, sigma)``, kept in ``cache``."""
    key = _key(method, model_fit, held)
    if key not in cache:
        cache[key] = predict(model_fit, held, sigma)
    return cache[key]


def _check(
    previous, new, sigma, cache, predict, method: str, k: float = 1.0, level: float = LEVEL
) -> PredictionCheck:
    """The comparison with one way of predicting a fold (``predict``)."""
    held_out, before, after = [], [], []
    n_before = n_after = 0
    for held in folds(new.problem):
        chi2_before, nuisance = _predicted(cache, method, predict, previous, held, sigma)
        chi2_after, nuisance_after = _predicted(cache, method, predict, new, held, sigma)
        held_out.append([int(new.problem.indices[position]) for position in held])
        before.append(chi2_before)
        after.append(chi2_after)
        n_before += nuisance
        n_after += nuisance_after
    rows = int(new.whitened.size)
    return PredictionCheck(held_out, before, after, n_before, n_after, method, None, rows, k, level)


def left_out(model_fit: EffectFit, sigma: float, cache: dict | None = None) -> LeftOut:
    """The left-out prediction of ``model_fit`` over its folds (linearised,
    ``linearised_left_out``; refitted when the model is nonlinear in its state); with a
    single fold, the in-sample chi^2 over m - k instead."""
    groups = folds(model_fit.problem)
    rows = int(model_fit.whitened.size)
    if len(groups) < 2 or model_fit.raw_jacobian is None:
        fitted = int(round(model_fit.effective_dof()))
        return LeftOut(model_fit.cost / sigma**2, rows, fitted, "in-sample")
    cache = {} if cache is None else cache
    method, predict = "linearised", linearised_left_out
    if not model_fit.problem.linear_state:  # as ``prediction_check``: refits
        method, predict = "exact", predict_left_out
    chi2 = sum(_predicted(cache, method, predict, model_fit, held, sigma)[0] for held in groups)
    return LeftOut(float(chi2), rows)
