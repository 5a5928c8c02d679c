"""Simultaneous dynamic inverse: the discretised dynamics as constraints of one IPOPT NLP.

With velocities scaled to w = v tau [mm] (tau: the mean frame interval), the NLP in
(zeta, u_1..u_N, w_1..w_N, e) for every load case k is

    min   1/2 sum_k |e_k|^2 / (n_res 1e-4 mm^2)
    s.t.  tau [(u_{n+1} - u_n)/h - (v_n + v_{n+1})/2] = 0                      (T1)/h
          [M (v_{n+1} - v_n)/h + D (v_n + v_{n+1})/2
           + (f(u_n) + f(u_{n+1}) - F_n - F_{n+1})/2] / |F_k|_1 = 0             (T2)/h
          O_k vec(u) + c_k - e_k = 0,        zeta_lower <= zeta <= zeta_upper,

with u_0 = v_0 = 0, x = x(z) in log space (``ParameterSpace``) and z = sigma zeta.

- Dividing (T1) and (T2) by h makes every constraint a rate, independent of the step;
  the force scale makes (T2) dimensionless like the static equilibrium constraints.
- **choice (parameter scaling)**: the NLP variable is zeta = z / sigma with
  sigma = ``parameter_step`` (default 0.03: one unit of zeta is a 3 % change of x).
  IPOPT regularises the indefinite exact Hessian by adding delta I to every variable;
  in unscaled z the log-parameters' curvature is large against that of the states,
  delta grows and the steps stall. On the 10-frame phantom problem from the paper's
  start: 42 iterations with sigma = 1, 28 with 0.1, 15 with 0.03, 21 with 0.01.
- **Linear model**: the three displacement components decouple (K, M, D are
  kron(I3, .)), so each loaded component of each case is its own block of states
  with n_free-sized matrices; components without load stay at rest and are dropped.
  The step Function of a block carries its Jacobian in closed form
  (``_step_jacobian``). The nonlinear model (k0) uses one 3 n_free block per case with
  the static residual g of ``TissueModel.state_residual`` and AD.
- Residuals are lifted into e (identity objective Hessian), the states are
  warm-started from the scheme at the start values, IPOPT uses CasADi's exact Hessian
  of the Lagrangian and the static solver's ``IpoptSettings`` (monotone barrier).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from solvers.dynamic.problem import DynamicProblem
from solvers.dynamic.scheme import TrapezoidalScheme
from solvers.inverse.methods import FullSpaceSolver
from solvers.inverse.simultaneous import IpoptSettings
from symbolic.sparse import to_casadi_sparse

DYNAMIC_DEFAULTS = {"ipopt.mumps_pivot_order": 2}
"""IPOPT options added for this NLP (the user's ``IpoptSettings.options`` override them).

**choice**: MUMPS with the AMF ordering. MUMPS' automatic choice made the
factorisations of this time-banded KKT matrix up to 20x slower. Solve times from the
paper's start on noise-free phantom data (single runs, shared 2-core machine):
20 frames at 1 ms: 141 s automatic, 38 s AMD, 14 s METIS, 9.4 s AMF; 20 frames at
2 ms: 284 s automatic, 23 s METIS, 13 s AMF; 40 frames at 1 ms with 2 substeps: 73 s
METIS, 33 s AMF.
"""

STEP_INPUTS = ("u0", "w0", "u1", "w1", "x", "F0", "F1", "h", "scale")
"""Inputs of the step constraint Function."""


@dataclass(frozen=True)
class Block:
    """States of one case and displacement components: rows of u in the 3 n_free state."""

    case: int
    rows: np.ndarray
    components: tuple[int, ...]


def step_constraints(problem: DynamicProblem, size: int) -> ca.Function:
    """The scaled step constraints c(u0, w0, u1, w1, x, F0, F1, h, scale) of (T1, T2).

    Parameters
    ----------
    problem : DynamicProblem
        The problem.
    size : int
        n_free (one component of the linear model) or 3 n_free (any model).

    Returns
    -------
    casadi.Function
        Inputs: u0, u1 [mm] and w0, w1 = v tau [mm], each (size,); x (p); F0, F1 =
        vec F_B(t) (size,) [N]; h [s]; scale |F|_1 [N]. Output c (2 size,): tau (T1)/h
        [mm] stacked over (T2)/(h |F|_1) [1].
    """
    symbols = _step_symbols(problem, size)
    expression = _step_expression(problem, size, *symbols)
    if size == 3 * problem.model.n_free:
        return ca.Function("step", symbols, [expression], list(STEP_INPUTS), ["c"])
    plain = ca.Function("step_plain", symbols, [expression])
    return ca.Function(
        "step",
        symbols,
        plain.call(symbols),
        list(STEP_INPUTS),
        ["c"],
        {"custom_jacobian": _step_jacobian(problem), "jac_penalty": 0, "never_inline": True},
    )


def _step_symbols(problem: DynamicProblem, size: int) -> list[ca.MX]:
    sizes = {"x": len(problem.names), "h": 1, "scale": 1}
    return [ca.MX.sym(name, sizes.get(name, size)) for name in STEP_INPUTS]


def _block_matrices(problem: DynamicProblem, size: int) -> tuple[ca.DM, ca.DM]:
    """M_1 and D_1 for one component (size n_free) or kron(I3, .) (size 3 n_free)."""
    mass, damping = problem.unit_matrices()
    return to_casadi_sparse(mass[:size, :size]), to_casadi_sparse(damping[:size, :size])


def _linear_stiffness(problem: DynamicProblem, x: ca.MX) -> tuple[ca.MX, list, ca.MX]:
    """K(x) = sum_t c_t(x) K_t on one component, the unit K_t and the coefficients c_t."""
    n, values = problem.model.n_free, problem.values(x)
    names = problem.term_parameters()
    blocks = [problem.model.free_block(m) for m in problem.model.terms.values()]
    pattern = sp.csc_matrix(sum(abs(b) for b in blocks))
    pattern.sort_indices()
    rows, cols = pattern.nonzero()
    order = np.lexsort((rows, cols))
    rows, cols = rows[order], cols[order]
    unit = np.column_stack([np.asarray(b[rows, cols]).ravel() for b in blocks])
    sparsity = ca.Sparsity(n, n, pattern.indptr.tolist(), pattern.indices.tolist())
    coefficients = ca.vertcat(*[ca.MX(values[names[t]]) for t in problem.model.terms])
    stiffness = ca.MX(sparsity, ca.mtimes(ca.DM(unit), coefficients))
    return stiffness, [to_casadi_sparse(b) for b in blocks], coefficients


def _step_expression(problem: DynamicProblem, size, u0, w0, u1, w1, x, f0, f1, h, scale):
    """c = [tau (T1)/h; (T2)/(h scale)] as an expression."""
    tau, free, values = problem.time_scale, problem.model.n_free, problem.values(x)
    unit_mass, unit_damping = _block_matrices(problem, size)
    v0, v1 = w0 / tau, w1 / tau
    if size == free:
        stiffness, _, _ = _linear_stiffness(problem, x)
        static = ca.mtimes(stiffness, u0 + u1) - f0 - f1
    else:
        empty = ca.MX(0, 3)
        static = problem.g(u0, x, ca.reshape(f0, free, 3), empty)
        static = static + problem.g(u1, x, ca.reshape(f1, free, 3), empty)
    kinematic = tau * ((u1 - u0) / h - (v0 + v1) / 2)
    dynamic = (
        values["mu"] * ca.mtimes(unit_mass, v1 - v0) / h
        + values["gamma"] * ca.mtimes(unit_damping, v0 + v1) / 2
        + static / 2
    ) / scale
    return ca.vertcat(kinematic, dynamic)


def _step_jacobian(problem: DynamicProblem) -> ca.Function:
    """Closed-form Jacobian of one component's linear step constraints.

    With K(x) = sum_t c_t(x) K_t, M = mu M_1 and D = gamma D_1 (one component):
    dc/du0,1 = [-+tau/h I; K/(2s)], dc/dw0,1 = [-I/2; (-+M/(tau h) + D/(2 tau))/s],
    dc/dF0,1 = [0; -I/(2s)], dc/dx = [0; (sum_t K_t (u0+u1)/2 dc_t/dx
    + M_1 (w1-w0)/(tau h) dmu/dx + D_1 (w0+w1)/(2 tau) dgamma/dx)/s], and the h and
    scale columns from the terms they divide.
    """
    n, tau = problem.model.n_free, problem.time_scale
    symbols = _step_symbols(problem, n)
    u0, w0, u1, w1, x, _, _, h, scale = symbols
    nominal = ca.MX.sym("out_c", 2 * n)
    values = problem.values(x)
    mu, gamma = ca.MX(values["mu"]), ca.MX(values["gamma"])
    unit_mass, unit_damping = _block_matrices(problem, n)
    stiffness, units, coefficients = _linear_stiffness(problem, x)
    eye, zero = ca.MX.eye(n), ca.MX(n, n)
    mass, damping = mu * unit_mass / (tau * h), gamma * unit_damping / (2 * tau)
    rate = ca.mtimes(unit_mass, w1 - w0) / (tau * h)
    average = ca.mtimes(unit_damping, w0 + w1) / (2 * tau)
    columns = ca.horzcat(*[ca.mtimes(k, u0 + u1) / 2 for k in units])
    d_x = (
        ca.mtimes(columns, ca.jacobian(coefficients, x))
        + ca.mtimes(rate, ca.jacobian(mu, x))
        + ca.mtimes(average, ca.jacobian(gamma, x))
    ) / scale
    d_force = ca.vertcat(zero, -eye / (2 * scale))
    outputs = [
        ca.vertcat(-tau / h * eye, stiffness / (2 * scale)),
        ca.vertcat(-eye / 2, (damping - mass) / scale),
        ca.vertcat(tau / h * eye, stiffness / (2 * scale)),
        ca.vertcat(-eye / 2, (damping + mass) / scale),
        ca.vertcat(ca.MX(n, x.numel()), d_x),
        d_force,
        d_force,
        ca.vertcat(-tau * (u1 - u0) / h**2, -mu * rate / (h * scale)),
        ca.vertcat(ca.MX(n, 1), -nominal[n:] / scale),
    ]
    return ca.Function(
        "jac_step",
        [*symbols, nominal],
        outputs,
        [*STEP_INPUTS, "out_c"],
        [f"jac_c_{name}" for name in STEP_INPUTS],
    )


def state_blocks(problem: DynamicProblem) -> list[Block]:
    """One block per loaded component and case (linear model), else one per case."""
    n = problem.model.n_free
    if not problem.linear:
        return [Block(k, np.arange(3 * n), (0, 1, 2)) for k in range(len(problem.cases))]
    return [
        Block(k, np.arange(c * n, (c + 1) * n), (c,))
        for k, case in enumerate(problem.cases)
        for c in np.flatnonzero(case.loaded_components)
    ]


class DynamicSimultaneousSolver(FullSpaceSolver):
    """Fit and discretised dynamics of all load cases in one NLP, solved by IPOPT.

    Parameters
    ----------
    problem : DynamicProblem
        The problem.
    settings : IpoptSettings
        Options (the static solver's; ``{**defaults, **user}``).
    parameter_step : float
        sigma of the NLP parameter variable zeta = z / sigma [log units].
    """

    def __init__(
        self,
        problem: DynamicProblem,
        settings: IpoptSettings | None = None,
        parameter_step: float = 0.03,
    ):
        if parameter_step <= 0:
            raise ValueError(f"parameter_step must be positive, got {parameter_step}")
        begin = time.perf_counter()
        self.problem, self.parameter_step = problem, float(parameter_step)
        self.settings = settings or IpoptSettings()
        self.options = self.settings.solver_options(DYNAMIC_DEFAULTS)
        self.scheme = TrapezoidalScheme(problem.model, problem.names, problem.grid)
        self.loads = [case.loads(problem.grid.nodes) for case in problem.cases]
        self.blocks = state_blocks(problem)
        zeta = ca.MX.sym("zeta", len(problem.names))
        x = problem.space.to_natural(self.parameter_step * zeta)
        self.objective_scale = max(problem.n_residuals, 1) * 1e-4
        variables, constraints, objective = [zeta], [], 0
        steps = problem.grid.steps.size
        step = {
            size: step_constraints(problem, size) for size in {b.rows.size for b in self.blocks}
        }
        for block in self.blocks:
            case = problem.cases[block.case]
            size = block.rows.size
            u, w = ca.MX.sym("u", size, steps), ca.MX.sym("w", size, steps)
            observe = to_casadi_sparse(problem.component_observation(case))
            offsets = problem.component_offsets(case)
            loads = self.loads[block.case][:, block.rows]
            constraints.append(self._dynamics(step[size], u, w, x, loads, case.force_scale()))
            n, lifted = problem.model.n_free, [ca.vec(u), ca.vec(w)]
            for i, c in enumerate(block.components):
                e = ca.MX.sym("e", observe.shape[0])
                component = ca.vec(u[i * n : (i + 1) * n, :])
                constraints.append(ca.mtimes(observe, component) + ca.DM(offsets[c]) - e)
                lifted.append(e)
                objective = objective + 0.5 * ca.sumsqr(e) / self.objective_scale
            variables += lifted
        self.block_sizes = [int(v.numel()) for v in variables]
        nlp = {"x": ca.vertcat(*variables), "f": objective, "g": ca.vertcat(*constraints)}
        self.solver = ca.nlpsol("dynamic_inverse", "ipopt", nlp, self.options)
        self.build_time = time.perf_counter() - begin

    def _dynamics(self, step, u, w, x, loads, scale) -> ca.MX:
        """The step constraints of one block, one call per step (u_0 = w_0 = 0).

        A loop of calls, not ``Function.map``: CasADi then uses the closed-form step
        Jacobian at every call (the constraint Jacobian was 5x faster than through map).
        """
        rest = ca.MX(u.shape[0], 1)
        parts = []
        for k, h in enumerate(self.problem.grid.steps):
            before_u = u[:, k - 1] if k else rest
            before_w = w[:, k - 1] if k else rest
            parts.append(
                step(before_u, before_w, u[:, k], w[:, k], x, loads[k], loads[k + 1], h, scale)
            )
        return ca.vertcat(*parts)

    def warm_start(self, x: np.ndarray) -> np.ndarray:
        """The initial guess: zeta, then (u, w, e per component) of every block.

        States from the scheme integrated at x; residuals from those states.
        """
        problem, tau = self.problem, self.problem.time_scale
        runs = [self.scheme.run(load, x) for load in self.loads]
        parts = [problem.space.to_internal(x) / self.parameter_step]
        for block in self.blocks:
            case, run = problem.cases[block.case], runs[block.case]
            observe = problem.component_observation(case)
            offsets = problem.component_offsets(case)
            u = run.displacements[1:, block.rows]
            parts += [u.ravel(), tau * run.velocities[1:, block.rows].ravel()]
            n = problem.model.n_free
            for i, c in enumerate(block.components):
                parts.append(observe @ u[:, i * n : (i + 1) * n].ravel() + offsets[c])
        return np.concatenate(parts)

    def initial(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``warm_start(x0)`` and the bounds of zeta = z / sigma."""
        guess = self.warm_start(x0)
        return (guess, *self.bounds(guess, self.parameter_step))

    def unpack(self, values: np.ndarray) -> tuple[np.ndarray, list, dict]:
        """x, u at the frames of every case, and the whole trajectories."""
        trajectories = self._trajectories(values)
        x = self.problem.space.to_natural(self.parameter_step * values[: len(self.problem.names)])
        frames = self.problem.grid.frame_nodes
        return x, [u[frames] for u in trajectories], {"trajectories": trajectories}

    def _trajectories(self, values: np.ndarray) -> list[np.ndarray]:
        """u at every node, (N + 1, 3 n_free) per case, from the NLP variables."""
        problem = self.problem
        nodes = problem.grid.nodes.size
        trajectories = [np.zeros((nodes, problem.n_state)) for _ in problem.cases]
        blocks = np.split(values, np.cumsum(self.block_sizes)[:-1])[1:]
        position = 0
        for block in self.blocks:
            u = blocks[position].reshape(nodes - 1, block.rows.size)
            trajectories[block.case][1:, block.rows] = u
            position += 2 + len(block.components)
        return trajectories
