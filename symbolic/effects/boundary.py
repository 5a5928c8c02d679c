"""Boundary effect: the inner layer on an elastic foundation instead of fixed (MODEL.md s. 2).

``base_compliance``: the inner surface (w = 0) rests on a Winkler foundation of
stiffness k_b [N/mm^3], with energy 1/2 k_b integral_{w=0} |u|^2 dA. Its inner
control points Delta_I become extra state, with equilibrium

    c (K_IF Delta_F + K_II Delta_I) + M_I Delta_I = 0,     c = 1/k_b [mm^3/N],

where M_I = integral_{w=0} J^T J dA [mm^2] and K is the linear K0 of eq. (18) at
the current alpha, beta (a skin load has F_I = 0). The free rows gain
K_FI Delta_I. At c = 0 the extra rows read M_I Delta_I = 0, so Delta_I = 0:
the fixed inner layer, exactly, with a non-singular Jacobian. (Stiffness
effects act on the free rows only; their reaction on the inner layer is a
second-order term in c.) On the continuum base model K is mu_L K_mu + lambda
K_lambda of eq. (C3), whose blocks act on the stacked vec(Delta).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.continuum_model import CONTINUUM_TERMS
from symbolic.effects.base import (
    CaseSymbols,
    Effect,
    componentwise,
    face_rule,
    linear_coefficient,
    surface_rule,
)
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


class BaseCompliance(Effect):
    """c = 1/k_b [mm^3/N], compliance of a foundation under the inner layer.

    Realistic magnitude 5 mm^3/N (k_b = 0.2 N/mm^3: about 2 mm of muscle of
    E = 0.4 MPa over the frontal bone).
    """

    energies = ("dnurbs", "linear-elastic")  # couples through the linear K
    name = "base_compliance"
    parameter_names = ("compliance",)
    units = ("mm^3/N",)
    scales = (1.0,)
    lower = (0.0,)
    upper = (1e4,)
    default_magnitude = 5.0
    magnitude_unit = "mm^3/N"
    equation = "c (K Delta)_I + M_I Delta_I = 0, c = 1/k_b"

    def inner(self, model: TissueModel) -> np.ndarray:
        """Indices of the fixed control points of the inner layer that the foundation frees."""

        def build():
            shape = model.volume.shape
            layer = np.zeros(shape, dtype=bool)
            layer[:, :, 0] = True
            if model.boundary.fix_lateral:
                layer[[0, -1], :, :] = False
                layer[:, [0, -1], :] = False
            candidates = np.flatnonzero(layer.reshape(-1))
            return np.intersect1d(candidates, model.fixed)

        return self.cached(model, "inner", build)

    def extra_points(self, model: TissueModel) -> int:
        return int(self.inner(model).size)

    def foundation_matrix(self, model: TissueModel) -> sp.csr_matrix:
        """M_I = integral_{w=0} J^T J dA on the inner points [mm^2]."""

        def build():
            params, area, _, _ = surface_rule(model, 0.0, model.volume.basis.degrees[0] + 2)
            collocation = model.volume.collocation(params)[:, self.inner(model)]
            return sp.csr_matrix(collocation.T @ sp.diags(area) @ collocation)

        return self.cached(model, "M_I", build)

    def _blocks(self, model: TissueModel) -> dict:
        def build():
            inner, free = self.inner(model), model.free
            out = {}
            if model.energy != "dnurbs":
                # the continuum's stacked terms (eq. C3): blocks act on vec(Delta)
                n = model.volume.basis.size
                inner, free = (np.concatenate([i + k * n for k in range(3)]) for i in (inner, free))
                terms = model.elasticity
            else:
                terms = model.terms
            for term, matrix in terms.items():
                matrix = sp.csr_matrix(matrix)
                out[term] = tuple(
                    to_casadi_sparse(matrix[a][:, b])
                    for a, b in ((free, inner), (inner, free), (inner, inner))
                )
            return out

        return self.cached(model, "blocks", build)

    def _coupled(self, model: TissueModel, values: dict, index: int, delta: ca.MX):
        blocks = self._blocks(model)
        if model.energy != "dnurbs":
            total = 0
            for coefficient, term in zip(model.coefficients(values), CONTINUUM_TERMS):
                block = blocks[term][index]
                product = ca.mtimes(block, ca.vec(delta))
                total = total + coefficient * ca.reshape(product, block.shape[0] // 3, 3)
            return total
        total = 0
        for term, pair in blocks.items():
            coefficient = linear_coefficient(values, term)
            if isinstance(coefficient, float) and coefficient == 0.0:
                continue
            total = total + coefficient * ca.mtimes(pair[index], delta)
        return total

    def internal_force(self, model: TissueModel, symbols: CaseSymbols, theta):
        return self._coupled(model, symbols.values, 0, symbols.extra[self.name])

    def extra_residual(self, model: TissueModel, symbols: CaseSymbols, theta):
        inner_delta = symbols.extra[self.name]
        reaction = self._coupled(model, symbols.values, 1, symbols.delta)
        reaction = reaction + self._coupled(model, symbols.values, 2, inner_delta)
        foundation = to_casadi_sparse(self.foundation_matrix(model))
        return theta[0] * reaction + ca.mtimes(foundation, inner_delta)


def lateral_rule(model: TissueModel) -> tuple[np.ndarray, np.ndarray]:
    """Gauss points on the four lateral faces (u or v = 0 or 1) with area weights [mm^2]."""
    points_per_span = max(model.volume.basis.degrees) + 2
    faces = [
        face_rule(model, axis, end, points_per_span)[:2] for axis in (0, 1) for end in (0.0, 1.0)
    ]
    return np.vstack([f[0] for f in faces]), np.concatenate([f[1] for f in faces])


class SurroundingTissue(Effect):
    """k_s [N/mm^3]: the tissue beyond the marked area holds the lateral faces.

    The volume ends where the markers end; real tissue goes on. Its resistance is
    modelled as a Winkler support of the four lateral faces (u or v = 0 or 1),
    energy 1/2 k_s integral_lateral |u|^2 dA, so K gains k_s M_L with
    M_L = integral_lateral J^T J dA on the free points (each component alike).
    k_s = 0 is the base model's free lateral faces. Realistic magnitude
    0.002 N/mm^3: E / L for E = 20 kPa and a 10 mm reach of the surrounding tissue.
    """

    name = "surrounding_tissue"
    parameter_names = ("k_s",)
    units = ("N/mm^3",)
    scales = (1e-3,)
    lower = (0.0,)
    upper = (10.0,)
    default_magnitude = 0.002
    magnitude_unit = "N/mm^3"
    equation = "k_s integral_lateral |u|^2 dA (Winkler support of the lateral faces)"
    linear = True

    def matrix(self, model: TissueModel) -> sp.csr_matrix:
        """M_L on all control points, (n, n) [mm^2]."""

        def build():
            points, area = lateral_rule(model)
            collocation = sp.csr_matrix(model.volume.collocation(points))
            return sp.csr_matrix(collocation.T @ sp.diags(area) @ collocation)

        return self.cached(model, "M_L", build)

    def stiffness_terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        return self.cached(
            model, "terms", lambda: [componentwise(model.free_block(self.matrix(model)))]
        )

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        return theta[0]

    def stiffness(self, model: TissueModel, values: dict, theta):
        block = self.cached(
            model, "M_L_free", lambda: to_casadi_sparse(self.stiffness_terms(model)[0])
        )
        return theta[0] * block
