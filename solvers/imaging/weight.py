"""The regularisation weight beta of eq. (I8): Morozov's discrepancy principle,
generalised cross-validation, or the L-curve.

- ``discrepancy_weight`` (the default): the whitened chi^2 of the estimate equals its
  expectation under pure noise, n (the number of residuals). It needs the noise level,
  which the dataset declares.
- ``gcv_weight``: the minimum over beta of generalised cross-validation,

      GCV(beta) = n chi^2(beta) / (n - k(beta))^2,                                 (I10)

  k(beta) = tr((J^T J + beta R'')^-1 J^T J) the effective number of parameters of the
  Laplace approximation at the estimate. It predicts the error of left-out data, so it
  does not need chi^2 to move by more than the noise does: where an inclusion's whole
  signal is about the spread of chi^2 under noise (sqrt(2 n)), Morozov's weight is set
  by the noise draw and smooths the inclusion away, GCV's is not (docs/imaging.md,
  "Which weight").
- ``lcurve_weight``: the corner of the curve (log chi^2, log R) traced over beta, the
  point of largest curvature; it needs no noise level and serves as a check on it.

Each takes the estimate's ``method``: a method of ``solvers.imaging.estimate.SOLVERS``
(default the adjoint Gauss-Newton), built once on (fp, regularizer) and solved at every
weight it tries.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from solvers.imaging.estimate import SOLVERS, FieldEstimate
from solvers.imaging.fieldproblem import FieldProblem
from solvers.imaging.laplace import laplace


@dataclass
class WeightChoice:
    """A choice of beta, with the path of (beta, chi^2) that found it."""

    estimate: FieldEstimate
    target: float
    reached: bool
    path: list[tuple[float, float]]
    """(beta, chi^2) of every solve, in order."""
    note: str
    rule: str = "morozov"


def discrepancy_weight(
    fp: FieldProblem,
    regularizer,
    method=None,
    target: float | None = None,
    bounds: tuple[float, float] = (1e-2, 1e10),
    tolerance: float = 0.02,
    log=None,
) -> WeightChoice:
    """beta with chi^2(beta) = target (default n_residuals), by bisection in log beta.

    chi^2 grows with beta. From the largest beta (nearly homogeneous) the weight falls
    a decade at a time until chi^2 drops below the target, then bisects to
    ``tolerance`` decades (``morozov_walk``). When even the largest beta meets the
    target, the data need no field (returned, ``reached`` False); when the smallest
    does not, the model cannot reach the noise.

    The walk's comparisons are not all solves: a comparison is implied by a solved
    weight (chi^2 at a larger beta below the target, or at a smaller one above it),
    else predicted from the nearest solved estimate's Gauss-Newton model (eq. I10',
    when the solver formed J), and only the weights the answer is made of (the last
    bracket's ends) are solved, one per walk, each warm-started from the nearest solved
    one. Once they are, every comparison of the walk is implied (the brackets are nested) or it
    is walked again with what they showed; after ``PREDICTED_ROUNDS`` rounds the first
    unknown comparison is solved, as in plain bisection. The answer is the bisection's:
    the same bracket, its end nearer the target, typically from 3 solves instead of 10-15.
    """
    solver = (method or SOLVERS["nested-adjoint"])(fp, regularizer)
    target = float(fp.n_residuals if target is None else target)
    path, solved, models = [], {}, {}

    def run(beta):
        nearest = min(solved, key=lambda b: abs(np.log10(b / beta)), default=None)
        start = None if nearest is None else solved[nearest].coefficients
        estimate = solver.solve(beta, start)
        solved[beta] = estimate
        path.append((beta, estimate.chi2))
        if log:
            log(
                f"  beta {beta:.3g} mm^2: chi2 {estimate.chi2:.1f} (target {target:.0f}), "
                f"rms {estimate.rms_um:.1f} um, {estimate.seconds:.1f} s"
            )
        return estimate

    def known(beta):
        if beta in solved:
            return solved[beta].chi2 > target
        if any(b <= beta and e.chi2 > target for b, e in solved.items()):
            return True
        if any(b >= beta and e.chi2 <= target for b, e in solved.items()):
            return False
        return None

    def predicted(beta):
        with_model = [b for b, e in solved.items() if e.jacobian is not None]
        if not with_model:
            return None
        nearest = min(with_model, key=lambda b: abs(np.log10(b / beta)))
        if nearest not in models:
            models[nearest] = _chi2_model(regularizer, solved[nearest])
        value = models[nearest](beta)
        side = solved[nearest].chi2 > target
        others = [b for b, e in solved.items() if (e.chi2 > target) != side]
        if others:  # the model's error at the nearest solve across the target, grown
            other = min(others, key=lambda b: abs(np.log10(b / nearest)))  # quadratically
            error = solved[other].chi2 - models[nearest](other)
            value += error * (np.log(beta / nearest) / np.log(other / nearest)) ** 2
        return value > target

    high = bounds[1]
    if run(high).chi2 <= target:
        return WeightChoice(solved[high], target, False, path, "the data need no field")
    for round_ in range(PREDICTED_ROUNDS + 100):
        guesses = []

        def compare(beta, predict=round_ < PREDICTED_ROUNDS, guesses=guesses):
            answer = known(beta)
            if answer is None and predict:
                answer = predicted(beta)
            if answer is None:  # no model: solve it now (plain bisection)
                answer = run(beta).chi2 > target
            elif known(beta) is None:
                guesses.append(beta)
            return answer

        outcome, ends = morozov_walk(high, bounds[0], tolerance, compare)
        missing = [beta for beta in ends if beta not in solved]
        if missing:  # one at a time: the next walk predicts from the nearer solve
            run(missing[0])
        elif not guesses:
            break
        else:  # unreachable when the brackets nest; solve the first guess
            run(guesses[0])
    if outcome == "smallest":
        estimate = solved[ends[0]]
        return WeightChoice(
            estimate, target, False, path, "chi2 above target at the smallest weight"
        )
    below, above = solved[ends[0]], solved[ends[1]]
    best = below if abs(below.chi2 - target) <= abs(above.chi2 - target) else above
    return WeightChoice(best, target, True, path, "chi2 = target")


PREDICTED_ROUNDS = 4
"""Rounds of ``discrepancy_weight`` that may predict a comparison before it solves."""


def morozov_walk(high: float, smallest: float, tolerance: float, above) -> tuple[str, tuple]:
    """The weights Morozov's search visits, given ``above(beta)``: chi^2(beta) > target.

    From ``high`` (above the target) down a decade at a time to the first beta below it,
    then bisection in log10 beta to ``tolerance`` decades. Returns ("bracket", (low,
    high)), the last bracket, or ("smallest", (beta,)) when the decades fall below
    ``smallest`` first, beta the last one tried.
    """
    low = high
    while above(low):
        high, low = low, low / 10.0
        if low < smallest:
            return "smallest", (high,)
    while np.log10(high / low) > tolerance:
        middle = np.sqrt(high * low)
        if above(middle):
            high = middle
        else:
            low = middle
    return "bracket", (low, high)


def _chi2_model(regularizer, estimate: FieldEstimate):
    """chi^2(beta) predicted by the Gauss-Newton model about a converged estimate (eq.
    I10'): Delta = -(J^T J + beta R'')^-1 (J^T r + beta g), with J^T r = -beta_e g at
    the estimate's own weight beta_e (stationarity), chi^2 ~ |r|^2 + 2 (J^T r) Delta +
    |J Delta|^2."""
    c, jac = estimate.coefficients, estimate.jacobian
    data = jac.T @ jac
    curvature, pull = regularizer.hessian(c).toarray(), regularizer.gradient(c)
    slope = -estimate.weight * pull

    def chi2(beta: float) -> float:
        delta = -np.linalg.solve(data + beta * curvature, slope + beta * pull)
        return float(estimate.chi2 + 2.0 * slope @ delta + delta @ data @ delta)

    return chi2


def lcurve_weight(
    fp: FieldProblem,
    regularizer,
    method=None,
    bounds: tuple[float, float] = (1e-2, 1e10),
    per_decade: int = 2,
    log=None,
) -> WeightChoice:
    """beta at the L-curve's corner: largest curvature of (log chi^2, log R) over log beta.

    The estimates are made from the largest beta down, each warm-started from the
    last; the curvature of the parametric curve (x(t), y(t)), t = log10 beta, is
    |x'y'' - y'x''| / (x'^2 + y'^2)^(3/2) by finite differences. Ends are excluded.
    """
    solver = (method or SOLVERS["nested-adjoint"])(fp, regularizer)
    count = int(round(np.log10(bounds[1] / bounds[0]) * per_decade)) + 1
    betas = np.logspace(np.log10(bounds[1]), np.log10(bounds[0]), count)
    estimates, start = [], None
    for beta in betas:
        estimate = solver.solve(beta, start)
        estimates.append(estimate)
        start = estimate.coefficients
        if log:
            chi2, value = estimate.chi2, estimate.regularization
            log(f"  beta {beta:.3g} mm^2: chi2 {chi2:.1f}, R {value:.3g}")
    t = np.log10(betas)
    x = np.log([e.chi2 for e in estimates])
    y = np.log([max(e.regularization, 1e-300) for e in estimates])
    dx, dy = np.gradient(x, t), np.gradient(y, t)
    ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
    curvature = np.abs(dx * ddy - dy * ddx) / np.maximum((dx**2 + dy**2) ** 1.5, 1e-300)
    curvature[[0, -1]] = -np.inf
    best = estimates[int(np.argmax(curvature))]
    path = [(float(b), e.chi2) for b, e in zip(betas, estimates)]
    return WeightChoice(best, float(fp.n_residuals), True, path, "L-curve corner", "lcurve")


def linear_gcv(fp: FieldProblem, regularizer, estimate: FieldEstimate, jac, ts) -> np.ndarray:
    """GCV (eq. I10) at the log10 weights ``ts``, predicted from one estimate's
    Gauss-Newton model of eq. (I8).

    About the estimate c (residual r, J = dr/dc, R's gradient g and Hessian R'', the
    lagged one for total variation), the estimate at weight beta is c + Delta(beta),

        Delta(beta) = -(J^T J + beta R'')^-1 (J^T r + beta g),
        chi^2(beta) ~ |r + J Delta(beta)|^2,
        k(beta)     ~ tr((J^T J + beta R'')^-1 J^T J),                             (I10')

    exact for a linear forward map and a quadratic R. At the estimate's own weight
    Delta = 0 and k is the Laplace dof, so the prediction agrees with eq. (I10) there.
    """
    c = estimate.coefficients
    r = fp.residual(c)
    data = jac.T @ jac
    slope, curvature = jac.T @ r, regularizer.hessian(c).toarray()
    pull = regularizer.gradient(c)
    n, values = float(fp.n_residuals), []
    for t in np.atleast_1d(ts):
        beta = float(10.0**t)
        solved = np.linalg.solve(
            data + beta * curvature, np.column_stack([slope + beta * pull, data])
        )
        misfit = r - jac @ solved[:, 0]
        dof = float(np.trace(solved[:, 1:]))
        values.append(n * float(misfit @ misfit) / max(n - dof, 1.0) ** 2)
    return np.asarray(values)


def gcv_weight(
    fp: FieldProblem,
    regularizer,
    method=None,
    bounds: tuple[float, float] = (1e-2, 1e10),
    rank: int | None = None,
    tolerance: float = 0.1,
    predict: bool = True,
    log=None,
) -> WeightChoice:
    """beta at the minimum of GCV (eq. I10).

    With ``predict`` (and J formed: ``rank`` None), the search first follows eq. (I10'):
    from the estimate at the largest beta, the weight where the Gauss-Newton model's GCV
    is least, then the same from the estimate made there (warm-started from the nearest
    one), until the predicted weight moves by no more than ``tolerance`` / 2 decades
    (one step of the grid it is sought on). At a fixed point the nonlinear GCV's slope
    is zero to Gauss-Newton's order. This skips the decades where the map is constant
    (dof 1) and replaces the golden section: 2-4 solves where the sweep below takes
    12-20 (docs/imaging.md). If it does not settle in ``PREDICTIONS`` solves, or GCV is
    least at the largest beta, the sweep decides.

    The sweep: from the largest beta down a decade at a time (each solve warm-started
    from the last) until GCV has risen two decades in a row past its least value, or
    the smallest beta; then a golden-section search in log10 beta over the decades
    either side of the least, to ``tolerance`` decades. A least value at the largest
    beta means the data need no field (``reached`` False, no search). k(beta) is the
    Laplace approximation's effective dof at each estimate (``rank`` as in
    ``solvers.imaging.laplace.laplace``).
    """
    solver = (method or SOLVERS["nested-adjoint"])(fp, regularizer)
    n = float(fp.n_residuals)
    path, found = [], {}

    def score(t: float, start) -> float:
        t = round(float(t), 6)
        if t in found:
            return found[t][0]
        beta = float(10.0**t)
        estimate = solver.solve(beta, start)
        if rank is None and estimate.jacobian is None:
            estimate = replace(estimate, jacobian=fp.sensitivities(estimate.coefficients))
        dof = laplace(fp, regularizer, estimate, rank).effective_dof
        value = n * estimate.chi2 / max(n - dof, 1.0) ** 2
        found[t] = (value, estimate)
        path.append((beta, estimate.chi2))
        if log:
            log(
                f"  beta {beta:.3g} mm^2: chi2 {estimate.chi2:.1f}, dof {dof:.1f}, "
                f"GCV {value:.5g}, {estimate.seconds:.1f} s"
            )
        return value

    low, high = round(np.log10(bounds[0]), 6), round(np.log10(bounds[1]), 6)
    score(high, None)
    if predict and rank is None:
        settled = _predicted_minimum(fp, regularizer, found, score, (low, high), tolerance, log)
        best = min(found, key=lambda k: found[k][0])
        if settled and best != high:
            return WeightChoice(found[best][1], n, True, path, "GCV minimum (predicted)", "gcv")
    t, start, rises = high, None, 0
    while t >= low - 1e-9:
        value = score(t, start)
        start = found[round(t, 6)][1].coefficients
        least = min(v for v, _ in found.values())
        rises = rises + 1 if value > least else 0
        if rises >= 2:
            break
        t -= 1.0
    best = min(found, key=lambda k: found[k][0])
    if best in (high, low):
        note = (
            "GCV least at the largest weight: the data need no field"
            if best == high
            else "GCV least at the smallest weight searched"
        )
        return WeightChoice(found[best][1], n, False, path, note, "gcv")
    a, b = best - 1.0, best + 1.0
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    c, d = b - ratio * (b - a), a + ratio * (b - a)
    near = found[best][1].coefficients
    fc, fd = score(c, near), score(d, near)
    while b - a > tolerance:
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - ratio * (b - a)
            fc = score(c, near)
        else:
            a, c, fc = c, d, fd
            d = a + ratio * (b - a)
            fd = score(d, near)
    best = min(found, key=lambda k: found[k][0])
    return WeightChoice(found[best][1], n, True, path, "GCV minimum", "gcv")


PREDICTIONS = 6
"""Solves the predicted GCV search (eq. I10') may make before the sweep takes over."""


def _predicted_minimum(fp, regularizer, found, score, span, tolerance, log) -> bool:
    """Follow eq. (I10') from the largest weight; True when the prediction settles."""
    grid = np.arange(span[1], span[0] - 1e-9, -tolerance / 2.0)
    at = max(found)
    for _ in range(PREDICTIONS):
        estimate = found[at][1]
        curve = linear_gcv(fp, regularizer, estimate, estimate.jacobian, grid)
        target = round(float(grid[int(np.argmin(curve))]), 6)
        if log:
            log(f"  predicted GCV minimum at beta {10.0**target:.3g} mm^2")
        if abs(target - at) <= tolerance / 2.0 + 1e-9:  # one step of the grid
            return True
        nearest = min(found, key=lambda k: abs(k - target))
        score(target, found[nearest][1].coefficients)
        at = target
    return False
