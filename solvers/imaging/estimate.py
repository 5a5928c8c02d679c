"""Stiffness imaging: the regularised field estimate, three ways, and its weight.

The estimate minimises (docs/imaging.md)

    J(c) = Phi_d(c) + beta R(c)                                                      (I8)

over the N field coefficients (``solvers.imaging.fieldproblem``,
``solvers.imaging.regularization``).

- ``gauss_newton(..., hessian="adjoint")``: nested, matrix-free. Each Gauss-Newton
  step solves (J^T J + beta R'') p = -grad by conjugate gradients, each product
  J^T J v costing one forward and one adjoint solve per case with the factorisation
  of the current c; the N-column sensitivity is never formed.
- ``gauss_newton(..., hessian="sensitivity")``: nested, implicit-function route: J
  formed column by column (N solves per case), the step by a dense solve.
- ``lbfgs``: nested, L-BFGS-B on J(c) with the adjoint gradient.
- ``simultaneous``: the coefficients and every case's state are the variables of one
  IPOPT NLP, the equilibria (eq. I3) its equality constraints.

``solvers.imaging.laplace`` gives the posterior standard deviations around an estimate; the weight
beta is chosen in ``solvers.imaging.weight``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

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


def objective(fp: FieldProblem, regularizer, weight: float, c: np.ndarray) -> float:
    """J(c) of eq. (I8)."""
    return fp.forward(c).misfit + weight * regularizer.value(c)


def _estimate(
    fp, regularizer, weight, c, iterations, begin, method, success, message, jacobian=None
):
    return FieldEstimate(
        np.asarray(c, dtype=float).copy(),
        float(weight),
        2.0 * fp.forward(c).misfit,
        float(regularizer.value(c)),
        fp.rms_um(c),
        int(iterations),
        time.perf_counter() - begin,
        method,
        bool(success),
        message,
        jacobian,
    )


MAX_STEP = 1.0
"""Largest change of s = log(E / E_ref) at any node in one Gauss-Newton step (E x e)."""


def _safe_objective(fp, regularizer, weight, c) -> float:
    """J(c), or infinity where the equilibrium cannot be solved (E under- or overflows)."""
    try:
        value = objective(fp, regularizer, weight, c)
    except RuntimeError:  # SuperLU: "Factor is exactly singular"
        return np.inf
    return value if np.isfinite(value) else np.inf


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


def gauss_newton(
    fp: FieldProblem,
    regularizer,
    weight: float,
    start: np.ndarray | None = None,
    hessian: str = "adjoint",
    tolerance: float = 1e-13,
    max_iterations: int = 200,
    secant: bool = True,
) -> FieldEstimate:
    """Gauss-Newton on eq. (I8) with a backtracking line search.

    Stops when the Newton decrement -grad . p / 2 falls below ``tolerance`` times
    J(c) (the objective can fall by no more than that). With noise and model error in
    the data Gauss-Newton alone converges linearly (it leaves out the residual's
    curvature; a factor of about 0.7 per step and 79 iterations at N = 16 on the
    9 x 9 x 2 benchmark), so by default (``secant``) the step solves
    (J^T J + S + beta R'') p = -grad with S from ``secant_update`` whenever that
    model predicted the last step's decrease better than Gauss-Newton's (the adaptive
    choice of NL2SOL), and plain Gauss-Newton otherwise or when the augmented step is
    not a descent direction. A step
    is shortened to ``MAX_STEP`` at its largest node, and a trial whose equilibrium
    cannot be solved counts as an increase.
    """
    if hessian not in ("adjoint", "sensitivity"):
        raise ValueError("hessian must be 'adjoint' or 'sensitivity'")
    begin = time.perf_counter()
    c = np.zeros(fp.size) if start is None else np.asarray(start, dtype=float).copy()
    value = objective(fp, regularizer, weight, c)

    def finish(iterations: int, success: bool, message: str, at_c=None) -> FieldEstimate:
        method = f"gn-{hessian}"
        return _estimate(
            fp, regularizer, weight, c, iterations, begin, method, success, message, at_c
        )

    first, last, augmented = None, None, False
    curvature = np.zeros((fp.size, fp.size)) if secant else None
    for iteration in range(1, max_iterations + 1):
        # the factorisation at c is kept: the line search's trials replace the problem's
        # cached one, and the secant update needs the previous c's as well
        state = fp.forward(c)
        prior = weight * regularizer.hessian(c)
        jac = fp.sensitivities(c) if hessian == "sensitivity" else None
        misfit_gradient = (
            fp.vjp_at(state, state.residual) if jac is None else jac.T @ state.residual
        )
        if secant and last is not None:
            old_c, old_state, old_jac, old_gradient = last
            old_product = (
                fp.vjp_at(old_state, state.residual)
                if old_jac is None
                else old_jac.T @ state.residual
            )
            curvature = secant_update(
                curvature, c - old_c, misfit_gradient - old_gradient, misfit_gradient - old_product
            )
        last = (c.copy(), state, jac, misfit_gradient)
        gradient = misfit_gradient + weight * regularizer.gradient(c)
        extra = curvature if augmented else None
        if hessian == "sensitivity":
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
        if decrement <= tolerance * max(value, 1.0):
            return finish(iteration, True, "converged", jac)
        length = min(1.0, MAX_STEP / max(float(np.abs(step).max()), 1e-300))
        while length > 1e-8:
            trial = c + length * step
            trial_value = _safe_objective(fp, regularizer, weight, trial)
            if trial_value <= value - 1e-4 * length * 2.0 * decrement:
                break
            length *= 0.5
        else:
            return finish(iteration, False, "line search failed", jac)
        if secant:  # the next step uses the model that predicted this one's decrease better
            taken = length * step
            linear = jac @ taken if jac is not None else fp.jvp_at(state, taken)
            plain = float(gradient @ taken + 0.5 * (linear @ linear + taken @ (prior @ taken)))
            with_s = plain + 0.5 * float(taken @ curvature @ taken)
            actual = trial_value - value
            augmented = abs(with_s - actual) < abs(plain - actual)
        c, value = trial, trial_value
    return finish(max_iterations, False, "iteration limit")


def lbfgs(fp, regularizer, weight, start=None, tolerance=1e-12, max_iterations=2000):
    """L-BFGS-B on eq. (I8) with the adjoint gradient (no bounds)."""
    begin = time.perf_counter()
    c0 = np.zeros(fp.size) if start is None else np.asarray(start, dtype=float)

    def value_and_gradient(c):
        total = objective(fp, regularizer, weight, c)
        return total, fp.gradient(c) + weight * regularizer.gradient(c)

    result = so.minimize(
        value_and_gradient,
        c0,
        jac=True,
        method="L-BFGS-B",
        options={"ftol": tolerance, "gtol": 1e-9, "maxiter": max_iterations, "maxcor": 30},
    )
    return _estimate(
        fp,
        regularizer,
        weight,
        result.x,
        result.nit,
        begin,
        "l-bfgs-b",
        result.success,
        str(result.message),
    )


def simultaneous(fp, regularizer, weight, start=None, tolerance=1e-10, options=None):
    """One IPOPT NLP over c and every case's state s_k, eq. (I3) as constraints.

    The NLP takes beta as a parameter, so it is built once per problem, regulariser
    and options (kept in ``fp.nlp_cache``) and reused for every weight Morozov tries.
    """
    begin = time.perf_counter()
    c0 = np.zeros(fp.size) if start is None else np.asarray(start, dtype=float)
    key = (id(regularizer), tolerance, repr(sorted((options or {}).items())))
    if key not in fp.nlp_cache:
        fp.nlp_cache[key] = (regularizer, _imaging_nlp(fp, regularizer, tolerance, options))
    solver = fp.nlp_cache[key][1]
    start_state = fp.forward(c0)
    x0 = np.concatenate(
        [c0, np.ravel(np.column_stack(start_state.states), order="F"), start_state.raw]
    )
    solution = solver(x0=x0, p=weight, lbg=0.0, ubg=0.0)
    stats = solver.stats()
    coefficients = np.asarray(solution["x"]).ravel()[: fp.size]
    return _estimate(
        fp,
        regularizer,
        weight,
        coefficients,
        stats["iter_count"],
        begin,
        "simultaneous",
        stats["success"],
        stats["return_status"],
    )


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
    "simultaneous": simultaneous,
    "nested-adjoint": lambda fp, r, w, start=None: gauss_newton(fp, r, w, start, "adjoint"),
    "nested-sensitivity": lambda fp, r, w, start=None: gauss_newton(fp, r, w, start, "sensitivity"),
    "l-bfgs-b": lbfgs,
}
"""The formulations by name (``dvs image --method``)."""
