"""Stiffness imaging (docs/imaging.md): ``fieldproblem`` (a field of Young's modulus
behind the markers), ``fieldsensitivity`` (its force operators, eq. I6), ``estimate``
(the regularised estimate by nested or simultaneous solvers, in the inverse's shape),
``laplace`` (its band), ``regularization`` (H1, TV), ``weight`` (Morozov, GCV,
L-curve) and ``fielddesign`` (the next press, I11-I14)."""

from solvers.imaging.estimate import (
    SOLVERS,
    FieldEstimate,
    FieldSimultaneousSolver,
    FieldSolver,
    GaussNewtonSolver,
    LbfgsSolver,
)
from solvers.imaging.fieldproblem import FieldProblem
from solvers.imaging.laplace import Laplace, laplace
from solvers.imaging.regularization import Tikhonov, TotalVariation
from solvers.imaging.weight import discrepancy_weight, gcv_weight, lcurve_weight

__all__ = [
    "SOLVERS",
    "FieldEstimate",
    "FieldSimultaneousSolver",
    "FieldSolver",
    "GaussNewtonSolver",
    "LbfgsSolver",
    "FieldProblem",
    "Laplace",
    "Tikhonov",
    "TotalVariation",
    "discrepancy_weight",
    "gcv_weight",
    "laplace",
    "lcurve_weight",
]
