"""Stiffness imaging (docs/imaging.md): ``fieldproblem`` (a field of Young's modulus
behind the markers), ``fieldsensitivity`` (its force operators, eq. I6), ``estimate``
(the regularised estimate three ways), ``laplace`` (its band), ``regularization`` (H1,
TV), ``weight`` (Morozov, GCV, L-curve) and ``fielddesign`` (the next press, I11-I14)."""

from solvers.imaging.estimate import FieldEstimate, gauss_newton, lbfgs, simultaneous
from solvers.imaging.fieldproblem import FieldProblem
from solvers.imaging.laplace import Laplace, laplace
from solvers.imaging.regularization import Tikhonov, TotalVariation
from solvers.imaging.weight import discrepancy_weight, gcv_weight, lcurve_weight

__all__ = [
    "FieldEstimate",
    "FieldProblem",
    "Laplace",
    "Tikhonov",
    "TotalVariation",
    "discrepancy_weight",
    "gauss_newton",
    "gcv_weight",
    "laplace",
    "lbfgs",
    "lcurve_weight",
    "simultaneous",
]
