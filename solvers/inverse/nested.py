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

from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver, NewtonSettings
from solvers.forward.evaluator import casadi_to_scipy
from solvers.inverse.continuumfit import ContinuumSystem
from solvers.inverse.methods import ReducedSpaceSolver
from solvers.inverse.problem import InverseProblem


class NestedSolver(ReducedSpaceSolver):
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
    method, tolerance, max_evaluations
        The outer least squares (``ReducedSpaceSolver``).
    failures : {"raise", "shrink"}
        A load case without equilibrium during the fit: "raise" ends the fit as failed;
        "shrink" returns a non-finite residual, on which trf shortens its step (the
        stiffening fits of real skin, docs/realskin.md). A first evaluation that fails
        from rest is retried by load continuation either way.
    """

    def __init__(
        self,
        problem: InverseProblem,
        method="trf",
        tolerance=1e-12,
        max_evaluations=200,
        failures="raise",
    ):
        if failures not in ("raise", "shrink"):
            raise ValueError(f"failures must be 'raise' or 'shrink', got {failures!r}")
        start = time.perf_counter()
        super().__init__(problem, method, tolerance, max_evaluations)
        self.failures = failures
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
        self.reset()

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
            self._states = list(self._cache[3])
            return self._cache[1]
        if self.equilibrium is None:
            return self.evaluate(z)[0]
        if self._pending is not None and _same(self._pending[0], z):
            self._states = [result.state for result in self._pending[3]]
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
            self._states = list(self._cache[3])
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
        self._cache = (np.array(z), r, jac, list(self._states))
        return r, jac

    @property
    def active(self) -> np.ndarray:
        """Parameters that move the equilibrium (without building g on the fast path)."""
        if self.scalar is not None:
            return self.scalar.influential
        if self.continuum is not None:
            return self.problem.model.influential(self.problem.names)
        return self.problem.active

    def reset(self) -> None:
        """Forget the previous solve: counters, Newton's warm starts and the caches."""
        self.forward_solves = 0
        self._states = [None] * len(self.problem.cases)
        self._memory: list[tuple | None] = [None] * len(self.problem.cases)
        self._cache: tuple | None = None  # (z, r, dr/dz, states)
        self._pending: tuple | None = None  # (z, r, x, equilibria) without sensitivities


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same point z, to the last bits (x -> z -> x round trips move them)."""
    return a.shape == np.shape(b) and np.allclose(a, b, rtol=1e-15, atol=0)


def _loads(case) -> tuple:
    """(F_B, d) of a load case, as the residual takes them."""
    return case.force, case.prescribed
