"""Continuum base models: the volume spline with a linear-elastic or hyperelastic energy.

The stiffness of ``TissueModel`` is eq. (18), sum_t c_t (I3 (x) K_t) on the free
control points. Here it is the continuum of ``symbolic.continuum`` instead,

    K(x) = mu_L(E, nu) K_mu + lambda(E, nu) K_lambda           (eq. C3),

two stacked (3 n, 3 n) terms that couple the x, y and z components. The residual,
its closed-form Jacobian, the prescribed displacements and the loads are those of
``TissueModel``, so the nested and the simultaneous inverse accept the model as it
is. E [kPa] and nu [1] are its parameters (``PARAMETERS``); mass and damping are
the D-NURBS ones of eq. (13) and (16), unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.basis import gauss_rule
from symbolic.continuum import KPA, PhysicalGradient, lame
from symbolic.curvature import ForceCurvature
from symbolic.hyperelastic import NeoHookeanForce, NeoHookeanTangent
from symbolic.model import TissueModel
from symbolic.sparse import combination, combined, pattern_entries, to_casadi_sparse

CONTINUUM_TERMS = ("shear", "volumetric")
"""The terms of eq. (C3): K_mu (coefficient mu_L) and K_lambda (coefficient lambda)."""

CONTINUUM_PARAMETERS = frozenset({"E", "nu"})
EXPONENTIAL_PARAMETERS = CONTINUUM_PARAMETERS | {"k1", "k2"}
FIBRE_PARAMETERS = EXPONENTIAL_PARAMETERS | {"kf1", "kf2", "fibre_angle"}


class ContinuumModel(TissueModel):
    """Isotropic linear elasticity in physical coordinates (docs/continuum.md).

    Same parameters as ``TissueModel``; the paper's alpha and beta do not enter.
    ``E`` [kPa] and ``nu`` set the Lame pair; k0 (stiffening) is not available.
    """

    componentwise = False
    energy = "linear-elastic"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.parameters["k0"] != 0.0:
            raise ValueError(f"the {self.energy} model has no stiffening k0; leave k0 at 0")
        self.gradient = PhysicalGradient.of(self.volume, self.extra_points)
        """The physical-gradient operators at the Gauss points (eq. C2)."""
        self.elasticity = self.gradient.elasticity()
        """K_mu and K_lambda on every control point, stacked (3 n, 3 n) [mm]."""
        free = np.concatenate([self.free + k * self.volume.basis.size for k in range(3)])
        self.continuum = {t: self.elasticity[t][free][:, free] for t in CONTINUUM_TERMS}
        """K_mu and K_lambda on the free points, CSR: the linear path sums them with the
        effects' CSR terms on one pattern (``solvers.forward.linearpath``); a CSC copy was
        converted back there for every model, 5 % of a diagnosis on row D."""
        self._dm: dict | None = None

    @property
    def _continuum_dm(self) -> dict:
        """The free terms as CasADi constants, for the symbolic path only (made on use:
        0.6 s at 27 x 27 x 4, which the linear path never needs)."""
        if self._dm is None:
            self._dm = {t: to_casadi_sparse(m) for t, m in self.continuum.items()}
        return self._dm

    # --------------------------------------------------------------- the terms
    def is_linear(self, names: tuple[str, ...] = ()) -> bool:
        if "k0" in names:
            raise ValueError(f"the {self.energy} model has no k0 to estimate")
        return True

    def influential(self, names: tuple[str, ...]) -> np.ndarray:
        """E and nu enter the equilibrium; the paper's alpha, beta, mu, gamma do not."""
        return np.array([n in CONTINUUM_PARAMETERS for n in names])

    def coefficients(self, values: dict) -> list:
        """[mu_L, lambda] [N/mm^2] of the values (numbers or CasADi expressions)."""
        return list(lame(values["E"], values["nu"]))

    def stiffness_matrix(self, overrides: dict[str, float] | None = None) -> sp.csr_matrix:
        """K(x) on the free points, stacked (3 n_free, 3 n_free) [N/mm] (not eq. 18)."""
        mu_l, lam = self.coefficients(self.values(overrides))
        return mu_l * self.continuum["shear"] + lam * self.continuum["volumetric"]

    def elastic_force(self, delta: ca.MX, values: dict, symbolic: tuple[str, ...]) -> ca.MX:
        """K(x) vec(Delta) as an (n_free, 3) expression [N]."""
        force = 0
        for term, coefficient in zip(CONTINUUM_TERMS, self.coefficients(values)):
            force = force + coefficient * ca.mtimes(self._continuum_dm[term], ca.vec(delta))
        return ca.reshape(force, self.n_free, 3)

    def linear_terms(self, names: tuple[str, ...]) -> tuple[ca.MX, ca.MX, list[str]]:
        """x, c(x) = [mu_L, lambda] and the two terms of eq. (C3)."""
        x, values = self.symbolic_values(names)
        return x, ca.vertcat(*self.coefficients(values)), list(CONTINUUM_TERMS)

    def term_columns(self, terms: list[str], vector: ca.MX) -> ca.MX:
        """[K_t v]_t, (3 n_free, 2): dg/dc_t at Delta = v."""
        return ca.horzcat(*[ca.mtimes(self._continuum_dm[t], vector) for t in terms])

    def free_term(self, term: str, form: str = "kron"):
        """K_t on the free points, stacked (it is not a Kronecker product here)."""
        if form != "kron":
            raise ValueError("the continuum terms couple the components: use form='kron'")
        return self.continuum[term]

    def stiffness_expression(self, coefficients: ca.MX, terms: list[str]) -> ca.MX:
        """K(x) = mu_L K_mu + lambda K_lambda on the free points, stacked (eq. C3)."""
        return combined(combination([self.continuum[t] for t in terms]), coefficients)

    def edges(self):
        raise ValueError(f"the {self.energy} model has no spring edges (no k0 stiffening)")


