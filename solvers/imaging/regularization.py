"""Regularisers of a stiffness field: Tikhonov on the gradient (H1) and total variation.

Both act on s = log(E / E_ref) (eq. I1) through its physical gradient at the field's
own Gauss points (``StiffnessField.gradient_rule``), averaged over the tissue so that
the weight beta has units of mm^2 whatever the tissue's size:

    R_H1(c) = 1/2 <|grad s|^2>,                                                    (I6)
    R_TV(c) = <sqrt(|grad s|^2 + epsilon^2)> - epsilon,                            (I7)

with <.> the volume mean. Neither penalises a constant s: the mean stiffness is the
data's alone. ``hessian`` of TV is the lagged-diffusivity matrix (positive
semi-definite, the usual Gauss-Newton choice for TV).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.field import StiffnessField
from symbolic.sparse import to_casadi_sparse


class Regularizer:
    """The shared part: the gradient operators D_d and the mean's weights."""

    name = ""

    def __init__(self, stiffness_field: StiffnessField, lengths: tuple[float, float, float]):
        operators, weights = stiffness_field.gradient_rule(lengths)
        self.operators = operators
        self.weights = weights / weights.sum()
        self.stacked = sp.vstack(operators).tocsr()

    def squared_gradient(self, c: np.ndarray) -> np.ndarray:
        """|grad s|^2 at the Gauss points [1/mm^2]."""
        return sum((op @ c) ** 2 for op in self.operators)


class Tikhonov(Regularizer):
    """R_H1 of eq. (I6): a quadratic form 1/2 c^T L c."""

    name = "h1"

    def __init__(self, stiffness_field, lengths):
        super().__init__(stiffness_field, lengths)
        weight = sp.diags(self.weights)
        self.matrix = sum(op.T @ weight @ op for op in self.operators).tocsr()

    def value(self, c: np.ndarray) -> float:
        return 0.5 * float(c @ (self.matrix @ c))

    def gradient(self, c: np.ndarray) -> np.ndarray:
        return self.matrix @ c

    def hessian(self, c: np.ndarray) -> sp.csr_matrix:
        return self.matrix

    def expression(self, c: ca.MX) -> ca.MX:
        """The same as a CasADi expression."""
        return 0.5 * ca.dot(c, ca.mtimes(to_casadi_sparse(self.matrix), c))


class TotalVariation(Regularizer):
    """R_TV of eq. (I7), smoothed by epsilon [1/mm] (default 0.01: a contrast of 1 %
    per mm is where it turns from quadratic to linear)."""

    name = "tv"

    def __init__(self, stiffness_field, lengths, epsilon: float = 0.01):
        super().__init__(stiffness_field, lengths)
        if epsilon <= 0:
            raise ValueError("the smoothing of total variation must be > 0")
        self.epsilon = float(epsilon)

    def _norm(self, c):
        return np.sqrt(self.squared_gradient(c) + self.epsilon**2)

    def value(self, c: np.ndarray) -> float:
        return float(self.weights @ self._norm(c)) - self.epsilon

    def gradient(self, c: np.ndarray) -> np.ndarray:
        scale = self.weights / self._norm(c)
        return sum(op.T @ (scale * (op @ c)) for op in self.operators)

    def hessian(self, c: np.ndarray) -> sp.csr_matrix:
        """The lagged-diffusivity matrix sum_d D_d^T diag(w / |grad s|_eps) D_d."""
        scale = sp.diags(self.weights / self._norm(c))
        return sum(op.T @ scale @ op for op in self.operators).tocsr()

    def expression(self, c: ca.MX) -> ca.MX:
        squared = 0
        for op in self.operators:
            squared = squared + ca.mtimes(to_casadi_sparse(op), c) ** 2
        return ca.dot(ca.DM(self.weights), ca.sqrt(squared + self.epsilon**2)) - self.epsilon


REGULARIZERS = {"h1": Tikhonov, "tv": TotalVariation}
