"""Nested (reduced-space) inverse: x is the only unknown (docs/inverse.md, "Nested").

Every residual evaluation solves the equilibrium of every load case. The
Jacobian is exact, by the implicit function theorem,

    dB/dx = -(dg/ds)^-1 dg/dx,

with dg/dx from CasADi (or the model's closed form) and dg/ds from the equilibrium's
LU. A nonlinear case starts Newton at its first-order prediction from the previous
evaluation, s(x') + ds/dx (x - x'), with the previous LU (``EquilibriumSolver``'s chord
steps), so most evaluations factorise little. scipy's ``least_squares`` (trf with
bounds, or lm without) does the outer iteration in the internal coordinates z of
``ParameterSpace``.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver, NewtonSettings
from solvers.forward.evaluator import casadi_to_scipy
from solvers.inverse.continuumfit import ContinuumSystem
from solvers.inverse.problem import InverseProblem
from solvers.inverse.result import InverseResult


def _result(solver, z, residual, success, status, evaluations, elapsed) -> InverseResult:
    """The InverseResult of a nested solver at internal coordinates z."""
    space = solver.problem.space
    return InverseResult(
        method=solver.name,
        names=space.names,
        x=space.to_natural(z),
        cost=0.5 * float(residual @ residual),
        states=list(solver._states),
        success=bool(success),
        status=str(status),
        iterations=int(evaluations),
        forward_solves=solver.forward_solves,
        build_time_s=solver.build_time,
        solve_time_s=elapsed,
    )


class NestedSolver:
    """Reduced-space least squares with exact sensitivities.

    For the linear model (``TissueModel.componentwise``) every evaluation factorises the
    scalar block A(x) once (``solvers.forward.componentwise``) and solves the three components,
    every load case and every sensitivity column with it; no CasADi Function is built.
    The linear-elastic model does the same with its full saddle system
    (``solvers.inverse.continuumfit``). Otherwise each case is a Newton solve of the full
    system (``EquilibriumSolver``).

    Parameters
    ----------
    problem : InverseProblem
        The problem.
    method : {"trf", "lm"}
        scipy least-squares method; "lm" ignores the bounds.
    tolerance : float
        ftol = xtol = gtol of least_squares.
    max_evaluations : int
        Cap on residual evaluations.
    failures : {"raise", "shrink"}
        A load case without equilibrium during the fit: "raise" ends the fit as failed;
        "shrink" returns a non-finite residual, on which trf shortens its step (the
        stiffening fits of real skin, docs/realskin.md). A first evaluation that fails
        from rest is retried by load continuation either way.
    """

    name = "nested"

    def __init__(
        self,
        problem: InverseProblem,
        method="trf",
        tolerance=1e-12,
        max_evaluations=200,
        failures="raise",
    ):
        if method not in ("trf", "lm"):
            raise ValueError(f"method must be 'trf' or 'lm', got {method!r}")
        if failures not in ("raise", "shrink"):
            raise ValueError(f"failures must be 'raise' or 'shrink', got {failures!r}")
        self.failures = failures
        start = time.perf_counter()
        self.problem = problem
        self.method = method
        self.tolerance = tolerance
        self.max_evaluations = max_evaluations
        model = problem.model
        self.scalar = self.continuum = self.equilibrium = None
        if model.componentwise and model.is_linear(problem.names):
            self.scalar = ScalarSystem(model, problem.names)
        elif ContinuumSystem.applies(problem):
            self.continuum = ContinuumSystem(problem)
        else:
            settings = NewtonSettings(reuse_lu=True)
            self.equilibrium = EquilibriumSolver(model, problem.names, settings, problem.g)
            self._g_x = None
        self.observation_jacobians = [problem.case_residual_jacobian(c) for c in problem.cases]
        self.build_time = time.perf_counter() - start
        self.forward_solves = 0
        self._states = [None] * len(problem.cases)
        self._memory: list[tuple | None] = [None] * len(problem.cases)
        self._cache: tuple | None = None
        self._pending: tuple | None = None  # (z, r, x, equilibria) without sensitivities

    @property
    def states(self) -> list:
        """The equilibrium state of every case at the last evaluation."""
        return list(self._states)

    def seed(self, x: np.ndarray, states: list) -> None:
        """Start every case's Newton at a known equilibrium ``states`` at x (natural
        units), e.g. a fitted stage's at its estimate: an evaluation there then costs
        one factorisation per case instead of Newton from rest."""
        x = np.asarray(x, dtype=float)
        self._memory = [(x, np.asarray(s), np.zeros((len(s), x.size)), None) for s in states]

    def _sensitivity(self, k: int, case, x: np.ndarray, result) -> np.ndarray:
        """ds/dx = -(dg/ds)^-1 dg/dx of one case at its equilibrium ``result``; kept with
        the state and LU as the next evaluation's prediction."""
        g_x = result.parameter_jacobian
        if g_x is None:
            g_x = casadi_to_scipy(self._parameter_jacobian()(result.state, x, *_loads(case)))
        sensitivity = -result.solve(g_x.toarray())
        self._memory[k] = (np.array(x), result.state, sensitivity, result.factor)
        return sensitivity

    def _equilibrium(self, case, x: np.ndarray, previous: tuple | None):
        """Newton from the first-order prediction of the previous evaluation with its LU;
        if that fails (a long step of a stiffening model), from rest; a first evaluation
        that fails from rest, by load continuation."""
        solver, args = self.equilibrium, (case.force, x, case.prescribed)
        if previous is not None:
            x_0, state, sensitivity, factor = previous
            start = state + sensitivity @ (x - x_0)
            try:
                return solver.solve(*args, start=start, factor=factor, label=case.label)
            except EquilibriumError:
                pass
        try:
            return solver.solve(*args, label=case.label)
        except EquilibriumError:
            if previous is not None:
                raise
            return solver.solve_by_continuation(*args, label=case.label)

    def _parameter_jacobian(self) -> ca.Function:
        """dg/dx(s, x, F_B, d) by CasADi AD (built on first use)."""
        if self._g_x is None:
            g = self.problem.g
            s, x, force, prescribed = g.mx_in()
            value = g(s, x, force, prescribed)
            self._g_x = ca.Function("dg_dx", [s, x, force, prescribed], [ca.jacobian(value, x)])
        return self._g_x

    def residual(self, z: np.ndarray) -> np.ndarray:
        """Residual r(z) alone. On the Newton path the sensitivities are left for
        ``evaluate`` at the same z: trf asks for the Jacobian only at the points it
        accepts (on real skin a quarter of the points it tries are rejected)."""
        if self._cache is not None and _same(self._cache[0], z):
            return self._cache[1]
        if self.equilibrium is None:
            return self.evaluate(z)[0]
        if self._pending is not None and _same(self._pending[0], z):
            return self._pending[1]
        problem = self.problem
        x = problem.space.to_natural(z)
        results, residuals = [], []
        for k, case in enumerate(problem.cases):
            try:
                result = self._equilibrium(case, x, self._memory[k])
            except EquilibriumError:
                if self.failures == "raise":
                    raise
                self._pending = None
                return np.full(problem.n_residuals, np.nan)  # trf shortens its step
            self.forward_solves += 1
            self._states[k] = result.state
            results.append(result)
            residuals.append(problem.case_residual(case, result.state))
        r = np.concatenate(residuals)
        self._pending = (np.array(z), r, x, results)
        return r

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual r(z) and its exact Jacobian dr/dz."""
        if self._cache is not None and _same(self._cache[0], z):
            return self._cache[1], self._cache[2]
        problem = self.problem
        x = problem.space.to_natural(z)
        dx_dz = problem.space.natural_derivative(z)
        if self.equilibrium is not None:
            r = self.residual(z)
            if not np.all(np.isfinite(r)):
                return r, np.full((r.size, len(x)), np.nan)
            _, _, x, results = self._pending
            sensitivities = [
                self._sensitivity(k, case, x, result)
                for k, (case, result) in enumerate(zip(problem.cases, results))
            ]
        else:
            if self.scalar is not None:
                factor = self.scalar.factor(x)
                solved = [self.scalar.state(factor, c.force, c.prescribed) for c in problem.cases]
                pairs = [(state, self.scalar.sensitivity(factor, state)) for state in solved]
            else:  # the linear-elastic model: all cases from one factorisation
                every = self.continuum.evaluate(x)
                pairs = [(every[0][:, k], every[1][:, k]) for k in range(len(problem.cases))]
            self._states = [state for state, _ in pairs]
            self.forward_solves += len(pairs)
            sensitivities = [sensitivity for _, sensitivity in pairs]
            r = np.concatenate(
                [problem.case_residual(c, s) for c, s in zip(problem.cases, self._states)]
            )
        jac = np.vstack(
            [
                (observe @ sensitivity) * dx_dz[None, :]
                for observe, sensitivity in zip(self.observation_jacobians, sensitivities)
            ]
        )
        self._cache = (np.array(z), r, jac)
        return r, jac

    @property
    def active(self) -> np.ndarray:
        """Parameters that move the equilibrium (without building g on the fast path)."""
        if self.scalar is not None:
            return self.scalar.influential
        if self.continuum is not None:
            return self.problem.model.influential(self.problem.names)
        return self.problem.active

    def solve(self, start: np.ndarray | None = None) -> InverseResult:
        """Run least_squares from ``start`` (natural units; default: the space's start)."""
        self.forward_solves = 0
        self._states = [None] * len(self.problem.cases)
        self._memory = [None] * len(self.problem.cases)
        self._pending = None
        z, success, status, nfev, elapsed = least_squares_fit(
            self.evaluate,
            self.problem.space,
            start,
            self.active,
            self.method,
            self.tolerance,
            self.max_evaluations,
            self.residual,
        )
        residual = self.evaluate(z)[0]
        if not np.all(np.isfinite(residual)):  # failures="shrink" and no equilibrium at z
            raise EquilibriumError(
                f"no equilibrium at the end of the fit ({status}); try another start"
            )
        return _result(self, z, residual, success, status, nfev, elapsed)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same point z, to the last bits (x -> z -> x round trips move them)."""
    return a.shape == np.shape(b) and np.allclose(a, b, rtol=1e-15, atol=0)


def _loads(case) -> tuple:
    """(F_B, d) of a load case, as the residual takes them."""
    return case.force, case.prescribed


def least_squares_fit(
    evaluate,
    space,
    start,
    active=None,
    method="trf",
    tolerance=1e-12,
    max_evaluations=200,
    residual=None,
):
    """The outer loop shared by the exact nested solvers.

    ``evaluate(z) -> (r, dr/dz)`` over every internal coordinate (``residual(z) -> r``,
    if given, where only r is asked for); parameters not in ``active`` (mu and gamma at
    steady state) stay at their start values. A failed forward solve ends the start
    with ``success = False``.

    Returns
    -------
    z, success, status, evaluations, elapsed
        Internal coordinates at the end, the verdict, scipy's message, residual
        evaluations and wall time [s].
    """
    z_full = space.to_internal(space.start if start is None else start)
    active = np.ones(len(z_full), dtype=bool) if active is None else np.asarray(active)
    lower, upper = (b[active] for b in space.internal_bounds())

    def full(z_active: np.ndarray) -> np.ndarray:
        z = z_full.copy()
        z[active] = z_active
        return z

    begin = time.perf_counter()
    kwargs = {} if method == "lm" else {"bounds": (lower, upper)}
    try:
        fit = least_squares(
            lambda z: residual(full(z)) if residual else evaluate(full(z))[0],
            np.clip(z_full[active], lower, upper),
            jac=lambda z: evaluate(full(z))[1][:, active],
            method=method,
            ftol=tolerance,
            xtol=tolerance,
            gtol=tolerance,
            max_nfev=max_evaluations,
            x_scale=1.0,
            **kwargs,
        )
        outcome = full(fit.x), fit.status > 0, status_text(fit.message), fit.nfev
    except Exception as error:  # noqa: BLE001  a failed forward solve ends this start
        outcome = z_full, False, f"failed: {error}", 0
    return (*outcome, time.perf_counter() - begin)


def status_text(message: str) -> str:
    """scipy's least_squares message without its backticks and final full stop."""
    return message.replace("`", "").strip().rstrip(".")
