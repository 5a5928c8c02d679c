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

from solvers.dynamic.problem import DynamicProblem
from solvers.dynamic.scheme import TrapezoidalScheme
from solvers.inverse.methods import ReducedSpaceSolver


class DynamicNestedSolver(ReducedSpaceSolver):
    """Reduced-space least squares over the trajectories, with exact sensitivities.

    The parameters are ``ReducedSpaceSolver``'s, the problem a ``DynamicProblem``.
    """

    def __init__(self, problem: DynamicProblem, method="trf", tolerance=1e-12, max_evaluations=200):
        start = time.perf_counter()
        super().__init__(problem, method, tolerance, max_evaluations)
        self.scheme = TrapezoidalScheme(problem.model, problem.names, problem.grid)
        nodes = problem.grid.nodes
        self.loads = [case.loads(nodes) for case in problem.cases]
        self.build_time = time.perf_counter() - start
        self.reset()

    def reset(self) -> None:
        """Forget the previous solve: its counter, cache and runs."""
        self.forward_solves = 0
        self._cache: tuple | None = None  # (z, r, dr/dz, runs)
        self.runs: list = []

    @property
    def states(self) -> list:
        """u at the frames of every case at the last evaluation."""
        return [run.displacements[self.problem.grid.frame_nodes] for run in self.runs]

    def extra(self) -> dict:
        """The whole trajectory u(t_n) of every case."""
        return {"trajectories": [run.displacements for run in self.runs]}

    def simulate(self, x: np.ndarray, sensitivities: bool = False) -> list:
        """One ``SchemeRun`` per case at x (natural units)."""
        runs = [self.scheme.run(load, x, sensitivities) for load in self.loads]
        self.forward_solves += len(runs)
        return runs

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual r(z) [mm] and its exact Jacobian dr/dz."""
        if self._cache is not None and np.array_equal(self._cache[0], z):
            self.runs = self._cache[3]
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
        self._cache = (np.array(z), r, jac, self.runs)
        return r, jac
