"""The paper-faithful nested inverse: the outer control points of the deformed volume fitted
directly, as the paper did (docs/inverse.md, "Nested")."""

from __future__ import annotations

import time

import numpy as np

from solvers.inverse.methods import ReducedSpaceSolver
from solvers.inverse.problem import InverseProblem


class PaperNestedSolver(ReducedSpaceSolver):
    """The paper's method: least squares with finite-difference Jacobians, where each
    forward solve integrates the dynamics (eq. 22) from rest to steady state.

    As in the paper, every named parameter is perturbed (mu too, although the
    steady state does not depend on it), the dynamics use mu = 1e-4 and
    gamma = 15 unless they are estimated, and the outer iteration is a
    trust-region least squares (MATLAB's lsqnonlin; here scipy's trf).

    Parameters
    ----------
    problem : InverseProblem
        The problem (without prescribed displacements).
    steady_tol : float
        Steady-state tolerance of each transient (relative residual and kinetic ratio).
    t_max : float
        Longest transient [s].
    log : callable, optional
        Called with one line per residual evaluation (each integrates every load case
        to steady state, so a fit takes seconds to minutes).
    """

    name = "paper"
    finite_differences = True
    DYNAMICS = {"mu": 1e-4, "gamma": 15.0}

    def __init__(
        self,
        problem: InverseProblem,
        steady_tol=1e-10,
        t_max=1e4,
        max_evaluations=400,
        log=None,
    ):
        from solvers.transient.stepping import TransientSolver

        start = time.perf_counter()
        super().__init__(problem, "trf", 1e-10, max_evaluations)
        self.steady_tol = steady_tol
        self.t_max = t_max
        # generalised-alpha (rho_inf = 0) damps the stiff modes; Newmark's do not decay
        self.transient = TransientSolver(problem.model, problem.names, "generalized_alpha")
        self.build_time = time.perf_counter() - start
        self.log = log
        self._states: list = [None] * len(problem.cases)

    def residual(self, z: np.ndarray) -> np.ndarray:
        """r(z): every load case integrated from rest to steady state."""
        problem = self.problem
        x = problem.space.to_natural(z)
        dynamics = {k: v for k, v in self.DYNAMICS.items() if k not in problem.names}
        parts = []
        for k, case in enumerate(problem.cases):
            run = self.transient.integrate(
                case.force, self.t_max, x, dynamics, steady_tol=self.steady_tol
            )
            self.forward_solves += 1
            self._states[k] = run.state
            parts.append(problem.case_residual(case, run.state))
        residual = np.concatenate(parts)
        if self.log is not None:
            self.log(
                f"transients {self.forward_solves}: 1/2 |r|^2 = {0.5 * residual @ residual:.6g}"
            )
        return residual

    @property
    def states(self) -> list:
        """The steady state of every case at the last evaluation."""
        return list(self._states)