def face_areas(volume, w: float = 0.0) -> np.ndarray:
    """integral of N_a dA over the face w = const of the volume, per control point
    (n,) [mm^2] (Gauss rule of degree + 1 points per knot span in u and v)."""
    (pu, wu), (pv, wv) = (gauss_rule(b) for b in volume.basis.bases[:2])
    uu, vv = np.meshgrid(pu, pv, indexing="ij")
    params = np.column_stack([uu.ravel(), vv.ravel(), np.full(uu.size, w)])
    normal = np.cross(volume.evaluate(params, (1, 0, 0)), volume.evaluate(params, (0, 1, 0)))
    area = np.linalg.norm(normal, axis=1) * np.outer(wu, wv).ravel()
    return np.asarray(volume.collocation(params).T @ area).ravel()


@dataclass
class NeoHookeanModel(ContinuumModel):
    """The compressible neo-Hookean energy of eq. (C6) as the base model (large strain).

    Same parameters as ``ContinuumModel`` (E [kPa], nu); the internal force is eq. (C8),
    nonlinear in the displacement, so the solvers take their Newton and AD paths. At rest
    its tangent is ``ContinuumModel``'s K(x); ``stiffness_matrix`` returns that tangent.

    Parameters
    ----------
    support : float
        Stiffness [N/mm^3] of an elastic (Winkler) foundation under the inner face w = 0
        that resists only the normal displacement u_z, lumped on the control points:
        f_az += support * integral(N_a dA) * Delta_az. 0 (default): none. A membrane
        with a free inner face buckles out of its plane under an in-plane pull, and
        Newton's branch then depends on its start (docs/realskin.md); skin lies on fat.
    """

    energy = "neo-hookean"
    support: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (np.isfinite(self.support) and self.support >= 0):
            raise ValueError(f"support must be a stiffness >= 0 N/mm^3, got {self.support}")
        self.force = NeoHookeanForce(
            [p[:, self.free] for p in self.gradient.operators],
            self.gradient.volume,
            exponential=self.exponential,
            fibres=self.fibres,
        )
        self._tangent: NeoHookeanTangent | None = None
        self._curvature: ForceCurvature | None = None
        self._support = None  # the foundation on u_z of the free points [N/mm]
        if self.support > 0.0:
            self._support = self.support * face_areas(self.volume)[self.free]
            zeros = np.zeros(2 * self.n_free)
            self._support_matrix = sp.diags(np.concatenate([zeros, self._support]))

    def stiffness_matrix(self, overrides: dict[str, float] | None = None) -> sp.csr_matrix:
        """The tangent at rest: K(x) of eq. (C3), plus the foundation [N/mm]."""
        matrix = super().stiffness_matrix(overrides)
        return matrix if self._support is None else (matrix + self._support_matrix).tocsr()

    @property
    def is_linear_fixed(self) -> bool:
        return False

    def is_linear(self, names: tuple[str, ...] = ()) -> bool:
        super().is_linear(names)  # refuses k0
        return False

    def elastic_force(self, delta: ca.MX, values: dict, symbolic: tuple[str, ...]) -> ca.MX:
        """f(Delta) of eq. (C8) on the free points (and the foundation), (n_free, 3) [N]."""
        force = self.force(delta, *self._energy_coefficients(values))
        if self._support is None:
            return force
        column = ca.DM(self._support) * delta[:, 2]
        return force + ca.horzcat(ca.DM.zeros(self.n_free, 2), column)

    def tangent(self, names: tuple[str, ...] = ()):
        """(vec(Delta_free), x) -> K_T of eq. (C9) on the free points (numpy, CSC)."""
        names = tuple(names)
        element_tangent = self._element_tangent()
        support = None  # the foundation's entries on the tangent's fixed pattern
        if self._support is not None:
            support = pattern_entries(element_tangent.pattern, self._support_matrix)

        def tangent(delta_vec: np.ndarray, x: np.ndarray) -> sp.csc_matrix:
            coefficients = self._numeric_coefficients(names, x)
            matrix = element_tangent(self._on_all_points(delta_vec), *coefficients)
            if support is not None:
                matrix.data += support
            return matrix

        return tangent

    def force_curvature(self, names: tuple[str, ...] = ()):
        """(vec(Delta_free), x, vec(w)) -> d2(w . f)/dDelta2 on the free points (numpy,
        CSC; ``symbolic.curvature``): f of eq. (C8), w a weight on the free points'
        components. The foundation is linear in Delta and adds nothing."""
        names = tuple(names)
        if self._curvature is None:
            self._curvature = ForceCurvature(self._element_tangent(), self.exponential, self.fibres)

        def curvature(delta_vec: np.ndarray, x: np.ndarray, weight: np.ndarray) -> sp.csc_matrix:
            coefficients = self._numeric_coefficients(names, x)
            delta, weight = self._on_all_points(delta_vec), self._on_all_points(weight)
            return self._curvature(delta, weight, *coefficients)

        return curvature

    def _element_tangent(self) -> NeoHookeanTangent:
        """The element-batched tangent of eq. (C8) (built once)."""
        if self._tangent is None:
            gradient = self.gradient
            values = self.volume.collocation(gradient.points)
            self._tangent = NeoHookeanTangent(
                values, gradient.operators, gradient.volume, self.free
            )
        return self._tangent

    def _numeric_coefficients(self, names: tuple[str, ...], x: np.ndarray) -> tuple:
        """``_energy_coefficients`` at the values ``x`` of ``names``, unchecked like the
        CasADi force: IPOPT may step past a bound by its relaxation (nu < 0 by 1e-8)."""
        return self._energy_coefficients({**self.parameters, **dict(zip(names, np.ravel(x)))})

    def _on_all_points(self, vector: np.ndarray) -> np.ndarray:
        """vec of the free points' values (x components first) as (n, 3) on every
        control point, 0 on the fixed ones."""
        field = np.zeros_like(self.rest)
        field[self.free] = np.asarray(vector)[: 3 * self.n_free].reshape(3, -1).T
        return field

    def _energy_coefficients(self, values: dict) -> tuple:
        """The numbers the force and the tangent take after Delta: (mu_L, lambda)
        [N/mm^2] (values may be CasADi expressions)."""
        return tuple(self.coefficients(values))


