"""The static inverse (docs/inverse.md): ``problem`` (model and observations, stated
once, eq. 24), ``space`` (the parameters, their bounds and internal coordinate),
``noise`` (the residual's covariance and whitening), ``methods`` (the reduced-space and
full-space solution methods, shared with the dynamic inverse), their static forms
``nested`` and ``simultaneous`` (one IPOPT NLP; ``lagrangian`` its derivatives), ``paperfaithful``
(the paper's own nested method), ``result`` (what every method returns),
``identifiability`` and ``continuumfit`` (the homogeneous continuum's forward map)."""

from solvers.inverse.identifiability import analyse, profile_likelihood
from solvers.inverse.methods import FullSpaceSolver, ReducedSpaceSolver
from solvers.inverse.nested import NestedSolver
from solvers.inverse.noise import Whitening, rest_noise_map
from solvers.inverse.paperfaithful import PaperNestedSolver
from solvers.inverse.problem import InverseProblem, LoadCase, PlanarProblem, observation_case
from solvers.inverse.result import InverseResult
from solvers.inverse.simultaneous import IpoptSettings, SimultaneousSolver
from solvers.inverse.space import ParameterSpace, SkinParameterSpace

__all__ = [
    "FullSpaceSolver",
    "InverseProblem",
    "InverseResult",
    "IpoptSettings",
    "LoadCase",
    "NestedSolver",
    "PaperNestedSolver",
    "ParameterSpace",
    "PlanarProblem",
    "ReducedSpaceSolver",
    "SimultaneousSolver",
    "SkinParameterSpace",
    "Whitening",
    "analyse",
    "observation_case",
    "profile_likelihood",
    "rest_noise_map",
]
