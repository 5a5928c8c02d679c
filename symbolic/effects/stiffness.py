"""Stiffness effects: terms added to the elastic force K(B; x)(B - B0) (docs/model.md, eq. 18).

Each is the gradient of an extra energy, so the extended K stays symmetric; all
vanish at theta = 0 (``nonlinear_stiffening`` lives in ``stiffening``).

- ``heterogeneity``: every alpha_i multiplied by the linear field
  1 + h_u (2u - 1) + h_v (2v - 1) (a stiffness gradient across the patch).
- ``bending``: the rigidity terms beta sum_{i<=j} J_ij^T J_ij of eq. (18).
- ``pre_tension``: sigma0 integral_skin g^ab (n . J_a)^T (n . J_b) dA, the geometric
  stiffness of an in-plane pre-stress sigma0 [N/mm] of the skin against rotation
  of its surface (normal displacement), in the physical metric.
- ``volumetric_coupling``: lambda integral (div u)^2 dV over the physical volume
  (Poisson effect), coupling the x, y, z components; a model may say which divergence
  (``volumetric_matrix``: the real skin's slab, a membrane, the in-plane one).
- ``shear_coupling``: mu_L integral 2 eps:eps dV, the continuum's shear energy; with
  volumetric_coupling it completes the isotropic linear elasticity of eq. (C3)
  beside the alpha energy.

On the continuum base model (``symbolic.continuum_model``) heterogeneity scales E
instead of the alpha; bending, volumetric_coupling and shear_coupling extend the
paper's model only (the continuum has them).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.basis import FIRST_DERIVATIVES
from symbolic.continuum import PhysicalGradient
from symbolic.continuum_model import CONTINUUM_TERMS
from symbolic.effects.base import Effect, OneTermStiffness, componentwise, stacked_free_block
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.skinrules import surface_rule
from symbolic.energy import quadrature
from symbolic.model import TissueModel
from symbolic.sparse import ProductTerm, combination, combined

ALPHA_TERMS = ("alpha_u", "alpha_v", "alpha_w")


def _gradient_fields():
    """The shape fields (2u - 1), (2v - 1) on parameter points."""
    return (
        lambda p: 2.0 * p[:, 0] - 1.0,
        lambda p: 2.0 * p[:, 1] - 1.0,
    )


def weighted_stiffness(model: TissueModel, shapes) -> list[list[sp.csr_matrix]]:
    """Per field f_j (a callable of parameter points), the base stiffness terms weighted by
    f_j on the free points (stacked order).

    The paper's model: sum_i integral f_j J_i^T J_i for alpha_i (times the model's own
    alpha field, if any; ``weighted_gram``), one block per alpha term. The continuum: K_mu
    and K_lambda of eq. (C3) with both moduli scaled by f_j. ``scaled_coefficients`` gives
    their coefficients: the stiffness of a material whose every modulus is
    multiplied by 1 + sum_j theta_j f_j, minus the base's.
    """
    if model.energy != "dnurbs":
        gradient = model.gradient  # the continuum model's own operators (eq. C2)
        out = []
        for shape in shapes:
            matrices = gradient.elasticity(shape)
            out.append([stacked_free_block(model, matrices[t]) for t in CONTINUUM_TERMS])
        return out
    fields = dict(model.fields or {})
    basis = model.volume.basis
    points, weights = quadrature(basis, model.extra_points)
    collocations: dict = {}  # per derivative, for every shape (one per cell of a region family)
    out = []
    for shape in shapes:
        blocks = []
        for term in ALPHA_TERMS:
            base = fields.get(term)
            scale = 1.0 if base is None else (base(points) if callable(base) else base)
            derivative = FIRST_DERIVATIVES[term[-1]]
            if derivative not in collocations:
                collocations[derivative] = basis.collocation(points, derivative)
            gram = _gram(collocations[derivative], weights, shape(points) * scale, term)
            blocks.append(componentwise(model.free_block(gram)))
        out.append(blocks)
    return out


def _gram(collocation: sp.csr_matrix, weights: np.ndarray, values, name: str) -> sp.csr_matrix:
    """integral c J_d^T J_d from the collocation of J_d at the quadrature points and c
    there: ``weighted_gram`` of a field (its quadrature branch, the same arithmetic), with
    the collocation made once for every shape instead of once per shape and term (144
    cells x 3 terms on the real skin's slab: 2.8 of the 5.1 s their terms took)."""
    values = np.asarray(values, dtype=float).reshape(-1)
    if values.shape != (collocation.shape[0],) or not np.all(np.isfinite(values)):
        raise ValueError(f"coefficient field {name!r} must give one finite value per point")
    gram = (collocation.T @ sp.diags(weights * values) @ collocation).tocsr()
    return (0.5 * (gram + gram.T)).tocsr()


def field_products(model: TissueModel, effect) -> list[ProductTerm]:
    """The continuum's ``weighted_stiffness`` terms of ``effect`` as ``ProductTerm``s:
    their products act on the free points through the model's own operators
    (``PhysicalGradient.elasticity_product``) and their matrices, when a coefficient
    is no longer zero, are the effect's ``terms`` (assembled once for all of them). The
    shear and volumetric products of one shape come from one pass over the points: the
    products are applied term after term, and the second reuses the first's."""
    gradient, n = model.gradient, model.rest.shape[0]
    index = np.concatenate([model.free + k * n for k in range(3)])
    last: list = []  # (shape, x, both products) of the last call: its twin term reuses it

    def product(shape, term):
        def apply(x):
            if not (last and last[0] is shape and np.array_equal(last[1], x)):
                full = np.zeros((3 * n,) + x.shape[1:])
                full[index] = x
                last[:] = [shape, x.copy(), gradient.elasticity_product(full, shape)]
            return last[2][term][index]

        return apply

    def assemble(at):
        return lambda: effect.terms(model)[at]

    pairs = [(shape, term) for shape in effect.shapes(model) for term in CONTINUUM_TERMS]
    return [ProductTerm(index.size, product(*pair), assemble(k)) for k, pair in enumerate(pairs)]


def scaled_coefficients(model: TissueModel, values: dict, theta, n_fields: int) -> ca.MX:
    """theta_j coefficient_t for every (field j, term t), j-major: the coefficients of the
    flattened ``weighted_stiffness`` (the alpha on the paper's model, the Lame pair on the
    continuum)."""
    if model.energy != "dnurbs":
        coefficients = model.coefficients(values)
    else:
        coefficients = tuple(model.coefficient(term, values) for term in ALPHA_TERMS)
    return ca.vertcat(*[theta[j] * c for j in range(n_fields) for c in coefficients])


class FieldStiffness:
    """A stiffness effect over fields: its unit terms are ``weighted_stiffness`` of the
    fields ``shapes(model)``, flattened j-major, and its K_theta their ``combination``
    with ``scaled_coefficients`` (each made once per model). A mixin of ``Effect``."""

    def terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        return self.cached(
            model,
            "terms",
            lambda: [b for terms in weighted_stiffness(model, self.shapes(model)) for b in terms],
        )

    def stiffness(self, model: TissueModel, values: dict, theta):
        """sum_j theta_j sum_t coefficient_t K_jt as one sparse product (``combined``): a
        Function evaluating it holds U and one result in its work, not a sum per (j, t)."""
        blocks = self.cached(model, "blocks", lambda: combination(self.terms(model)))
        return combined(blocks, scaled_coefficients(model, values, theta, self.dim))

    def stiffness_terms(self, model: TissueModel) -> list:
        """The unit terms; on the continuum as ``ProductTerm``s (``field_products``)."""
        if model.energy == "dnurbs":
            return self.terms(model)
        return self.cached(model, "products", lambda: field_products(model, self))

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        return scaled_coefficients(model, values, theta, self.dim)


class Heterogeneity(FieldStiffness, Effect):
    """alpha_i(u, v) = alpha_i (1 + h_u (2u-1) + h_v (2v-1)), eq. (18): a stiffness gradient.

    K gains sum_j h_j sum_i alpha_i integral f_j J_i^T J_i (``weighted_gram`` with
    the field f_j). Realistic magnitude 0.5: alpha varies by +-50 % along u and
    +-25 % along v across the patch (skin thickness and stiffness vary that
    much across a forehead).

    The field was bilinear (a third parameter h_uv with (2u-1)(2v-1)) until the twist
    proved not identifiable from contacts 8 mm around the centre: on FE tissue with a
    gradient (E x 0.4-1.6 across the markers, docs/results/tissue-defaults.md) h_uv swung by +-0.27
    as each corner contact was left out, so the fit to four contacts predicted the
    fifth worse than no gradient (left-out chi^2 3066 -> 3197) and the guard rejected
    it; without h_uv the same fit lowers chi^2 as much (3339 -> 2695) and predicts the
    fifth better (3066 -> 2860). A field that varies more is the opt-in
    ``stiffness_field``.
    """

    energies = ("dnurbs", "linear-elastic")  # scales the linear K of eq. (C3)
    linear = True
    name = "heterogeneity"
    parameters = (
        Parameter("h_u", "1", 0.1, -0.9, 0.9),
        Parameter("h_v", "1", 0.1, -0.9, 0.9),
    )
    magnitude = Magnitude(0.5, "1", direction=(1.0, -0.5))
    equation = "alpha_i (1 + h_u (2u-1) + h_v (2v-1))"

    def shapes(self, model: TissueModel):
        return _gradient_fields()

    def least_modulus(self, theta: np.ndarray) -> float:
        """-|h_u| - |h_v|, at a corner of the volume. The box bounds alone allow a
        modulus of 1 - 1.8 there: on FE tissue with a gradient, left-out refits went to
        h = (-0.89, -0.65), where K(p) is indefinite (22 of 247 factorisations of one
        diagnosis, each a failed Cholesky and a SuperLU solve of a model with no
        equilibrium)."""
        return -float(np.sum(np.abs(theta)))


SKIN_BANDS_MM = ((0.0, 1.0), (1.0, 2.0))
"""Depth bands [mm] below the skin surface of the ``layering`` effect's two fields."""


def _depth_bands(model: TissueModel):
    """Indicators of ``SKIN_BANDS_MM`` on parameter points: depth (1 - w) T(u, v), T the
    local thickness between the inner (w = 0) and outer (w = 1) surfaces."""
    volume = model.volume

    def band(top: float, bottom: float):
        def indicator(p):
            p = np.asarray(p, dtype=float)
            ends = [np.column_stack([p[:, :2], np.full(len(p), w)]) for w in (0.0, 1.0)]
            thickness = np.linalg.norm(volume.evaluate(ends[1]) - volume.evaluate(ends[0]), axis=1)
            depth = (1.0 - p[:, 2]) * thickness
            return ((depth >= top) & (depth < bottom)).astype(float)

        return indicator

    return tuple(band(*limits) for limits in SKIN_BANDS_MM)


class Layering(FieldStiffness, Effect):
    """A stiffer (or softer) skin over the fat: E x (1 + s_1) in the top 1 mm and
    E x (1 + s_2) from 1 to 2 mm below the skin surface (``SKIN_BANDS_MM``).

    Skin (dermis, about 1-2 mm) is several times stiffer than the fat below it. The two
    bands give the depth profile the data can see: s_1 is the ratio minus one of the
    skin's modulus to the fat's, and s_2 says whether the stiff layer goes on below
    1 mm (the interface depth). Markers on the surface weigh the top band most: on FE
    data with a 1.5 mm skin 5x stiffer (docs/stepzero.md, row G) the fit gives
    s_1 = 4.4 +- 0.3 and s_2 = -0.2 +- 0.2. Both moduli scale together (nu unchanged).
    Linear in s, zero at s = 0; the continuum only (the paper's energy has no depth).
    Realistic magnitude 4: a skin 5x stiffer.
    """

    energies = ("linear-elastic",)
    linear = True
    name = "layering"
    parameters = (
        Parameter("s_1", "1", 1.0, -0.9, 300.0),
        Parameter("s_2", "1", 1.0, -0.9, 300.0),
    )
    magnitude = Magnitude(4.0, "1 (E_skin / E - 1)", direction=(1.0, 0.5))
    equation = "E (1 + s_1 [depth < 1 mm] + s_2 [1 <= depth < 2 mm])"

    def shapes(self, model: TissueModel):
        return self.cached(model, "bands", lambda: _depth_bands(model))

    def least_modulus(self, theta: np.ndarray) -> float:
        """min(0, s_1, s_2): the bands do not overlap. With a gradient beside it the sum
        can reach zero (h = (0.71, -0.17) and s_1 = -0.18 on FE tissue: 1 - 0.88 - 0.18
        at a corner of the top band)."""
        return min(0.0, float(np.min(theta)))


class Bending(OneTermStiffness, Effect):
    """beta [N/mm] times the rigidity terms sum_{i<=j} J_ij^T J_ij of eq. (18).

    Added to the model's own beta (default 0). Realistic magnitude 5e-3 N/mm
    (the probe then moves about 15 % less).
    """

    name = "bending"
    parameters = (Parameter("beta", "N/mm", 0.001, 0.0, 10.0),)
    magnitude = Magnitude(0.005, "N/mm")
    equation = "beta integral sum_{i<=j} |d_ij V|^2 (eq. 18)"
    energies = ("dnurbs",)

    def stiffness_terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        def build():
            total = sum(m for t, m in model.terms.items() if t.startswith("beta_"))
            return [componentwise(model.free_block(total))]

        return self.cached(model, "terms", build)


class StackedStiffness(OneTermStiffness, Effect):
    """An effect theta_0 K on the free points, K (3n, 3n) stacked from ``matrix(model)``."""

    def matrix(self, model: TissueModel) -> sp.csr_matrix:
        """K on all control points, (3n, 3n) in stacked order (``build``, once per model)."""
        return self.cached(model, "matrix", lambda: self.build(model))

    def build(self, model: TissueModel) -> sp.csr_matrix:
        """K on all control points, (3n, 3n) in stacked order."""
        raise NotImplementedError

    def stiffness_terms(self, model: TissueModel) -> list[sp.csr_matrix]:
        return self.cached(model, "terms", lambda: [stacked_free_block(model, self.matrix(model))])


class PreTension(StackedStiffness):
    """sigma0 [N/mm]: in-plane pre-stress of the skin, a geometric stiffness.

    An isotropic membrane pre-stress sigma0 adds 1/2 sigma0 integral_skin g^ab
    u_,a . u_,b dA to the energy (a, b in {u, v}; g_ab = V_a . V_b of the rest
    skin). Split u_,a into its tangential part and its normal part (n . u_,a):

    - the tangential part stiffens in-plane stretching by sigma0, next to the
      skin's in-plane material stiffness E t (0.1-1 MPa times 1-2 mm, i.e.
      100-2000 N/mm): a change below 1e-3, dropped;
    - the normal part is the rotation of the skin's surface element,
      delta n = -g^ab (n . u_,a) V_b, whose only stiffness in a membrane is the
      pre-stress: a first-order effect (a drum's T laplacian w).

    So K_sigma = integral_{w=1} g^ab (n . J_a)^T (n . J_b) dA: it acts on the
    normal component of the displacement through its in-plane gradients and
    couples x, y, z (3n x 3n, stacked). The base model's alpha terms act on
    every component alike, so pre-tension is told apart by loads with an
    in-plane component (a tilted probe). Realistic magnitude 0.05 N/mm (in vivo
    skin tension, 10-50 kPa times 1-2 mm).
    """

    name = "pre_tension"
    parameters = (Parameter("sigma0", "N/mm", 0.01, 0.0, 10.0, plausible=(0.0, 1.0)),)
    magnitude = Magnitude(0.05, "N/mm")
    equation = "sigma0 integral_skin g^ab (n . d_a u)(n . d_b u) dA"

    def build(self, model: TissueModel) -> sp.csr_matrix:
        """K_sigma on all control points, (3n, 3n) in stacked order [1]."""
        params, area, du, dv = surface_rule(model, 1.0, model.volume.basis.degrees[0] + 2)
        metric = np.stack(
            [
                np.stack([np.sum(du * du, 1), np.sum(du * dv, 1)], -1),
                np.stack([np.sum(dv * du, 1), np.sum(dv * dv, 1)], -1),
            ],
            -2,
        )
        inverse = np.linalg.inv(metric)
        normal = model.volume.outer_normal(params[:, :2])
        rows = []
        for derivative in ((1, 0, 0), (0, 1, 0)):
            j = sp.csr_matrix(model.volume.collocation(params, derivative))
            rows.append(sp.hstack([sp.diags(normal[:, i]) @ j for i in range(3)]).tocsr())
        total = sum(
            rows[a].T @ sp.diags(area * inverse[:, a, b]) @ rows[b]
            for a in range(2)
            for b in range(2)
        )
        return sp.csr_matrix(0.5 * (total + total.T))


class VolumetricCoupling(StackedStiffness):
    """lambda [N/mm^2]: 1/2 lambda integral (div u)^2 dV over the physical volume.

    With G = [V_u V_v V_w] of the rest shape B0 at a quadrature point,
    div u = sum_a sum_i (G^-1)_ai (J_a Delta)_i, a row D of length 3n acting on
    vec(Delta); K_lambda = sum_q w_q |det G_q| D_q^T D_q (3n x 3n) couples the
    x, y, z components, which eq. (18) does not. Realistic magnitude
    0.05 N/mm^2 (50 kPa, a few times the through-thickness shear modulus of the
    phantom, for a nearly incompressible layer).
    """

    name = "volumetric_coupling"
    parameters = (Parameter("lambda", "N/mm^2", 0.01, 0.0, 100.0),)
    magnitude = Magnitude(0.05, "N/mm^2")
    equation = "lambda integral (div u)^2 dV (physical volume)"
    energies = ("dnurbs",)

    def build(self, model: TissueModel) -> sp.csr_matrix:
        """K_lambda on all control points, (3n, 3n) in stacked order [mm]: the model's own
        ``volumetric_matrix()`` when it has one (a membrane's in-plane divergence), else
        the 3D divergence of the physical volume."""
        own = getattr(model, "volumetric_matrix", None)
        if own is not None:
            return own()
        gradient = PhysicalGradient.of(model.volume)
        return gradient.gram([gradient.divergence()])


class ShearCoupling(StackedStiffness):
    """mu_L [N/mm^2]: mu_L integral 2 eps:eps dV, the shear energy of a continuum.

    eq. (18)'s alpha energy is a component-wise Laplacian in parameter space; a
    continuum also couples the components through eps:eps = (grad u : grad u +
    grad u : grad u^T) / 2. K_mu of ``symbolic.continuum`` (eq. C3) is that term,
    stacked (3n x 3n). With volumetric_coupling it completes isotropic linear
    elasticity beside the alpha energy. Realistic magnitude 0.005 N/mm^2 (5 kPa:
    E of about 15 kPa for soft tissue).
    """

    name = "shear_coupling"
    parameters = (Parameter("mu_L", "N/mm^2", 0.001, 0.0, 100.0, plausible=(0.0, 1.0)),)
    magnitude = Magnitude(0.005, "N/mm^2")
    equation = "mu_L integral 2 eps:eps dV (physical volume, eq. C3)"
    energies = ("dnurbs",)

    def build(self, model: TissueModel) -> sp.csr_matrix:
        """K_mu on all control points, (3n, 3n) in stacked order [mm]."""
        gradient = PhysicalGradient.of(model.volume)
        return gradient.gram(gradient.strain(), 2.0)
