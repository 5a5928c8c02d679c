"""Stiffness imaging: the regularised field estimate, three ways, and its weight.

The estimate minimises (docs/imaging.md)

    J(c) = Phi_d(c) + beta R(c)                                                      (I8)

over the N field coefficients (``solvers.imaging.fieldproblem``,
``solvers.imaging.regularization``).

Every method has the inverse's shape (``solvers.inverse.methods``): built once on the
problem, here the ``FieldProblem`` and its regulariser, ``solve(weight, start)`` returns a
``FieldEstimate``; ``SOLVERS`` names them (``dvs image --method``).

- ``GaussNewtonSolver(..., hessian="adjoint")``: nested, matrix-free. Each Gauss-Newton
  step solves (J^T J + beta R'') p = -grad by conjugate gradients, each product
  J^T J v costing one forward and one adjoint solve per case with the factorisation
  of the current c; the N-column sensitivity is never formed.
- ``GaussNewtonSolver(..., hessian="sensitivity")``: nested, implicit-function route: J
  formed column by column (N solves per case), the step by a dense solve.
- ``LbfgsSolver``: nested, L-BFGS-B on J(c) with the adjoint gradient.
- ``FieldSimultaneousSolver``: the coefficients and every case's state are the variables of one
  IPOPT NLP, the equilibria (eq. I3) its equality constraints.

``solvers.imaging.laplace`` gives the posterior standard deviations around an estimate; the weight
beta is chosen in ``solvers.imaging.weight``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial

import casadi as ca
import numpy as np
import scipy.optimize as so
import scipy.sparse.linalg as spla

from solvers.imaging.fieldproblem import FieldProblem
from solvers.inverse.simultaneous import static_defaults
from symbolic.continuum import KPA
from symbolic.sparse import to_casadi_sparse


@dataclass
class FieldEstimate:
    """One regularised estimate (eq. I8).

    Attributes
    ----------
    coefficients : numpy.ndarray
        c, (N,): s = log(E / E_ref) at the field's nodes (degree 1).
    weight : float
        beta [mm^2].
    chi2 : float
        |r|^2, the whitened misfit (expectation n_residuals under pure noise).
    regularization : float
        R(c).
    rms_um : float
        RMS marker distance [um].
    iterations, seconds : int, float
        Outer iterations and wall time [s].
    method, success, message : str, bool, str
        Which solver, and how it ended.
    """

    coefficients: np.ndarray
    weight: float
    chi2: float
    regularization: float
    rms_um: float
    iterations: int
    seconds: float
    method: str
    success: bool
    message: str = ""
    jacobian: np.ndarray | None = field(default=None, repr=False)
    """J = dr/dc at ``coefficients`` when the solver formed it there (the sensitivity
    route), so that ``laplace`` need not form it again; else None."""


class FieldSolver:
    """What every imaging method shares: the problem it is built on, J(c) and its result.

    Parameters
    ----------
    fp : FieldProblem
        The field behind the markers and their data.
    regularizer : Tikhonov or TotalVariation
        R(c).
    """

    name = ""

    def __init__(self, fp: FieldProblem, regularizer):
        self.problem, self.regularizer = fp, regularizer

    def solve(self, weight: float, start: np.ndarray | None = None) -> FieldEstimate:
        """The estimate at beta = ``weight`` [mm^2] from ``start`` (default c = 0)."""
        raise NotImplementedError

    def objective(self, weight: float, c: np.ndarray) -> float:
        """J(c) of eq. (I8)."""
        return self.problem.forward(c).misfit + weight * self.regularizer.value(c)

    def safe_objective(self, weight: float, c: np.ndarray) -> float:
        """J(c), or infinity where the equilibrium cannot be solved (E under- or
        overflows)."""
        try:
            value = self.objective(weight, c)
        except RuntimeError:  # SuperLU: "Factor is exactly singular"
            return np.inf
        return value if np.isfinite(value) else np.inf

    def start(self, start: np.ndarray | None) -> np.ndarray:
        """c at the start: a copy of ``start``, or the homogeneous field."""
        size = self.problem.size
        return np.zeros(size) if start is None else np.asarray(start, dtype=float).copy()

    def estimate(
        self, weight, c, iterations, begin, success, message, jacobian=None
    ) -> FieldEstimate:
        """The ``FieldEstimate`` at c, timed from ``begin``."""
        fp = self.problem
        return FieldEstimate(
            np.asarray(c, dtype=float).copy(),
            float(weight),
            2.0 * fp.forward(c).misfit,
            float(self.regularizer.value(c)),
            fp.rms_um(c),
            int(iterations),
            time.perf_counter() - begin,
            self.name,
            bool(success),
            message,
            jacobian,
        )


MAX_STEP = 1.0
"""Largest change of s = log(E / E_ref) at any node in one Gauss-Newton step (E x e)."""


def secant_update(S: np.ndarray, step, y, y_sharp) -> np.ndarray:
    """The structured secant update of the residual-curvature term S (NL2SOL).

    S approximates sum_i r_i grad^2 r_i, the part of the Hessian of Phi_d that
    Gauss-Newton leaves out; the update (Dennis, Gay and Welsch 1981, ACM TOMS 7)
    makes S step = y# with y# = (J_new - J_old)^T r_new, symmetric and closest to
    the sized S, where y is the change of J^T r. Skipped (S returned) when y . step
    <= 0.
    """
    curvature = float(y @ step)
    if curvature <= 1e-12 * np.linalg.norm(y) * np.linalg.norm(step):
        return S
    size = abs(float(step @ S @ step))
    if size > 0:
        S = min(1.0, abs(float(step @ y_sharp)) / size) * S
    w = y_sharp - S @ step
    return (
        S
        + (np.outer(w, y) + np.outer(y, w)) / curvature
        - float(w @ step) * np.outer(y, y) / curvature**2
    )


def _cg_step(fp, state, prior, curvature, gradient, forcing) -> np.ndarray:
    """p from (J^T J + S + beta R'') p = -grad by CG, J^T J v by a jvp and a vjp at the
    kept ``state`` (``FieldProblem.forward``); S is left out when None."""

    def product(v):
        out = fp.vjp_at(state, fp.jvp_at(state, v)) + prior @ v
        return out if curvature is None else out + curvature @ v

    operator = spla.LinearOperator((fp.size, fp.size), matvec=product)
    step, _ = spla.cg(operator, -gradient, rtol=forcing * 1e-2, maxiter=4 * fp.size)
    return step


class GaussNewtonSolver(FieldSolver):
    """Gauss-Newton on eq. (I8) with a backtracking line search.

    Stops when the Newton decrement -grad . p / 2 falls below ``tolerance`` times
    J(c) (the objective can fall by no more than that). With noise and model error in
    the data Gauss-Newton alone converges linearly (it leaves out the residual's
    curvature; a factor of about 0.7 per step and 79 iterations at N = 16 on the
    9 x 9 x 2 benchmark), so by default (``secant``) the step solves
    (J^T J + S + beta R'') p = -grad with S from ``secant_update`` whenever that
    model predicted the last step's decrease better than Gauss-Newton's (the adaptive
    choice of NL2SOL), and plain Gauss-Newton otherwise or when the augmented step is
    not a descent direction. A step is shortened to ``MAX_STEP`` at its largest node,
    and a trial whose equilibrium cannot be solved counts as an increase.

    Parameters
    ----------
    fp, regularizer
        As ``FieldSolver``.
    hessian : {"adjoint", "sensitivity"}
        J^T J v matrix-free by CG, or J formed and the step by a dense solve.
    tolerance : float
        Relative Newton decrement at which it stops.
    max_iterations : int
        Cap on Gauss-Newton steps.
    secant : bool
        The NL2SOL residual-curvature term.
    """

    def __init__(
        self,
        fp: FieldProblem,
        regularizer,
        hessian: str = "adjoint",
        tolerance: float = 1e-13,
        max_iterations: int = 200,
        secant: bool = True,
    ):
        if hessian not in ("adjoint", "sensitivity"):
            raise ValueError("hessian must be 'adjoint' or 'sensitivity'")
        super().__init__(fp, regularizer)
        self.hessian, self.tolerance = hessian, tolerance
        self.max_iterations, self.secant = max_iterations, secant
        self.name = f"gn-{hessian}"

    def solve(self, weight: float, start: np.ndarray | None = None) -> FieldEstimate:
        """The estimate at beta = ``weight`` [mm^2] from ``start`` (default c = 0)."""
        fp, begin, c = self.problem, time.perf_counter(), self.start(start)
        value = self.objective(weight, c)

        def finish(iterations: int, success: bool, message: str, at_c=None) -> FieldEstimate:
            return self.estimate(weight, c, iterations, begin, success, message, at_c)

        first, last, augmented = None, None, False
        curvature = np.zeros((fp.size, fp.size)) if self.secant else None
        for iteration in range(1, self.max_iterations + 1):
            # the factorisation at c is kept: the line search's trials replace the problem's
            # cached one, and the secant update needs the previous c's as well
            state = fp.forward(c)
            prior = weight * self.regularizer.hessian(c)
            jac = fp.sensitivities(c) if self.hessian == "sensitivity" else None
            misfit_gradient = (
                fp.vjp_at(state, state.residual) if jac is None else jac.T @ state.residual
            )
            if self.secant and last is not None:
                old_c, old_state, old_jac, old_gradient = last
                old_product = (
                    fp.vjp_at(old_state, state.residual)
                    if old_jac is None
                    else old_jac.T @ state.residual
                )
                curvature = secant_update(
                    curvature,
                    c - old_c,
                    misfit_gradient - old_gradient,
                    misfit_gradient - old_product,
                )
            last = (c.copy(), state, jac, misfit_gradient)
            gradient = misfit_gradient + weight * self.regularizer.gradient(c)
            extra = curvature if augmented else None
            if self.hessian == "sensitivity":
                base = jac.T @ jac + prior.toarray()
                step = np.linalg.solve(base if extra is None else base + extra, -gradient)
                if float(gradient @ step) >= 0:  # not a descent direction: plain GN
                    step, augmented = np.linalg.solve(base, -gradient), False
            else:
                first = np.linalg.norm(gradient) if first is None else first
                forcing = min(0.1, np.sqrt(np.linalg.norm(gradient) / first))
                step = _cg_step(fp, state, prior, extra, gradient, forcing)
                if extra is not None and float(gradient @ step) >= 0:  # indefinite: plain GN
                    step, augmented = _cg_step(fp, state, prior, None, gradient, forcing), False
            decrement = -0.5 * float(gradient @ step)
            if decrement <= self.tolerance * max(value, 1.0):
                return finish(iteration, True, "converged", jac)
            length = min(1.0, MAX_STEP / max(float(np.abs(step).max()), 1e-300))
            while length > 1e-8:
                trial = c + length * step
                trial_value = self.safe_objective(weight, trial)
                if trial_value <= value - 1e-4 * length * 2.0 * decrement:
                    break
                length *= 0.5
            else:
                return finish(iteration, False, "line search failed", jac)
            if self.secant:  # the next step: the model that predicted this decrease better
                taken = length * step
                linear = jac @ taken if jac is not None else fp.jvp_at(state, taken)
                plain = float(gradient @ taken + 0.5 * (linear @ linear + taken @ (prior @ taken)))
                with_s = plain + 0.5 * float(taken @ curvature @ taken)
                actual = trial_value - value
                augmented = abs(with_s - actual) < abs(plain - actual)
            c, value = trial, trial_value
        return finish(self.max_iterations, False, "iteration limit")


class LbfgsSolver(FieldSolver):
    """L-BFGS-B on eq. (I8) with the adjoint gradient (no bounds)."""

    name = "l-bfgs-b"

    def __init__(self, fp, regularizer, tolerance=1e-12, max_iterations=2000):
        super().__init__(fp, regularizer)
        self.tolerance, self.max_iterations = tolerance, max_iterations

    def solve(self, weight: float, start: np.ndarray | None = None) -> FieldEstimate:
        """The estimate at beta = ``weight`` [mm^2] from ``start`` (default c = 0)."""
        begin, gradient = time.perf_counter(), self.regularizer.gradient

        def value_and_gradient(c):
            total = self.objective(weight, c)
            return total, self.problem.gradient(c) + weight * gradient(c)

        options = {"ftol": self.tolerance, "gtol": 1e-9, "maxiter": self.max_iterations}
        result = so.minimize(
            value_and_gradient,
            self.start(start),
            jac=True,
            method="L-BFGS-B",
            options={**options, "maxcor": 30},
        )
        message = str(result.message)
        return self.estimate(weight, result.x, result.nit, begin, result.success, message)


class FieldSimultaneousSolver(FieldSolver):
    """One IPOPT NLP over c and every case's state s_k, eq. (I3) as constraints.

    The NLP takes beta as a parameter, so it is built once per problem, regulariser
    and options (kept in ``fp.nlp_cache``) and reused for every weight Morozov tries.
    """

    name = "simultaneous"

    def __init__(self, fp, regularizer, tolerance=1e-10, options=None):
        super().__init__(fp, regularizer)
        key = (id(regularizer), tolerance, repr(sorted((options or {}).items())))
        if key not in fp.nlp_cache:
            fp.nlp_cache[key] = (regularizer, _imaging_nlp(fp, regularizer, tolerance, options))
        self.solver = fp.nlp_cache[key][1]

    def solve(self, weight: float, start: np.ndarray | None = None) -> FieldEstimate:
        """The estimate at beta = ``weight`` [mm^2] from ``start`` (default c = 0)."""
        begin, c0 = time.perf_counter(), self.start(start)
        at_start = self.problem.forward(c0)
        states = np.ravel(np.column_stack(at_start.states), order="F")
        solution = self.solver(
            x0=np.concatenate([c0, states, at_start.raw]), p=weight, lbg=0.0, ubg=0.0
        )
        stats = self.solver.stats()
        c = np.asarray(solution["x"]).ravel()[: self.problem.size]
        success, message = stats["success"], stats["return_status"]
        return self.estimate(weight, c, stats["iter_count"], begin, success, message)


def _imaging_nlp(fp, regularizer, tolerance, options) -> ca.Function:
    """The NLP of ``simultaneous``: variables [c; vec(s); r], parameter beta."""
    n_state, n_cases = fp.right_hand_sides.shape
    c = ca.MX.sym("c", fp.size)
    states = ca.MX.sym("s", n_state, n_cases)
    weight = ca.MX.sym("beta")
    g_matrix = to_casadi_sparse(fp.G)
    per_point = ca.DM(fp.volume * KPA * fp.reference_kpa) * ca.exp(
        ca.mtimes(to_casadi_sparse(fp.Phi), c)
    )
    h = ca.vertcat(*[float(f) * per_point for f in fp.moduli])
    n = fp.n_displacement
    coupling = to_casadi_sparse(fp.coupling) if fp.coupling.shape[0] else None
    constraints, raw = [], []
    for k in range(n_cases):
        delta = states[:n, k]
        force = ca.mtimes(g_matrix.T, h * ca.mtimes(g_matrix, delta))
        if coupling is None:
            constraints.append(force)
        else:  # the rows of eq. (I3): K Delta + C^T lam = F, C Delta = Q d
            constraints.append(force + ca.mtimes(coupling.T, states[n:, k]))
            constraints.append(ca.mtimes(coupling, delta))
        raw.append(ca.mtimes(to_casadi_sparse(fp.A[k]), states[:, k]) + ca.DM(fp.b[k]))
    # the residual lifted too: the whitening couples every case through the shared
    # rest markers, and W^T W on the residual is far sparser than A^T W^T W A on states
    markers = ca.MX.sym("r", fp.n_residuals)
    residual = ca.mtimes(to_casadi_sparse(fp.whitening), markers)
    f = 0.5 * ca.dot(residual, residual) + weight * regularizer.expression(c)
    g = ca.vertcat(
        ca.vertcat(*constraints) - ca.DM(np.ravel(fp.right_hand_sides, order="F")),
        markers - ca.vertcat(*raw),
    )
    variables = ca.vertcat(c, ca.vec(states), markers)
    settings = {
        **static_defaults(variables.numel()),  # MUMPS ordering and pivoting by size
        "ipopt.print_level": 0,
        "print_time": False,
        "ipopt.tol": tolerance,
        "ipopt.max_iter": 200,
        "ipopt.sb": "yes",
        **(options or {}),
    }
    nlp = {"x": variables, "p": weight, "f": f, "g": g}
    return ca.nlpsol("imaging", "ipopt", nlp, settings)


SOLVERS = {
    "simultaneous": FieldSimultaneousSolver,
    "nested-adjoint": partial(GaussNewtonSolver, hessian="adjoint"),
    "nested-sensitivity": partial(GaussNewtonSolver, hessian="sensitivity"),
    "l-bfgs-b": LbfgsSolver,
}
"""The methods by name (``dvs image --method``): ``SOLVERS[name](fp, regularizer)``."""
