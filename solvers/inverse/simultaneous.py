"""Simultaneous (full-space) inverse: one IPOPT NLP (docs/inverse.md, "Simultaneous").

    min_{z, s_k}  1/2 sum_k |J_k s_k + r_k|^2 / scale_f
    s.t.          g(s_k, x(z), F_k, d_k) / |F_k| = 0         for every load case k
                  z_lower <= z <= z_upper

- x(z) is exp(z) for alpha, mu, gamma (log space) and a scaled z otherwise;
- every equilibrium constraint is divided by its case's force magnitude;
- the states are warm-started from a forward solve at the start values;
- IPOPT uses the exact Hessian of the Lagrangian, assembled from the problem's
  structure (``solvers.inverse.lagrangian``): the objective is quadratic with a constant
  Hessian J^T J, for the linear model g is bilinear in (c(x), Delta), and the
  neo-Hookean family assembles dg/ds and the curvature of lam^T g in numpy.

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
        Give IPOPT the Hessian of the Lagrangian (and, for the linear model and a
        model with a numeric tangent, the constraint Jacobian) assembled from the
        problem's structure (``solvers.inverse.lagrangian``) instead of CasADi's
        coloured AD derivatives. Same matrices, cheaper per evaluation.
    options : dict
        Extra nlpsol options, e.g. ``{"ipopt.mu_strategy": "adaptive"}``; they
        override the defaults above and each solver's own (``STATIC_DEFAULTS``).

    Notes
    -----
    The monotone (Fiacco-McCormick) barrier and tol = 1e-10 are the defaults; why, with
    the multistart counts, is in docs/results/inverse-speed.md ("IPOPT's options").
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
"""IPOPT options of the static NLP (``IpoptSettings.options`` override them): the
equality multipliers start at zero (the states start on the equilibrium, and IPOPT's
least-squares estimate costs a factorisation), and once the barrier problem is solved
mu falls to mu^1.8 instead of mu^1.5. docs/results/inverse-speed.md ("IPOPT's options")
gives the multistart counts and iterations that chose them.
"""

METIS_ABOVE = 2000
"""NLP variables above which the options of a large NLP apply (``static_defaults``)."""


def static_defaults(n_variables: int) -> dict:
    """``STATIC_DEFAULTS`` plus the options that depend on the size of the NLP
    (``n_variables``): above ``METIS_ABOVE``, MUMPS orders by METIS, keeps the residual
    check of each search direction and pivots statically (``mumps_pivtol`` 0); below it,
    IPOPT's automatic ordering, no residual check and MUMPS's default pivoting. The
    measurements behind each choice are in docs/results/inverse-speed.md ("IPOPT's
    options").
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