class ExponentialModel(NeoHookeanModel):
    """The neo-Hookean energy plus the isochoric exponential stiffening of eq. (C10).

    Parameters E [kPa], nu, k1 [kPa] and k2 [1]. The added term, its stress and its
    tangent vanish at rest, so the small-strain behaviour is ``NeoHookeanModel``'s
    (and ``stiffness_matrix``, the tangent at rest, is its K(x)); at k1 = 0 the model is
    the neo-Hookean one, so k1 is the loop's stiffening effect with null value 0.
    """

    energy = "exponential"
    exponential = True

    def influential(self, names: tuple[str, ...]) -> np.ndarray:
        """E, nu, k1 and k2 enter the equilibrium."""
        return np.array([n in EXPONENTIAL_PARAMETERS for n in names])

    def _energy_coefficients(self, values: dict) -> tuple:
        """(mu_L, lambda, k1) [N/mm^2] and k2 [1]: the stress (C7) + (C11)."""
        return (*self.coefficients(values), KPA * values["k1"], values["k2"])


class FibreModel(ExponentialModel):
    """The exponential energy plus one fibre family in the skin's plane, eq. (C13).

    Parameters E [kPa], nu, k1 [kPa], k2 [1], kf1 [kPa], kf2 [1] and fibre_angle [deg,
    from x]. The fibres resist only stretch, and their term, stress and tangent vanish
    at rest, so at kf1 = 0 the model is ``ExponentialModel`` (and at k1 = kf1 = 0 the
    neo-Hookean one): kf1 is the loop's anisotropic stiffening effect with null value 0.
    """

    energy = "fibres"
    fibres = True

    def influential(self, names: tuple[str, ...]) -> np.ndarray:
        """Every parameter of the energy enters the equilibrium."""
        return np.array([n in FIBRE_PARAMETERS for n in names])

    def _energy_coefficients(self, values: dict) -> tuple:
        """(mu_L, lambda, k1) [N/mm^2], k2 [1], kf1 [N/mm^2], kf2 [1], phi [rad]: the
        stress (C7) + (C11) + (C14)."""
        angle = values["fibre_angle"] * (np.pi / 180.0)
        return (*super()._energy_coefficients(values), KPA * values["kf1"], values["kf2"], angle)


ENERGIES = {
    "dnurbs": TissueModel,
    "linear-elastic": ContinuumModel,
    "neo-hookean": NeoHookeanModel,
    "exponential": ExponentialModel,
    "fibres": FibreModel,
}
"""Base models by the name ``dvs fit --energy`` takes."""
