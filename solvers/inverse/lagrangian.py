"""Derivatives of the simultaneous NLP assembled from its structure: Hessian and Jacobian.

The simultaneous NLP (``solvers.inverse.simultaneous``) has variables v = [z; s_1; ...; s_K]
and Lagrangian

    L = lam_f f(s) + sum_k lam_k^T g(s_k, x(z)) / c_k,
    f = 1/2 sum_k |J_k s_k + r_k|^2 / scale.

The objective is quadratic with a constant sparse Hessian Q_k = J_k^T J_k / scale.
For the linear model g = A(x) Delta + C^T lam - F (eq. 22), A(x) = sum_t c_t(x) B_t
with constant B_t, so

    d2L / ds_k2     = lam_f Q_k                          (g is linear in s)
    d2L / dz dDelta_k = (dc/dz)^T [B_t mu_k]_t,             mu_k = lam_k[:n] / c_k
    d2L / dz2       = sum_k sum_t (mu_k^T B_t Delta_k) d2c_t / dz2.

CasADi's automatic Hessian finds the same matrix by graph colouring, at several
times the cost per evaluation, because it must push seeds through the products
with B_t and J_k.

A nonlinear model that assembles its tangent and force curvature in numpy (the
neo-Hookean family: ``TissueModel.tangent``, ``TissueModel.force_curvature``) has
g(s, x) = [f(Delta, x) - F + C^T lam; C Delta - Q d], nonlinear only through the
elastic force f. Then, with mu_k = lam_k[:n] / c_k,

    d2L / ds_k2      = [[d2(mu_k . f)/dDelta2 (Delta_k, x), 0], [0, 0]] + lam_f Q_k,
    d2L / dz dv      = d/dv (d(lam^T g)/dz)           (AD: n_z reverse sweeps),

and the constraint Jacobian is dg_k/ds_k = [[K_T(Delta_k, x), C^T], [C, 0]] / c_k, the
nested path's tangent, with dg/dz by forward AD (n_z directions). Only the n_z rows
and columns of z go through CasADi's graph. The nonlinear model without either (the
D-NURBS K(B), k0) leaves the constraint part to automatic differentiation.

The constraint Jacobian of the linear model is, per case,
dg_k/ds_k = [[A(x), C^T], [C, 0]] / c_k (the same A(x) for every case, built once)
and dg_k/dz = [sum_t (B_t Delta_k) dc_t/dz; 0] / c_k.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from solvers.forward.evaluator import kkt_jacobian
from solvers.inverse.problem import InverseProblem
from symbolic.sparse import SparseCallback, to_casadi_sparse


def objective_hessians(problem: InverseProblem, scale: float) -> list[sp.csc_matrix]:
    """Q_k = J_k^T J_k / scale for every load case, (n_state, n_state)."""
    hessians = []
    for case in problem.cases:
        jac = problem.case_residual_jacobian(case)
        hessians.append(sp.csc_matrix(jac.T @ jac) / scale)
    return hessians


def lagrangian_hessian(
    problem: InverseProblem,
    z: ca.MX,
    states: list[ca.MX],
    constraints: ca.MX,
    objective_scale: float,
    force_scales: list[float],
) -> ca.Function:
    """The Function IPOPT calls for the upper triangle of d2L/dv2.

    Parameters
    ----------
    problem : InverseProblem
        The problem (its model, load cases and parameter space).
    z, states : casadi.MX
        The NLP's symbols: internal parameters z and the state s_k of every case;
        v = [z; s_1; ...; s_K].
    constraints : casadi.MX
        The NLP constraints in terms of v (used only for the nonlinear model,
        where their Hessian comes from AD).
    objective_scale : float
        ``scale`` in f above.
    force_scales : list of float
        c_k, the force magnitudes dividing each case's equilibrium rows [N].

    Returns
    -------
    casadi.Function
        (x, p, lam_f, lam_g) -> triu(d2L/dv2), nlpsol's ``hess_lag`` signature.
    """
    variables = ca.vertcat(z, *states)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", constraints.numel())
    quadratic = ca.diagcat(
        ca.MX(z.numel(), z.numel()),
        *[to_casadi_sparse(q) for q in objective_hessians(problem, objective_scale)],
    )
    callbacks = []
    if problem.model.is_linear(problem.names):
        constraint_part = _linear_constraint_hessian(problem, z, states, lam_g, force_scales)
    elif problem.model.force_curvature(problem.names) is not None:
        constraint_part, callback = _curvature_constraint_hessian(
            problem, z, states, lam_g, constraints, force_scales
        )
        callbacks.append(callback)
    else:
        constraint_part = ca.hessian(ca.dot(lam_g, constraints), variables)[0]
    function = ca.Function(
        "nlp_hess_l",
        [variables, ca.MX.sym("p", 0), lam_f, lam_g],
        [ca.triu(lam_f * quadratic + constraint_part)],
        ["x", "p", "lam_f", "lam_g"],
        ["triu_hess_gamma_x_x"],
    )
    function.callbacks = callbacks  # CasADi does not keep a Python callback alive
    return function


def _coefficients(problem: InverseProblem, z: ca.MX) -> tuple[ca.MX, ca.MX, list[str]]:
    """c(x(z)), dc/dz and the terms of the linear model (``TissueModel.linear_terms``)."""
    x, coefficients, terms = problem.model.linear_terms(problem.names)
    c_of_z = ca.Function("c", [x], [coefficients])(problem.space.to_natural(z))
    return c_of_z, ca.jacobian(c_of_z, z), terms


def _linear_constraint_hessian(problem, z, states, lam_g, force_scales) -> ca.MX:
    """d2(sum_k lam_k^T g_k / c_k)/dv2 for g linear in s and in c(x) (module docstring)."""
    model = problem.model
    n_z, n_state, n = z.numel(), problem.n_state, 3 * model.n_free
    c_of_z, dc_dz, terms = _coefficients(problem, z)
    weight = ca.MX.sym("w", len(terms))
    curvature = ca.Function("d2c", [z, weight], [ca.hessian(ca.dot(weight, c_of_z), z)[0]])
    cross, weights = [], 0
    for k, (state, scale) in enumerate(zip(states, force_scales)):
        mu = lam_g[k * n_state : k * n_state + n] / scale
        directions = model.term_columns(terms, mu)  # (I3 (x) K_t) mu, K_t symmetric
        cross.append(ca.horzcat(ca.mtimes(directions, dc_dz).T, ca.MX(n_z, n_state - n)))
        weights = weights + ca.mtimes(directions.T, state[:n])
    size = n_z + len(states) * n_state
    top = ca.horzcat(curvature(z, weights), *cross)
    lower = ca.horzcat(ca.vertcat(*[c.T for c in cross]), ca.MX(size - n_z, size - n_z))
    return ca.vertcat(top, lower)


def _curvature_constraint_hessian(problem, z, states, lam_g, constraints, force_scales):
    """d2(lam^T g)/dv2 from the model's force curvature (module docstring): the state
    blocks numeric, the rows and columns of z by AD; with the callback it calls."""
    model, n_state = problem.model, problem.n_state
    n = 3 * model.n_free
    x = problem.space.to_natural(z)
    curvature = model.force_curvature(problem.names)
    pattern = curvature(np.zeros(n), problem.space.start, np.zeros(n))
    callback = SparseCallback("force_curvature", curvature, (n, x.numel(), n), pattern)
    variables = ca.vertcat(z, *states)
    mixed = ca.jacobian(ca.gradient(ca.dot(lam_g, constraints), z), variables)
    blocks = []
    for k, (state, scale) in enumerate(zip(states, force_scales)):
        weight = lam_g[k * n_state : k * n_state + n] / scale
        blocks.append(ca.diagcat(callback(state[:n], x, weight), ca.MX(n_state - n, n_state - n)))
    lower = ca.horzcat(mixed[:, z.numel() :].T, ca.diagcat(*blocks))
    return ca.vertcat(mixed, lower), callback


def constraint_jacobian(
    problem: InverseProblem, z: ca.MX, states: list[ca.MX], constraints: ca.MX
) -> ca.Function | None:
    """(x, p) -> (g, dg/dv) for the linear model, with A(x) shared by the cases, and
    for a nonlinear model with a numeric tangent (``_tangent_constraint_jacobian``).

    Returns None for the nonlinear model without one (k0), where CasADi's own
    Jacobian is used.
    """
    model = problem.model
    if not model.is_linear(problem.names):
        return _tangent_constraint_jacobian(problem, z, states, constraints)
    _, dc_dz, terms = _coefficients(problem, z)
    # [[A(x), C^T], [C, 0]]: the state block of g, the same for every case
    zero = ca.MX(problem.n_state, 1)
    natural = problem.space.to_natural(z)
    state_block = problem.g.jacobian()(zero, natural, 0, 0, zero)[0]
    n, n_state = 3 * model.n_free, problem.n_state
    rows = []
    for k, (case, state) in enumerate(zip(problem.cases, states)):
        columns = model.term_columns(terms, state[:n])
        d_z = ca.vertcat(ca.mtimes(columns, dc_dz), ca.MX(n_state - n, z.numel()))
        blocks = [d_z] + [
            state_block if j == k else ca.MX(n_state, n_state) for j in range(len(states))
        ]
        rows.append(ca.horzcat(*blocks) / case.force_scale())
    return ca.Function(
        "nlp_jac_g",
        [ca.vertcat(z, *states), ca.MX.sym("p", 0)],
        [constraints, ca.vertcat(*rows)],
        ["x", "p"],
        ["g", "jac_g_x"],
    )


def _tangent_constraint_jacobian(problem, z, states, constraints) -> ca.Function | None:
    """(x, p) -> (g, dg/dv) with dg_k/ds_k = [[K_T, C^T], [C, 0]] / c_k from the model's
    numeric tangent (``kkt_jacobian``, as the nested path) and dg/dz by forward AD;
    None when the model has no tangent."""
    jacobian = kkt_jacobian(problem.model, problem.names)
    if jacobian is None:
        return None
    n_state, x = problem.n_state, problem.space.to_natural(z)

    def evaluate(state, values):
        return jacobian(state, values, None, None)

    pattern = evaluate(np.zeros(n_state), problem.space.start)
    callback = SparseCallback("dg_ds", evaluate, (n_state, x.numel()), pattern)
    blocks = [callback(s, x) / case.force_scale() for s, case in zip(states, problem.cases)]
    function = ca.Function(
        "nlp_jac_g",
        [ca.vertcat(z, *states), ca.MX.sym("p", 0)],
        [constraints, ca.horzcat(ca.jacobian(constraints, z), ca.diagcat(*blocks))],
        ["x", "p"],
        ["g", "jac_g_x"],
    )
    function.callbacks = [callback]  # CasADi does not keep a Python callback alive
    return function
