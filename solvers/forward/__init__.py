"""The forward solution: ``equilibrium`` (K(B; x)(B - B0) = F_B by Newton, docs/model.md
eq. 22), ``componentwise`` (the linear model on one scalar factorisation),
``linearpath`` (a model linear in the state: every load case and sensitivity from one
factorisation of K(p), shared by the diagnosis, design and imaging) and ``evaluator``
(CasADi's sparse Jacobians into scipy matrices)."""

from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import (
    Equilibrium,
    EquilibriumError,
    EquilibriumSolver,
    NewtonSettings,
)

__all__ = ["Equilibrium", "EquilibriumError", "EquilibriumSolver", "NewtonSettings", "ScalarSystem"]
