"""Simultaneous (full-space) inverse: one IPOPT NLP (docs/inverse.md, "Simultaneous").

    min_{z, s_k}  1/2 sum_k |J_k s_k + r_k|^2 / scale_f
    s.t.          g(s_k, x(z), F_k, d_k) / |F_k| = 0         for every load case k
                  z_lower <= z <= z_upper

- x(z) is exp(z) for alpha, mu, gamma (log space) and a scaled z otherwise;
- every equilibrium constraint is divided by its case's force magnitude;
- the states are warm-started from a forward solve at the start values;
- IPOPT uses the exact Hessian of the Lagrangian, assembled from the problem's
  structure (``solvers.inverse.lagrangian``): the objective is quadratic with a constant
  Hessian J^T J, and for the linear model g is bilinear in (c(x), Delta).

The marker residuals are not lifted into extra variables: J_k^T J_k couples only
control points that already share a stiffness entry (a marker touches 4 x 4
outer points, a stiffness entry reaches 7 x 7), so the KKT matrix keeps K's
pattern at half the size. On 9 x 9 x 2 that halved the factorisation time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from solvers.forward.equilibrium import EquilibriumSolver
from solvers.inverse.lagrangian import constraint_jacobian, lagrangian_hessian
from solvers.inverse.methods import FullSpaceSolver
from solvers.inverse.problem import InverseProblem
from symbolic.sparse import to_casadi_sparse


@dataclass(frozen=True)
class IpoptSettings:
    """Options of the simultaneous solver; ``options`` passes anything through to nlpsol.

    Attributes
    ----------
    tol : float
        IPOPT's convergence tolerance (scaled NLP error).
    max_iter : int
        IPOPT iteration limit.
    print_level : int
        IPOPT verbosity, 0 (silent) to 12.
    expand : bool
        Expand the MX graph to SX. Evaluation gets faster but building the
        derivative graphs takes seconds (colouring of K's rows), so off by default.
    structured_hessian : bool
        Give IPOPT the Hessian of the Lagrangian (and, for the linear model, the
        constraint Jacobian) assembled from the problem's structure
        (``solvers.inverse.lagrangian``) instead of CasADi's coloured AD derivatives.
        Same matrices, cheaper per evaluation.
    options : dict
        Extra nlpsol options, e.g. ``{"ipopt.mu_strategy": "adaptive"}``; they
        override the defaults above and each solver's own (``STATIC_DEFAULTS``).

    Notes
    -----
    The monotone (Fiacco-McCormick) barrier is the default: from 80
    log-uniform starts on the phantom it converged 80 times; mu_init = 1e-3
    73 times (the others ended in a second basin, alpha_u at its lower bound
    with a stiff alpha_w). tol = 1e-8 (IPOPT's default) would save one
    iteration, but on the pad-force problem it leaves alpha_w 1.7e-6 from the
    noise-free truth, so 1e-10 stays.
    """

    tol: float = 1e-10
    max_iter: int = 300
    print_level: int = 0
    expand: bool = False
    structured_hessian: bool = True
    options: dict = field(default_factory=dict)

    def nlpsol_options(self) -> dict:
        """Defaults merged with the user's options (user wins); never mutates either."""
        defaults = {
            "ipopt.tol": self.tol,
            "ipopt.max_iter": self.max_iter,
            "ipopt.print_level": self.print_level,
            "ipopt.sb": "yes",
            "ipopt.hessian_approximation": "exact",
            "ipopt.mu_strategy": "monotone",
            "print_time": False,
            "expand": self.expand,
        }
        return {**defaults, **self.options}

    def solver_options(self, solver_defaults: dict) -> dict:
        """``nlpsol_options`` with one NLP's own defaults in between (the user still wins)."""
        return {**self.nlpsol_options(), **solver_defaults, **self.options}


STATIC_DEFAULTS = {
    "ipopt.constr_mult_init_max": 0.0,
    "ipopt.mu_superlinear_decrease_power": 1.8,
}
"""IPOPT options measured on the static NLP (``IpoptSettings.options`` override them).

- The equality multipliers start at zero instead of IPOPT's least-squares estimate:
  the states start on the equilibrium, and the estimate costs a factorisation of its
  own. From 80 log-uniform starts it converged 80 times (79 with the estimate) in
  15.7 iterations on average (17.8), and in 9 instead of 10 from the paper's start.
- Once the barrier problem is solved, mu falls to mu^1.8 instead of mu^1.5 (the
  monotone strategy's superlinear phase): 7 instead of 9 iterations from the
  paper's start, and 160/160 converged from 160 log-uniform starts (8 draws of 20,
  mean 15.1 iterations against 16.4); 1.9 lost one of the 160.
"""

METIS_ABOVE = 2000
"""NLP variables above which the options of a large NLP apply (``static_defaults``)."""


def static_defaults(n_variables: int) -> dict:
    """``STATIC_DEFAULTS`` plus the options that depend on the size of the NLP.

    - MUMPS ordering: on 17 x 17 x 3 (3,471 variables) METIS halved the factorisation
      time against IPOPT's automatic choice (1.9 s against 4.2 s CPU over one solve)
      and matches AMD; on 9 x 9 x 2 (489 variables) AMD is about 15 % faster per
      solve than METIS, whose own ordering time is then not repaid (40 interleaved
      solves each, median).
    - Residual check of each search direction: skipped on small NLPs
      (``fast_step_computation``), about 10 % off a 9 x 9 x 2 solve with the same
      iterations and 240/240 starts. Kept on large ones: on 33 x 33 x 4 skipping it
      took 19 iterations instead of 10.
    - MUMPS without threshold pivoting on large NLPs (``mumps_pivtol`` 0, static
      pivots in METIS's order): on 33 x 33 x 4 one solve takes 9 iterations and 13 s
      instead of 16 and 262 s (MUMPS's default 1e-6), the same optimum to all printed
      digits; 1e-10 was slower than either. Converged from 80 of 80 starts on 17 x 17
      x 3 and 5 of 5 on 33 x 33 x 4; also 80/80 on 9 x 9 x 2 with METIS, but 30/80 with
      AMD, so small NLPs keep MUMPS's default (docs/inverse.md, "Speed at scale").
    """
    small = n_variables <= METIS_ABOVE
    large = {} if small else {"ipopt.mumps_pivtol": 0.0}
    return {
        **STATIC_DEFAULTS,
        "ipopt.mumps_pivot_order": 0 if small else 5,
        "ipopt.fast_step_computation": "yes" if small else "no",
        **large,
    }


class SimultaneousSolver(FullSpaceSolver):
    """Fit and equilibrium of all load cases in one NLP, solved by IPOPT.

    Parameters
    ----------
    problem : InverseProblem
        The problem.
    settings : IpoptSettings
        Options.
    """

    def __init__(self, problem: InverseProblem, settings: IpoptSettings | None = None):
        start = time.perf_counter()
        self.problem = problem
        self.settings = settings or IpoptSettings()
        space = problem.space
        n_variables = len(space.names) + len(problem.cases) * problem.n_state
        self.options = self.settings.solver_options(static_defaults(n_variables))
        z = ca.MX.sym("z", len(space.names))
        x = space.to_natural(z)
        states, objective, constraints = [], 0, []
        self.objective_scale = self._objective_scale()
        for k, case in enumerate(problem.cases):
            s = ca.MX.sym(f"s{k}", problem.n_state)
            jac = to_casadi_sparse(problem.case_residual_jacobian(case))
            residual = ca.mtimes(jac, s) + ca.DM(problem.case_offset(case))
            objective = objective + 0.5 * ca.sumsqr(residual) / self.objective_scale
            g = problem.g(s, x, ca.DM(case.force), ca.DM(case.prescribed))
            constraints.append(g / case.force_scale())
            states.append(s)
        constraints = ca.vertcat(*constraints)
        self.block_sizes = [int(v.numel()) for v in [z, *states]]
        options = dict(self.options)
        if self.settings.structured_hessian and "hess_lag" not in options:
            scales = [case.force_scale() for case in problem.cases]
            options["hess_lag"] = lagrangian_hessian(
                problem, z, states, constraints, self.objective_scale, scales
            )
            jacobian = constraint_jacobian(problem, z, states, constraints)
            if jacobian is not None and "jac_g" not in options:
                options["jac_g"] = jacobian
        self.nlp = {"x": ca.vertcat(z, *states), "f": objective, "g": constraints}
        self.hessian, self.jacobian = options.get("hess_lag"), options.get("jac_g")
        self.solver = ca.nlpsol("inverse", "ipopt", self.nlp, options)
        self.warm = EquilibriumSolver(problem.model, space.names, residual=problem.g)
        self.build_time = time.perf_counter() - start

    def _objective_scale(self) -> float:
        """Residuals of 0.01 mm on every observation make the objective O(1)."""
        return max(self.problem.n_residuals, 1) * 1e-4

    def warm_start(self, x: np.ndarray) -> list[np.ndarray]:
        """Equilibrium states of every load case at x (forward solves)."""
        return [
            self.warm.solve(case.force, x, case.prescribed).state for case in self.problem.cases
        ]

    def initial(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z, s_1..s_K) at x0 with the states on the equilibrium, and the bounds; the
        parameters absent from the equilibrium (mu, gamma) are fixed at x0."""
        guess = np.concatenate([self.problem.space.to_internal(x0), *self.warm_start(x0)])
        lbx, ubx = self.bounds(guess)
        inactive = np.flatnonzero(~self.problem.active)
        lbx[inactive] = ubx[inactive] = guess[inactive]
        return guess, lbx, ubx

    def unpack(self, values: np.ndarray) -> tuple[np.ndarray, list, dict]:
        """x and the equilibrium state of every case."""
        blocks = np.split(values, np.cumsum(self.block_sizes)[:-1])
        return self.problem.space.to_natural(blocks[0]), blocks[1:], {}
