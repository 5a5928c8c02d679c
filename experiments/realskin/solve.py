"""Solving the extensometer's inverse problem: in-plane markers and the pad force, jointly.

    f(x) = 1/2 sum_k ( |S_k^xy Delta^k(x) + c_k^xy|^2 + w_f^2 (R_x lam^k - F_k)^2 ),

subject to the equilibrium g(s^k, x) = 0 of every frame k with its pad displacement
prescribed (docs/model.md eq. 22, docs/inverse.md eq. 24). The DIC measures x and y only, so
a marker gives two residuals (``PlanarProblem``); frames without DIC give only the force
residual.

- ``ForwardSolver``: Newton with the model's closed-form Jacobian, a first-order
  predictor between parameter values and an LU reused while it converges fast;
- ``PlanarNestedSolver``: reduced-space least squares (scipy trf) with exact
  sensitivities ds/dx = -(dg/ds)^-1 dg/dx (implicit function theorem).

Standard errors, score tests and the stages of the loop are in ``experiments.realskin.stages``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from experiments.realskin.model import SkinSlabModel
from solvers.equilibrium import EquilibriumError, SparseEvaluator, kkt_jacobian
from solvers.nested import least_squares_fit
from solvers.problem import InverseProblem, LoadCase

NEWTON_TOLERANCE = 1e-10
"""Stop Newton at |g| <= NEWTON_TOLERANCE |g(0)| (as ``solvers.equilibrium``)."""


class PlanarProblem(InverseProblem):
    """``InverseProblem`` whose markers are observed in x and y only (2D DIC).

    Residual of a case: vec(W (S Delta + c)[:, :2]) (the x's, then the y's) [mm], then
    the weighted force residual w_f (R lam - F) [mm] if the case measures a force.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self._planar: dict[int, sp.csr_matrix] = {}

    @property
    def n_residuals(self) -> int:
        """Scalar residuals: 2 per marker plus one per measured force component."""
        return sum(2 * c.n_observations + _n_forces(c) for c in self.cases)

    def case_offset(self, case: LoadCase) -> np.ndarray:
        """Residual at rest: vec(W (S B0 - Y)) over x and y, then -w_f F."""
        markers = (case.weights[:, None] * case.offset[:, :2]).T.reshape(-1)
        if case.force_rows is None:
            return markers
        return np.concatenate([markers, -case.force_weight * np.asarray(case.force_target)])

    def case_residual_jacobian(self, case: LoadCase) -> sp.csr_matrix:
        """d(residual)/d(state): kron([I2 0], W S) on Delta, w_f R on lam (cached)."""
        key = id(case)
        if key not in self._planar:
            planar = sp.csr_matrix(np.eye(3)[:2])
            block = sp.kron(planar, sp.diags(case.weights) @ case.rows).tocsr()
            padding = sp.csr_matrix((block.shape[0], self.n_state - block.shape[1]))
            block = sp.hstack([block, padding])
            if case.force_rows is not None:
                lam = case.force_weight * sp.csr_matrix(case.force_rows)
                zero = sp.csr_matrix((lam.shape[0], 3 * self.model.n_free))
                block = sp.vstack([block, sp.hstack([zero, lam])])
            self._planar[key] = block.tocsr()
        return self._planar[key]

    def case_residual(self, case: LoadCase, state: np.ndarray) -> np.ndarray:
        """The residual of one case at a state [mm]."""
        return self.case_residual_jacobian(case) @ state + self.case_offset(case)

    def planar_errors(self, states: list[np.ndarray]) -> list[np.ndarray]:
        """Per case, model minus measured in-plane displacement (n_obs, 2) [mm]."""
        errors = []
        for case, state in zip(self.cases, states):
            delta = state[: 3 * self.model.n_free].reshape(3, -1).T
            errors.append((case.rows @ delta + case.offset)[:, :2])
        return errors

    def point_errors(self, states: list[np.ndarray]) -> list[np.ndarray]:
        """Per case, the in-plane distance |S B - Y|_xy of every marker [mm]."""
        return [np.linalg.norm(e, axis=1) for e in self.planar_errors(states)]

    def rest_noise_map(self) -> None:
        """The DIC reference (frame 0) is an exact grid: no shared rest noise."""
        return None


def _n_forces(case: LoadCase) -> int:
    return 0 if case.force_rows is None else int(case.force_rows.shape[0])


# ------------------------------------------------------------------------ forward solve
def _norm(vector: np.ndarray) -> float:
    """Euclidean norm; inf for a vector with non-finite entries (overflowed stiffening)."""
    if not np.all(np.isfinite(vector)):
        return np.inf
    with np.errstate(over="ignore"):
        return float(np.linalg.norm(vector))


@dataclass
class ForwardState:
    """An equilibrium: state s, its sensitivity ds/dx, the parameters and an LU near it."""

    x: np.ndarray
    state: np.ndarray
    sensitivity: np.ndarray
    factor: object


