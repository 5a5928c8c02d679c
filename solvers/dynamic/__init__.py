"""The dynamic inverse: mu, gamma and alpha from marker trajectories (docs/dynamic.md).

- ``dynamicproblem``: the problem stated once (trajectories, time grid, scheme);
- ``scheme``: the trapezoidal scheme and its exact forward sensitivities;
- ``dynamicsimultaneous``: the discretised dynamics as constraints of one IPOPT NLP;
- ``dynamicnested``: single shooting over the scheme;
- ``dynamicidentifiability``: what trajectories tell, against static data."""

from solvers.dynamic.dynamicidentifiability import analyse_dynamic
from solvers.dynamic.dynamicnested import DynamicNestedSolver
from solvers.dynamic.dynamicproblem import DynamicProblem, TimeGrid, trajectory_case
from solvers.dynamic.dynamicsimultaneous import DynamicSimultaneousSolver

__all__ = [
    "DynamicNestedSolver",
    "DynamicProblem",
    "DynamicSimultaneousSolver",
    "TimeGrid",
    "analyse_dynamic",
    "trajectory_case",
]
