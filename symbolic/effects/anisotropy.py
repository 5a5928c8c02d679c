"""``anisotropy`` (opt-in): the alpha_v term of eq. (18) scaled, on a model that ties it.

The real skin's slab (``symbolic.skin_slab``) is isotropic in the plane: alpha_v is tied
to alpha_u so that the membrane tensions along and across the pull are equal. Skin is
stiffer along Langer's lines; this effect frees the ratio T_y / T_x = 1 + a.
"""

from __future__ import annotations

import casadi as ca
import scipy.sparse as sp

from symbolic.effects.base import Effect, OneTermStiffness, componentwise
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


class Anisotropy(OneTermStiffness, Effect):
    """a [1]: the alpha_v term of eq. (18) times 1 + a, K_theta = a c_v K_v.

    On a model whose alpha_v is tied to alpha_u (the real skin's isotropic slab,
    ``symbolic.skin_slab``), 1 + a = T_y / T_x, the membrane tension across the pull
    over the tension along it (skin is stiffer along Langer's lines). On the paper's
    model, whose alpha_v is estimated, it is alpha_v itself (confounded: its score test
    says so). Opt-in. Bounds -0.999 < a < 999 (T_y / T_x from 1e-3 to 1e3).
    """

    name = "anisotropy"
    parameters = (Parameter("a", "1", 0.1, -0.999, 999.0),)
    magnitude = Magnitude(1.0, "1 (T_y / T_x - 1)")
    equation = "alpha_v (1 + a) J_v^T J_v (eq. 18)"
    energies = ("dnurbs",)

    def stiffness_terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        return self.cached(
            model, "terms", lambda: [componentwise(model.free_block(model.terms["alpha_v"]))]
        )

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        return theta[0] * model.coefficient("alpha_v", values)

    def stiffness(self, model: TissueModel, values: dict, theta) -> ca.MX:
        block = self.cached(model, "term", lambda: to_casadi_sparse(self.stiffness_terms(model)[0]))
        return self.stiffness_coefficients(model, values, theta) * block
