"""``stiffness_field``: the stiffness scaled by a field over the skin, with a smoothness prior.

The general form of ``heterogeneity`` (a bilinear field) and of the rectangle scan of
real skin: every stiffness of the base model is multiplied by

    1 + s(u, v),        s = sum_k c_k phi_k(u, v),                                 (F1)

with phi_k the degree-1 tensor B-spline basis of ``symbolic.field.StiffnessField``
over the skin (``shape`` nodes, 4 x 4 by default), so c_k is s at node k. On the
paper's model the alpha of eq. (18) are scaled, on the linear-elastic one E (eq. C3).
The force is linear in c and in the state: K gains sum_k c_k K_k, with K_k the base
stiffness integrated with the weight phi_k. Since the phi_k are non-negative and sum
to 1, c_k > -1 keeps the stiffness positive everywhere (the lower bound is -0.9).

Sixteen free coefficients would fit noise as readily as stiffness; the effect
therefore carries a Gaussian prior (``Effect.prior``), c ~ N(0, Q^-1), which the
fit adds to chi^2 as c^T Q c:

    Q = N / (A tau^2) (M + ell^2 G),                                               (F2)

with M = integral phi phi^T dA and G = integral grad phi . grad phi^T dA over the
tissue's (u, v) extent of area A, tau the prior's RMS of s (0.5: +-50 %, the
effect's realistic magnitude) and ell the node spacing [mm]. Under this prior the
expected mean square of s is about tau^2, and fields rougher than the node spacing
are costly. A further row holds the area mean of s at 0 (``MEAN_PIN``): without it
the field and E trade a common factor (on scikit-fem data the field went to its lower
bound at the unobserved margin while E rose tenfold). The loop counts the field by its
effective degrees of freedom, tr((J^T J + sigma^2 Q)^-1 J^T J) (``solvers.diagnosis.fit``).
The constant field is the base stiffness's own direction; the score test projects it
out.

The effect is not in the default library (``symbolic.effects.library``): a field
explains a bilinear gradient too, and would otherwise appear as heterogeneity's
rival on every such dataset. Ask for it by name (``dvs diagnose --candidates``).
"""

from __future__ import annotations

import numpy as np

from symbolic.effects.base import Effect
from symbolic.effects.stiffness import FieldStiffness
from symbolic.field import StiffnessField, tissue_lengths
from symbolic.model import TissueModel

PRIOR_RMS = 0.5
"""tau of eq. (F2): the prior's RMS of s [1]."""
MEAN_PIN = 1e3
"""The area mean of s is held at 0 by a prior row 1e3 / tau times it: the mean
stiffness is the base model's E (or alpha), not the field's."""


class StiffnessFieldEffect(FieldStiffness, Effect):
    """Every stiffness times 1 + s(u, v) of eq. (F1), with the prior of eq. (F2).

    Parameters
    ----------
    shape : tuple of int
        Nodes of the field along u and v (default 4 x 4: N = 16).
    """

    energies = ("dnurbs", "linear-elastic")
    linear = True
    name = "stiffness_field"
    default_magnitude = 0.5
    magnitude_unit = "1"
    equation = "(1 + sum_k c_k phi_k(u, v)) times every stiffness (eq. 18 / C3)"

    def __init__(self, shape: tuple[int, int] = (4, 4)) -> None:
        super().__init__()
        self.field = StiffnessField(tuple(int(n) for n in shape), "surface", 1)
        n_u, n_v = self.field.shape
        self.parameter_names = tuple(f"c_{i}_{j}" for i in range(n_u) for j in range(n_v))
        n = self.field.size
        self.units = ("1",) * n
        self.scales = (0.1,) * n
        self.lower = (-0.9,) * n
        self.upper = (3.0,) * n

    def direction(self) -> tuple[float, ...]:
        """A stiff spot: 1 at the node nearest (1/3, 2/3) of the skin, 0 elsewhere."""
        nodes = self.field.nodes()[:, :2]
        spot = np.argmin(np.linalg.norm(nodes - [1.0 / 3.0, 2.0 / 3.0], axis=1))
        return tuple(float(k == spot) for k in range(self.field.size))

    def least_modulus(self, theta: np.ndarray) -> float:
        """min(0, min_k c_k): the phi_k are non-negative and sum to one."""
        return min(0.0, float(np.min(theta)))

    def shapes(self, model: TissueModel):
        """The field's basis functions phi_k as callables of parameter points."""
        return [
            lambda p, k=k: self.field.collocation(p)[:, k].toarray().ravel()
            for k in range(self.field.size)
        ]

    def prior(self, model: TissueModel) -> np.ndarray:
        """R with R^T R = Q of eq. (F2), and the mean's row, (N + 1, N) [1]."""

        def build():
            lengths = tissue_lengths(model)
            area = lengths[0] * lengths[1]
            points, unit = self.field.rule()
            weights = unit * area  # [mm^2]
            phi = self.field.collocation(points).toarray()
            mass = phi.T @ (weights[:, None] * phi)
            operators, _ = self.field.gradient_rule(lengths)
            stiffness = sum(op.T @ op.multiply(weights[:, None]) for op in operators).toarray()
            spacing = min(length / (n - 1) for length, n in zip(lengths, self.field.shape))
            scale = self.field.size / (area * PRIOR_RMS**2)
            precision = scale * (mass + spacing**2 * stiffness)
            factor = np.linalg.cholesky(0.5 * (precision + precision.T)).T
            mean = mass.sum(axis=0) / area  # mean @ c is the area mean of s
            return np.vstack([factor, MEAN_PIN / PRIOR_RMS * mean])

        return self.cached(model, "prior", build)
