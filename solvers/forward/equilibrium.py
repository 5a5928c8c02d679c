"""Static forward solve of K(B; x)(B - B0) = F_B by Newton's method (docs/model.md, eq. 22).

The residual and its sparse Jacobian come from the model: its numeric tangent
(``kkt_jacobian``), its closed-form Jacobian (``jacobian_function``, the real-skin slab) or
CasADi's AD. Each Newton step is one sparse LU solve (SuperLU through scipy, symmetric
minimum-degree ordering). An LU is kept while it contracts the residual at least 2x per
step (``CHORD_CONTRACTION``) and made afresh otherwise, so a good start (a previous
equilibrium, or its first-order prediction at new parameters) with the previous LU
often needs no factorisation at all. A backtracking line search on |g| guards the
nonlinear model. Solves with dg/ds at the solution (``Equilibrium.solve``: the
sensitivities of the nested inverse) refine the nearby LU's solution with dg/ds
itself. The linear model (k0 = 0) is solved in one step on its scalar block instead
(``solvers.forward.componentwise``), without building any CasADi Function.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.forward.componentwise import ORDERING, ScalarSystem
from solvers.forward.evaluator import SparseEvaluator, kkt_jacobian
from symbolic.model import TissueModel

CHORD_CONTRACTION = 0.5
"""An LU is kept for the next Newton step while |g| falls at least this much per step."""
REFINEMENT_TOLERANCE = 1e-9
"""``Equilibrium.solve`` refines until |dg/ds X - rhs| <= REFINEMENT_TOLERANCE |rhs|
(relative; what the fit's Jacobian needs)."""


class EquilibriumError(RuntimeError):
    """Newton's method did not reach the requested residual."""


@dataclass(frozen=True)
class NewtonSettings:
    """Settings of the Newton solver.

    Attributes
    ----------
    tolerance : float
        Stop when |g(s)| <= tolerance * |g(0)| (relative residual).
    max_iterations : int
        Give up after this many Newton steps.
    line_search : bool
        Halve the step until |g| decreases (at most 30 halvings).
    reuse_lu : bool
        Keep an LU made during the solve for the next steps while it contracts |g| at
        least 2x per step (chord steps: linear convergence, fewer factorisations; for
        the many solves of a nested fit). Off: full Newton, quadratic convergence. An
        LU passed to ``solve`` is kept while it contracts either way.
    """

    tolerance: float = 1e-10
    max_iterations: int = 40
    line_search: bool = True
    reuse_lu: bool = False

    def __post_init__(self) -> None:
        if not (0 < self.tolerance < 1):
            raise ValueError(f"tolerance must lie in (0, 1), got {self.tolerance}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise ValueError(
                f"max_iterations must be a positive integer, got {self.max_iterations}"
            )


@dataclass
class Equilibrium:
    """A converged static state.

    Attributes
    ----------
    positions : numpy.ndarray
        B, all control points, (n, 3) [mm].
    state : numpy.ndarray
        s = [vec(B_free - B0_free); vec(lam)].
    multipliers : numpy.ndarray
        lam, (r, 3) [N]; empty without prescribed displacements.
    iterations : int
        Newton steps taken.
    residual_history : list of float
        Relative residual |g| / |g(0)| before each step and at the end.
    jacobian : scipy.sparse.csc_matrix
        dg/ds at the solution (for sensitivities); None for the linear model's scalar path.
    factor : scipy.sparse.linalg.SuperLU
        An LU of dg/ds: at the solution when ``exact``, else at a nearby state (Newton's
        last); use ``solve``.
    exact : bool
        Whether ``factor`` is dg/ds's own at the solution.
    parameter_jacobian : scipy.sparse.csc_matrix, optional
        dg/dx at the solution, when the model's closed form gave it with dg/ds.
    """

    positions: np.ndarray
    state: np.ndarray
    multipliers: np.ndarray
    iterations: int
    residual_history: list[float] = field(default_factory=list)
    jacobian: sp.csc_matrix | None = None
    factor: object | None = None
    exact: bool = True
    parameter_jacobian: sp.csc_matrix | None = None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """X with dg/ds X = rhs at the solution (dense rhs, (n_state,) or (n_state, k)).

        With a nearby LU, iterative refinement with dg/ds (to ``REFINEMENT_TOLERANCE``);
        if a step does not cut the defect 10x, dg/ds is factorised and the LU kept
        (``exact`` becomes True).
        """
        rhs = np.asarray(rhs, dtype=float)
        solution = self.factor.solve(rhs)
        if self.exact:
            return solution
        target = REFINEMENT_TOLERANCE * max(float(np.linalg.norm(rhs)), 1e-300)
        previous = np.inf
        for _ in range(8):
            defect = rhs - self.jacobian @ solution
            size = float(np.linalg.norm(defect))
            if size <= target:
                return solution
            if size > 0.1 * previous:
                break  # the LU is too far from dg/ds to refine in a few steps
            solution, previous = solution + self.factor.solve(defect), size
        self.factor, self.exact = _lu(self.jacobian), True
        return self.factor.solve(rhs)


def _lu(matrix: sp.spmatrix):
    """SuperLU of dg/ds (symmetric minimum-degree ordering); singular: EquilibriumError."""
    try:
        return spla.splu(sp.csc_matrix(matrix), **ORDERING)
    except RuntimeError as error:  # singular: no equilibrium near this state
        raise EquilibriumError(f"dg/ds is singular ({error})") from error


def _norm(vector: np.ndarray) -> float:
    """Euclidean norm; inf for a vector with non-finite entries (overflowed stiffening)."""
    if not np.all(np.isfinite(vector)):
        return np.inf
    with np.errstate(over="ignore"):
        return float(np.linalg.norm(vector))


class EquilibriumSolver:
    """Newton solver for one model and one choice of symbolic parameters.

    The CasADi Functions are built once in the constructor; ``solve`` can be
    called for many parameter values and loads.

    Parameters
    ----------
    model : TissueModel
        The model.
    names : tuple of str
        Parameters passed as ``x`` to ``solve`` (the others are fixed).
    settings : NewtonSettings
        Tolerances.
    residual : casadi.Function, optional
        ``model.state_residual(names)`` if the caller already built it.
    """

    def __init__(
        self, model: TissueModel, names: tuple[str, ...] = (), settings=None, residual=None
    ):
        self.model = model
        self.names = tuple(names)
        self.settings = settings or NewtonSettings()
        self.linear = model.is_linear(self.names)
        self.scalar = None
        if model.componentwise and self.linear:
            model.symbolic_values(self.names)  # the names' checks, one message for all paths
            self.scalar = ScalarSystem(model, self.names)
            self.n_state = 3 * (model.n_free + model.n_constraints)
            self._cache: tuple | None = None
            return
        g = model.state_residual(self.names) if residual is None else residual
        self.residual = g
        self._both = None  # (s, x, F_B, d) -> [dg/ds, dg/dx] in closed form
        self._jacobian = kkt_jacobian(model, self.names)
        if self._jacobian is None and hasattr(model, "jacobian_function"):
            self._both = SparseEvaluator(model.jacobian_function(self.names)).evaluate
            self._jacobian = lambda *args: self._both(*args)[0]
        elif self._jacobian is None:
            s, x, force, prescribed = g.mx_in()
            value = g(s, x, force, prescribed)
            jacobian = ca.Function(
                "dg_ds",
                [s, x, force, prescribed],
                [ca.jacobian(value, s)],
                ["s", "x", "F_B", "d"],
                ["dg_ds"],
            )
            self._jacobian = SparseEvaluator(jacobian)
        self.n_state = g.size1_in(0)
        self._cache = None

    def _x(self, x) -> np.ndarray:
        x = np.asarray([] if x is None else x, dtype=float).reshape(-1)
        if x.size != len(self.names):
            raise ValueError(f"expected {len(self.names)} values for {self.names}, got {x.size}")
        return x

    def solve(
        self, force: np.ndarray, x=None, prescribed=None, start=None, factor=None, label=""
    ) -> Equilibrium:
        """Solve for the equilibrium under one load case.

        Parameters
        ----------
        force : numpy.ndarray
            F_B on the free points, (n_free, 3) [N] (``model.generalized_force``).
        x : array_like, optional
            Values of the symbolic parameters ``names``.
        prescribed : numpy.ndarray, optional
            d, prescribed displacements (m, 3) [mm].
        start : numpy.ndarray, optional
            Initial state s (default zero: the rest shape).
        factor : scipy.sparse.linalg.SuperLU, optional
            An LU of dg/ds near ``start`` (a previous equilibrium's), for the first steps
            (ignored by the linear model, which has its own at x).
        label : str
            The load case's name, for the error message.

        Raises
        ------
        EquilibriumError
            When the relative residual does not reach the tolerance.
        """
        x = self._x(x)
        rows = self.model._constraint_rows.shape[1]
        prescribed = np.zeros((rows, 3)) if prescribed is None else np.asarray(prescribed, float)
        if self.scalar is not None:
            return self._solve_scalar(np.asarray(force, dtype=float), x, prescribed)
        args = (x, np.asarray(force, dtype=float), prescribed)
        scale = self._load_norm(*args[1:]) or 1.0
        state = np.zeros(self.n_state) if start is None else np.array(start, dtype=float)
        g = self._residual(state, args)
        history = [_norm(g) / scale]
        if self.linear:  # dg/ds is constant: its own LU at x, shared by the load cases
            factor = self._linear_factor(state, args)
        iterations = 0
        while history[-1] > self.settings.tolerance:
            if iterations == self.settings.max_iterations or not np.isfinite(history[-1]):
                case = f" for {label}" if label else ""
                raise EquilibriumError(
                    f"Newton did not converge in {iterations} iterations{case} "
                    f"(relative residual {history[-1]:.2e} > "
                    f"{self.settings.tolerance:.0e}); reduce the load or the stiffening, or "
                    "give a better start"
                )
            fresh = factor is None
            if fresh:
                factor = self._factorized(state, args)
            step = factor.solve(-g)
            state, g = self._line_search(state, step, g, args)
            history.append(_norm(g) / scale)
            iterations += 1
            contracts = history[-1] <= CHORD_CONTRACTION * history[-2]
            if not self.linear and not (contracts and (self.settings.reuse_lu or not fresh)):
                factor = None  # full Newton, or the LU no longer contracts: a fresh one
        return self._equilibrium(state, args, factor, iterations, history)

    def _equilibrium(self, state, args, factor, iterations, history) -> Equilibrium:
        """The converged state with dg/ds (and dg/dx if closed-form) at it and an LU:
        the linear model's own; else Newton's last, exact only if made here."""
        parameter_jacobian = None
        if self._both is not None:
            jacobian, parameter_jacobian = self._both(state, *args)
        elif self.linear:  # constant: the one the LU was made of
            jacobian = self._cache[1]
        else:
            jacobian = self._jacobian(state, *args)
        if self.linear:
            exact = True
        elif factor is None:
            factor, exact = _lu(jacobian), True
        else:
            exact = False
        n_points = 3 * self.model.n_free
        delta = state[:n_points].reshape(3, -1).T
        return Equilibrium(
            positions=self.model.full_positions(delta),
            state=state,
            multipliers=state[n_points:].reshape(3, -1).T,
            iterations=iterations,
            residual_history=history,
            jacobian=sp.csc_matrix(jacobian),
            factor=factor,
            exact=exact,
            parameter_jacobian=parameter_jacobian,
        )

    def solve_by_continuation(
        self, force, x, prescribed, label="", steps: int = 4, halvings: int = 3
    ) -> Equilibrium:
        """Equilibrium by load continuation: Newton at t (F_B, d) for t rising from 0 to
        1 in ``steps`` steps, each started from the last state scaled by the load ratio;
        a step whose Newton fails is halved (at most ``halvings`` times in a row).

        For a stiffening model far from its rest state, where Newton from rest fails.
        """
        prescribed = np.asarray(prescribed, dtype=float)
        t, dt, previous, failures = 0.0, 1.0 / steps, None, 0
        while t < 1.0:
            target = min(1.0, t + dt)
            start = None if previous is None else previous.state * (target / t)
            try:
                previous = self.solve(target * force, x, target * prescribed, start, None, label)
            except EquilibriumError:
                failures += 1
                if failures > halvings:
                    raise
                dt *= 0.5
                continue
            t, failures = target, 0
        return previous

    def _load_norm(self, force: np.ndarray, prescribed: np.ndarray) -> float:
        """|g(0)| = |[F_B; C d]|, the scale of the relative residual: every model's rest
        state is stress-free, so g at rest is the load alone (tested)."""
        constraint = self.model._constraint_rows @ prescribed
        return float(np.sqrt(np.sum(force**2) + np.sum(constraint**2)))

    def _residual(self, state: np.ndarray, args: tuple) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):  # exp stiffening may overflow
            return self.residual(state, *args).full().ravel()

    def _solve_scalar(self, force: np.ndarray, x: np.ndarray, prescribed: np.ndarray):
        """The linear model: one solve on the scalar block, factorised once per x."""
        if self._cache is None or not np.array_equal(self._cache.x, x):
            self._cache = self.scalar.factor(x)
        factor = self._cache
        state = self.scalar.state(factor, force, prescribed)
        right = np.vstack([force, self.scalar.reduce @ prescribed])
        n = self.model.n_free
        blocks = np.vstack([state[: 3 * n].reshape(3, n).T, state[3 * n :].reshape(3, -1).T])
        scale = float(np.linalg.norm(right)) or 1.0
        residual = float(np.linalg.norm(factor.stiffness @ blocks - right)) / scale
        if not residual <= self.settings.tolerance:
            raise EquilibriumError(
                f"the linear system is singular or ill-conditioned (relative residual "
                f"{residual:.2e}); check the boundary conditions and parameters"
            )
        delta = state[: 3 * n].reshape(3, -1).T
        return Equilibrium(
            positions=self.model.full_positions(delta),
            state=state,
            multipliers=state[3 * n :].reshape(3, -1).T,
            iterations=1,
            residual_history=[1.0, residual],
            jacobian=None,
            factor=factor,
        )

    def jacobian(self, state, x, force, prescribed) -> sp.csc_matrix:
        """dg/ds at a state (the KKT matrix of the nonlinear model), scipy CSC."""
        return sp.csc_matrix(self._jacobian(state, x, force, prescribed))

    def _factorized(self, state: np.ndarray, args: tuple):
        """An LU of dg/ds at ``state``."""
        return _lu(self._jacobian_at(state, args))

    def _jacobian_at(self, state: np.ndarray, args: tuple):
        try:
            return self._jacobian(state, *args)
        except ValueError as error:  # e.g. an inverted element of the neo-Hookean model
            raise EquilibriumError(f"{error}; reduce the load or give a better start") from None

    def _linear_factor(self, state: np.ndarray, args: tuple):
        """The linear model's dg/ds and LU, cached per x (shared by load cases)."""
        x = args[0]
        if self._cache is None or not np.array_equal(self._cache[0], x):
            jacobian = self._jacobian_at(state, args)
            self._cache = (np.array(x), jacobian, _lu(jacobian))
        return self._cache[2]

    def _line_search(self, state, step, g, args):
        """Full step, halved while the residual norm does not decrease."""
        norm = _norm(g)
        trial = state + step
        g_trial = self._residual(trial, args)
        if not self.settings.line_search:
            return trial, g_trial
        length = 1.0
        for _ in range(30):
            if _norm(g_trial) < norm or _norm(g_trial) == 0.0:
                break
            length *= 0.5
            trial = state + length * step
            g_trial = self._residual(trial, args)
        return trial, g_trial
