"""Boundary effect: the inner layer on an elastic foundation instead of fixed
(docs/model.md, "Dynamics").

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
    OneTermStiffness,
    componentwise,
    linear_coefficient,
)
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.skinrules import face_rule, surface_rule
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


class BaseCompliance(Effect):
    """c = 1/k_b [mm^3/N], compliance of a foundation under the inner layer.

    Realistic magnitude 5 mm^3/N (k_b = 0.2 N/mm^3: about 2 mm of muscle of
    E = 0.4 MPa over the frontal bone).
    """

    energies = ("dnurbs", "linear-elastic")  # couples through the linear K
    name = "base_compliance"
    parameters = (Parameter("compliance", "mm^3/N", 1.0, 0.0, 10000.0),)
    magnitude = Magnitude(5.0, "mm^3/N")
    equation = "c (K Delta)_I + M_I Delta_I = 0, c = 1/k_b"
    unit_terms = True

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

    def extra_row_scale(self, theta: np.ndarray) -> float | None:
        """1/c: the inner rows c (K Delta)_I + M_I Delta_I divided by c are K's own rows
        plus k_b M_I, so dg/ds becomes symmetric positive definite (none at c = 0)."""
        compliance = float(theta[0])
        return 1.0 / compliance if compliance > 0.0 else None

    def foundation_matrix(self, model: TissueModel) -> sp.csr_matrix:
        """M_I = integral_{w=0} J^T J dA on the inner points [mm^2]."""

        def build():
            params, area, _, _ = surface_rule(model, 0.0, model.volume.basis.degrees[0] + 2)
            collocation = model.volume.collocation(params)[:, self.inner(model)]
            return sp.csr_matrix(collocation.T @ sp.diags(area) @ collocation)

        return self.cached(model, "M_I", build)

    def _matrices(self, model: TissueModel) -> dict:
        """Per base term, its (free, inner), (inner, free) and (inner, inner) blocks."""

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
                    sp.csr_matrix(matrix[a][:, b])
                    for a, b in ((free, inner), (inner, free), (inner, inner))
                )
            return out

        return self.cached(model, "matrices", build)

    def _blocks(self, model: TissueModel) -> dict:
        """``_matrices`` as CasADi constants."""

        def build():
            return {
                term: tuple(to_casadi_sparse(b) for b in blocks)
                for term, blocks in self._matrices(model).items()
            }

        return self.cached(model, "blocks", build)

    def _terms_used(self, model: TissueModel, values: dict, every: bool = False) -> list:
        """(term, coefficient) of the base model's terms, as ``_coupled`` sums them (those
        with a fixed zero coefficient left out unless ``every``)."""
        if model.energy != "dnurbs":
            return list(zip(CONTINUUM_TERMS, model.coefficients(values)))
        pairs = [(term, linear_coefficient(model, values, term)) for term in self._matrices(model)]
        return [p for p in pairs if every or not (isinstance(p[1], float) and p[1] == 0.0)]

    def stiffness_terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        """Unit terms on [free points; inner points] (this effect's extra state right after
        the free points), stacked: per base term t, its coupling of the free rows to the
        inner points (coefficient c_t) and the inner rows (coefficient c c_t), then the
        foundation (coefficient 1); the order of ``stiffness_coefficients``."""

        def build():
            blocks = self._matrices(model)
            n, k = 3 * model.n_free, 3 * self.extra_points(model)

            def stacked(block):
                return componentwise(block) if model.energy == "dnurbs" else block

            def placed(free_inner=None, inner_free=None, inner_inner=None):
                inner_inner = sp.csr_matrix((k, k)) if inner_inner is None else inner_inner
                grid = [[sp.csr_matrix((n, n)), free_inner], [inner_free, inner_inner]]
                return sp.bmat(grid, format="csr")

            terms = [t for t, _ in self._terms_used(model, model.values(), every=True)]
            out = [placed(free_inner=stacked(blocks[t][0])) for t in terms]
            out += [placed(None, stacked(blocks[t][1]), stacked(blocks[t][2])) for t in terms]
            out.append(placed(inner_inner=componentwise(self.foundation_matrix(model))))
            return out

        return self.cached(model, "terms", build)

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        coefficients = [c for _, c in self._terms_used(model, values, every=True)]
        return ca.vertcat(*coefficients, *[theta[0] * c for c in coefficients], 1.0)

    def _coupled(self, model: TissueModel, values: dict, index: int, delta: ca.MX):
        blocks = self._blocks(model)
        total = 0
        for term, coefficient in self._terms_used(model, values):
            block = blocks[term][index]
            if model.energy != "dnurbs":  # stacked blocks act on vec(Delta)
                product = ca.mtimes(block, ca.vec(delta))
                total = total + coefficient * ca.reshape(product, block.shape[0] // 3, 3)
            else:
                total = total + coefficient * ca.mtimes(block, delta)
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


class SurroundingTissue(OneTermStiffness, Effect):
    """k_s [N/mm^3]: the tissue beyond the marked area holds the lateral faces.

    The volume ends where the markers end; real tissue goes on. Its resistance is
    modelled as a Winkler support of the four lateral faces (u or v = 0 or 1),
    energy 1/2 k_s integral_lateral |u|^2 dA, so K gains k_s M_L with
    M_L = integral_lateral J^T J dA on the free points (each component alike).
    k_s = 0 is the base model's free lateral faces. Realistic magnitude
    0.002 N/mm^3: E / L for E = 20 kPa and a 10 mm reach of the surrounding tissue.
    """

    name = "surrounding_tissue"
    parameters = (Parameter("k_s", "N/mm^3", 0.001, 0.0, 10.0, plausible=(0.0, 1.0)),)
    magnitude = Magnitude(0.002, "N/mm^3")
    equation = "k_s integral_lateral |u|^2 dA (Winkler support of the lateral faces)"

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