def general_derivatives(model, names: tuple[str, ...], g):
    """(s, x, F_B, d) -> [dg/ds, dg/dx] of any ``TissueModel``: its numeric dg/ds where
    it has one (``kkt_jacobian``), CasADi's Jacobians otherwise."""
    s, x, force, prescribed = g.mx_in()
    value = g(s, x, force, prescribed)
    numeric = kkt_jacobian(model, names)
    outputs = [ca.jacobian(value, x)] if numeric else [ca.jacobian(value, s), ca.jacobian(value, x)]
    evaluator = SparseEvaluator(ca.Function("dg", [s, x, force, prescribed], outputs))

    def derivatives(*args) -> list[sp.csc_matrix]:
        results = evaluator.evaluate(*args)
        return [numeric(*args), *results] if numeric else results

    return derivatives


class ForwardSolver:
    """Newton for g(s, x, F_B, d) = 0 with the model's closed-form Jacobian.

    - one Jacobian call gives dg/ds and dg/dx;
    - the start is the first-order prediction s(x') + ds/dx (x - x') from ``previous``;
    - one LU (minimum-degree ordering of A^T + A: the KKT pattern is symmetric) is
      reused while the residual falls at least 4x per step; the linear model's LU at x
      is shared by every load case;
    - the sensitivity ds/dx = -(dg/ds)^-1 dg/dx is exact: the LU preconditions
      iterative refinement with dg/ds at the solution.

    Parameters
    ----------
    model : SkinSlabModel
        The model.
    names : tuple of str
        The parameters x.
    """

    def __init__(self, model: SkinSlabModel, names: tuple[str, ...]):
        self.model = model
        self.names = tuple(names)
        self.g = model.state_residual(self.names)
        self.n_state = self.g.size1_in(0)
        if hasattr(model, "jacobian_function"):
            self.derivatives = SparseEvaluator(model.jacobian_function(self.names)).evaluate
        else:  # a base model of symbolic.continuum_model
            self.derivatives = general_derivatives(model, self.names, self.g)
        self.linear = model.is_linear(self.names)
        self.factorizations = 0
        self._shared: tuple | None = None

    def _factor(self, matrix: sp.csc_matrix):
        self.factorizations += 1
        try:
            return spla.splu(matrix, permc_spec="MMD_AT_PLUS_A")
        except RuntimeError as error:  # singular: no equilibrium near this state
            raise EquilibriumError(f"dg/ds is singular ({error})") from error

    def _residual(self, state, args) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):  # exp stiffening may overflow
            return self.g(state, *args).full().ravel()

    def solve(
        self,
        force: np.ndarray,
        x: np.ndarray,
        prescribed: np.ndarray,
        previous: ForwardState | None = None,
        label: str = "",
    ) -> ForwardState:
        """Equilibrium at x under the load F_B and the prescribed displacements d."""
        x = np.asarray(x, dtype=float)
        args = (x, force, prescribed)
        factor = None
        if self.linear and self._shared is not None and np.array_equal(self._shared[0], x):
            factor = self._shared[1]
        state = np.zeros(self.n_state)
        if previous is not None:
            state = previous.state + previous.sensitivity @ (x - previous.x)
            factor = factor if self.linear else previous.factor
        scale = float(np.linalg.norm(self._residual(np.zeros(self.n_state), args))) or 1.0
        g = self._residual(state, args)
        for _ in range(40):
            if _norm(g) <= NEWTON_TOLERANCE * scale:
                return self._finish(state, args, factor)
            fresh = factor is None
            if fresh:
                factor = self._factor(self.derivatives(state, *args)[0])
            step = factor.solve(-g)
            norm, length = np.linalg.norm(g), 1.0
            for _ in range(30):
                trial = state + length * step
                g_trial = self._residual(trial, args)
                if _norm(g_trial) < norm:
                    break
                length *= 0.5
            state, g = trial, g_trial
            if not np.isfinite(_norm(g)):
                break  # the stiffening overflowed along the whole step
            if _norm(g) > 0.25 * norm and not (self.linear and fresh):
                factor = None
        raise EquilibriumError(
            f"Newton did not converge for {label or 'a load case'} (relative residual "
            f"{_norm(g) / scale:.1e}); lower the stiffening bound or the load"
        )

    def solve_by_continuation(
        self,
        force: np.ndarray,
        x: np.ndarray,
        prescribed: np.ndarray,
        label: str = "",
        steps: int = 4,
        halvings: int = 3,
    ) -> ForwardState:
        """Equilibrium by load continuation: Newton at t (F_B, d) for t rising from 0 to
        1 in ``steps`` steps, each started from the last state scaled by the load ratio;
        a step whose Newton fails is halved (at most ``halvings`` times in a row).

        For a stiffening model far from the last equilibrium, where Newton from rest
        fails (large pad travel at large k0).
        """
        x = np.asarray(x, dtype=float)
        t, dt, previous, failures = 0.0, 1.0 / steps, None, 0
        while t < 1.0:
            target = min(1.0, t + dt)
            start = None
            if previous is not None:
                start = ForwardState(
                    x, previous.state * (target / t), np.zeros_like(previous.sensitivity), None
                )
            try:
                previous = self.solve(target * force, x, target * prescribed, start, label)
            except EquilibriumError:
                failures += 1
                if failures > halvings:
                    raise
                dt *= 0.5
                continue
            t, failures = target, 0
        return previous

    def _finish(self, state, args, factor) -> ForwardState:
        """Sensitivity at the solution, by refinement preconditioned with ``factor``."""
        d_s, d_x = self.derivatives(state, *args)
        rhs = -d_x.toarray()
        factor = self._factor(d_s) if factor is None else factor
        solution = factor.solve(rhs)
        for _ in range(8):
            defect = rhs - d_s @ solution
            if np.linalg.norm(defect) <= 1e-12 * max(np.linalg.norm(rhs), 1e-300):
                break
            solution = solution + factor.solve(defect)
        else:
            factor = self._factor(d_s)
            solution = factor.solve(rhs)
        if self.linear:
            self._shared = (np.array(args[0]), factor)
        return ForwardState(np.array(args[0]), state, solution, factor)


