"""Nested dynamic inverse: single shooting over the trapezoidal scheme (``solvers.dynamic``).

x is the only unknown. Every residual evaluation integrates (T1, T2) from rest for
every load case; the Jacobian is exact for the discrete scheme, from its forward
sensitivities (``solvers.dynamic.scheme``):

    dr/dz = W S du(t_j)/dx dx/dz.

scipy's ``least_squares`` (trf with bounds, or lm) iterates in the internal
coordinates z of ``ParameterSpace`` (log space for mu, gamma and alpha).
"""

from __future__ import annotations

import time

import numpy as np

from solvers.dynamic.dynamicproblem import DynamicProblem
from solvers.dynamic.scheme import TrapezoidalScheme
from solvers.inverse.nested import least_squares_fit
from solvers.inverse.result import InverseResult


class DynamicNestedSolver:
    """Reduced-space least squares over the trajectories, with exact sensitivities.

    Parameters
    ----------
    problem : DynamicProblem
        The problem.
    method : {"trf", "lm"}
        scipy least-squares method; "lm" ignores the bounds.
    tolerance : float
        ftol = xtol = gtol of least_squares.
    max_evaluations : int
        Cap on residual evaluations.
    """

    name = "nested"

    def __init__(self, problem: DynamicProblem, method="trf", tolerance=1e-12, max_evaluations=200):
        if method not in ("trf", "lm"):
            raise ValueError(f"method must be 'trf' or 'lm', got {method!r}")
        start = time.perf_counter()
        self.problem = problem
        self.method, self.tolerance, self.max_evaluations = method, tolerance, max_evaluations
        self.scheme = TrapezoidalScheme(problem.model, problem.names, problem.grid)
        nodes = problem.grid.nodes
        self.loads = [case.loads(nodes) for case in problem.cases]
        self.build_time = time.perf_counter() - start
        self.forward_solves = 0
        self._cache: tuple | None = None
        self.runs: list = []

    def simulate(self, x: np.ndarray, sensitivities: bool = False) -> list:
        """One ``SchemeRun`` per case at x (natural units)."""
        runs = [self.scheme.run(load, x, sensitivities) for load in self.loads]
        self.forward_solves += len(runs)
        return runs

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual r(z) [mm] and its exact Jacobian dr/dz."""
        if self._cache is not None and np.array_equal(self._cache[0], z):
            return self._cache[1], self._cache[2]
        problem = self.problem
        x = problem.space.to_natural(z)
        dx_dz = problem.space.natural_derivative(z)
        frames = problem.grid.frame_nodes
        self.runs = self.simulate(x, sensitivities=True)
        residuals, jacobians = [], []
        for case, run in zip(problem.cases, self.runs):
            residuals.append(problem.case_residual(case, run.displacements[frames]))
            jacobian = problem.case_sensitivity(case, run.sensitivities[frames])
            jacobians.append(jacobian * dx_dz[None, :])
        r, jac = np.concatenate(residuals), np.vstack(jacobians)
        self._cache = (np.array(z), r, jac)
        return r, jac

    def solve(self, start: np.ndarray | None = None) -> InverseResult:
        """Run least_squares from ``start`` (natural units; default the space's start)."""
        self.forward_solves = 0
        z, success, status, nfev, elapsed = least_squares_fit(
            self.evaluate,
            self.problem.space,
            start,
            None,
            self.method,
            self.tolerance,
            self.max_evaluations,
        )
        space = self.problem.space
        r, _ = self.evaluate(z)
        frames = self.problem.grid.frame_nodes
        return InverseResult(
            method=self.name,
            names=space.names,
            x=space.to_natural(z),
            cost=0.5 * float(r @ r),
            states=[run.displacements[frames] for run in self.runs],
            success=bool(success),
            status=str(status),
            iterations=int(nfev),
            forward_solves=self.forward_solves,
            build_time_s=self.build_time,
            solve_time_s=elapsed,
            extra={"trajectories": [run.displacements for run in self.runs]},
        )
