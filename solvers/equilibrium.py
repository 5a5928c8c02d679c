"""Static forward solve of K(B; x)(B - B0) = F_B by Newton's method (docs/model.md, eq. 22).

The residual and its sparse Jacobian come from CasADi; each Newton step is one
sparse LU solve (SuperLU through scipy, symmetric minimum-degree ordering). A
backtracking line search on |g| guards the nonlinear model; near the solution full
steps give quadratic convergence. The linear model (k0 = 0) is solved in one step on
its scalar block instead (``solvers.componentwise``), without building any CasADi
Function.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.componentwise import ORDERING, ScalarSystem
from symbolic.model import TissueModel


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
    """

    tolerance: float = 1e-10
    max_iterations: int = 30
    line_search: bool = True

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
        dg/ds at the solution (for sensitivities).
    factor : scipy.sparse.linalg.SuperLU
        Its LU factorisation, for sensitivity solves without refactorising.
    """

    positions: np.ndarray
    state: np.ndarray
    multipliers: np.ndarray
    iterations: int
    residual_history: list[float] = field(default_factory=list)
    jacobian: sp.csc_matrix | None = None
    factor: object | None = None


class SparseEvaluator:
    """Evaluates a CasADi Function with sparse outputs straight into scipy CSC matrices.

    The outputs' patterns are read once; each call writes the nonzeros into numpy
    buffers through ``Function.buffer`` (no Python lists, no DM).
    """

    def __init__(self, function: ca.Function):
        self.buffer, self.trigger = function.buffer()
        self.patterns, self.outputs = [], []
        for i in range(function.n_out()):
            pattern = function.sparsity_out(i)
            indptr, indices = (np.asarray(v) for v in pattern.get_ccs())
            self.patterns.append((indptr, indices, pattern.shape))
            self.outputs.append(np.zeros(pattern.nnz()))
            self.buffer.set_res(i, memoryview(self.outputs[-1]))
        self._inputs: list = []

    def evaluate(self, *args) -> list[sp.csc_matrix]:
        """Every output at the inputs (numpy arrays, vec'd column-major as CasADi does)."""
        self._inputs = [np.ascontiguousarray(np.asarray(a, dtype=float).T.ravel()) for a in args]
        for i, value in enumerate(self._inputs):
            self.buffer.set_arg(i, memoryview(value))
        self.trigger()
        return [
            sp.csc_matrix((values.copy(), indices, indptr), shape=shape)
            for values, (indptr, indices, shape) in zip(self.outputs, self.patterns)
        ]

    def __call__(self, *args) -> sp.csc_matrix:
        """The first output."""
        return self.evaluate(*args)[0]


def casadi_to_scipy(matrix: ca.DM) -> sp.csc_matrix:
    """A CasADi sparse DM as a scipy CSC matrix."""
    pattern = matrix.sparsity()
    indptr, indices = pattern.get_ccs()
    return sp.csc_matrix((np.asarray(matrix.nonzeros()), indices, indptr), shape=matrix.shape)


def kkt_jacobian(model: TissueModel, names: tuple[str, ...]):
    """dg/ds(s, x, F_B, d) = [[K_T, C^T], [C, 0]] from the model's numeric tangent
    (``TissueModel.tangent``), as scipy CSC; None when the model has none (use AD)."""
    tangent = model.tangent(tuple(names))
    if tangent is None:
        return None
    coupling = sp.kron(sp.identity(3), model._constraint_free).tocsc()

    def jacobian(state, x, force, prescribed) -> sp.csc_matrix:
        matrix = tangent(state, x)
        if coupling.shape[0] == 0:
            return matrix
        return sp.bmat([[matrix, coupling.T], [coupling, None]], format="csc")

    return jacobian


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
        self._jacobian = kkt_jacobian(model, self.names)
        if self._jacobian is None:
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

    def solve(self, force: np.ndarray, x=None, prescribed=None, start=None) -> Equilibrium:
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
        state = np.zeros(self.n_state) if start is None else np.array(start, dtype=float)
        scale = float(np.linalg.norm(self.residual(np.zeros(self.n_state), *args).full()))
        if scale == 0.0:
            scale = 1.0
        g = self.residual(state, *args).full().ravel()
        history = [float(np.linalg.norm(g)) / scale]
        iterations = 0
        while history[-1] > self.settings.tolerance:
            if iterations == self.settings.max_iterations:
                raise EquilibriumError(
                    f"Newton did not converge in {iterations} iterations (relative residual "
                    f"{history[-1]:.2e} > {self.settings.tolerance:.0e}); reduce the load or "
                    "the stiffening k0, or give a better start"
                )
            jacobian, factor = self._factorized(state, args)
            step = factor.solve(-g)
            state, g = self._line_search(state, step, g, args)
            history.append(float(np.linalg.norm(g)) / scale)
            iterations += 1
        if not (self.linear and iterations > 0):  # a linear model's Jacobian is constant
            jacobian, factor = self._factorized(state, args)
        n_points = 3 * self.model.n_free
        delta = state[:n_points].reshape(3, -1).T
        return Equilibrium(
            positions=self.model.full_positions(delta),
            state=state,
            multipliers=state[n_points:].reshape(3, -1).T,
            iterations=iterations,
            residual_history=history,
            jacobian=jacobian,
            factor=factor,
        )

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

    def _factorized(self, state: np.ndarray, args: tuple):
        """dg/ds and its LU; for the linear model cached per x (shared by load cases)."""
        x = args[0]
        if self.linear and self._cache is not None and np.array_equal(self._cache[0], x):
            return self._cache[1], self._cache[2]
        try:
            jacobian = self._jacobian(state, *args)
        except ValueError as error:  # e.g. an inverted element of the neo-Hookean model
            raise EquilibriumError(f"{error}; reduce the load or give a better start") from None
        factor = spla.splu(jacobian, **ORDERING)
        if self.linear:
            self._cache = (np.array(x), jacobian, factor)
        return jacobian, factor

    def _line_search(self, state, step, g, args):
        """Full step, halved while the residual norm does not decrease."""
        norm = np.linalg.norm(g)
        trial = state + step
        g_trial = self.residual(trial, *args).full().ravel()
        if not self.settings.line_search:
            return trial, g_trial
        length = 1.0
        for _ in range(30):
            if np.linalg.norm(g_trial) < norm or np.linalg.norm(g_trial) == 0.0:
                break
            length *= 0.5
            trial = state + length * step
            g_trial = self.residual(trial, *args).full().ravel()
        return trial, g_trial