# ----------------------------------------------------------------------- nested solver
@dataclass
class NestedFit:
    """The outcome of ``PlanarNestedSolver.solve``.

    Attributes
    ----------
    x : numpy.ndarray
        Estimates (natural units).
    cost : float
        1/2 |r|^2 [mm^2].
    states : list of numpy.ndarray
        Equilibrium state of every load case at x.
    success : bool
        scipy's verdict (status > 0).
    status : str
        scipy's message.
    evaluations : int
        Residual evaluations.
    seconds : float
        Wall time [s].
    """

    x: np.ndarray
    cost: float
    states: list
    success: bool
    status: str
    evaluations: int
    seconds: float


class PlanarNestedSolver:
    """Reduced-space least squares over z (``ParameterSpace`` coordinates), scipy trf.

    Parameters
    ----------
    problem : PlanarProblem
        The problem.
    tolerance : float
        ftol = xtol = gtol of ``scipy.optimize.least_squares``.
    max_evaluations : int
        Cap on residual evaluations.
    """

    def __init__(self, problem: PlanarProblem, tolerance=1e-10, max_evaluations=80):
        self.problem = problem
        self.tolerance = tolerance
        self.max_evaluations = max_evaluations
        self.forward = ForwardSolver(problem.model, problem.names)
        self.memory: list[ForwardState | None] = [None] * len(problem.cases)
        self._cache: tuple | None = None

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual r(z) [mm] and its exact Jacobian dr/dz."""
        if self._cache is not None and np.array_equal(self._cache[0], z):
            return self._cache[1], self._cache[2]
        problem = self.problem
        x = problem.space.to_natural(z)
        dx_dz = problem.space.natural_derivative(z)
        residuals, jacobians, results = [], [], []
        for k, case in enumerate(problem.cases):
            try:
                result = self._solve_case(case, x, self.memory[k])
            except EquilibriumError:  # trf shrinks its trust region on a non-finite residual
                nan = np.full(problem.n_residuals, np.nan)
                return nan, np.full((nan.size, len(x)), np.nan)
            results.append(result)
            observe = problem.case_residual_jacobian(case)
            residuals.append(problem.case_residual(case, result.state))
            jacobians.append((observe @ result.sensitivity) * dx_dz[None, :])
        r, jac = np.concatenate(residuals), np.vstack(jacobians)
        self.memory = results
        self._cache = (np.array(z), r, jac)
        return r, jac

    def _solve_case(self, case: LoadCase, x: np.ndarray, previous: ForwardState | None):
        """Equilibrium of one case, predicted from ``previous``; if Newton fails from that
        prediction (a long step of a stiffening model), from the rest state. With no
        previous state (a fit's first evaluation), a failure from rest is retried by load
        continuation (``ForwardSolver.solve_by_continuation``); later in a fit a failure
        is reported (trf then shortens its step), which is much cheaper."""
        forward, args = self.forward, (case.force, x, case.prescribed)
        if previous is not None:
            try:
                return forward.solve(*args, previous, case.label)
            except EquilibriumError:
                return forward.solve(*args, None, case.label)
        try:
            return forward.solve(*args, None, case.label)
        except EquilibriumError:
            return forward.solve_by_continuation(*args, label=case.label)

    def solve(self, start: np.ndarray | None = None) -> NestedFit:
        """Fit from ``start`` (natural units; default the space's start values)."""
        space = self.problem.space
        z, success, status, evaluations, seconds = least_squares_fit(
            self.evaluate,
            space,
            start,
            tolerance=self.tolerance,
            max_evaluations=self.max_evaluations,
        )
        r, _ = self.evaluate(z)
        if not np.all(np.isfinite(r)):
            raise EquilibriumError(
                f"no equilibrium at the end of the fit ({status}); try another start"
            )
        return NestedFit(
            x=space.to_natural(z),
            cost=0.5 * float(r @ r),
            states=[m.state for m in self.memory],
            success=bool(success),
            status=str(status),
            evaluations=int(evaluations),
            seconds=seconds,
        )
