"""The dynamic inverse: mu, gamma and alpha from marker trajectories (docs/dynamic.md).

- ``problem``: the problem stated once (trajectories, time grid, scheme);
- ``scheme``: the trapezoidal scheme and its exact forward sensitivities;
- ``simultaneous``: the discretised dynamics as constraints of one IPOPT NLP;
- ``nested``: single shooting over the scheme;
- ``identifiability``: what trajectories tell, against static data."""

from solvers.dynamic.identifiability import analyse_dynamic
from solvers.dynamic.nested import DynamicNestedSolver
from solvers.dynamic.problem import DynamicProblem, TimeGrid, trajectory_case
from solvers.dynamic.simultaneous import DynamicSimultaneousSolver

__all__ = [
    "DynamicNestedSolver",
    "DynamicProblem",
    "DynamicSimultaneousSolver",
    "TimeGrid",
    "analyse_dynamic",
    "trajectory_case",
]
