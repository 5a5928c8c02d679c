"""A strain-stiffening plane-strain energy on P1 triangles: neo-Hookean plus an exponential.

The neo-Hookean plane-strain energy of ``symbolic.planar_neohookean`` (eq. P3 there) plus
an isotropic exponential term of Holzapfel-Gasser-Ogden type in the **isochoric** first
invariant of the 3D deformation in plane strain (F33 = 1). With F the 2 x 2 in-plane
deformation gradient, J = det F and a = F^-T,

    I1_3 = tr(F^T F) + 1,      Ibar1 = J^(-2/3) I1_3,      s = Ibar1 - 3,

    psi = psi_NH(E, nu) + W(s),      W = k1 / (2 k2) (exp(k2 s^2) - 1),             (S1)

    psi_NH = mu/2 (I1 - 2 - 2 ln J) + lam/2 (ln J)^2,      I1 = tr(F^T F),

with E [N/mm per unit depth], nu, k1 [N/mm] and k2 [-]; as k2 -> 0, W tends to
k1/2 s^2 (used at k2 = 0). At k1 = 0 the energy is the neo-Hookean one exactly.

Why isochoric: Ibar1 >= 3 with equality only where the 3D F is a rotation times a
dilatation (in plane strain: F a rotation), so s = 0 and dIbar1/dF = 0 at rest, and at
small strain s = 2 |dev eps|^2 + O(eps^3) (the 3D deviator, eps33 = 0): W is quartic in
the strain, zero in energy, stress **and tangent** at rest, a pure stiffening that leaves
the small-strain moduli to (E, nu). The previous form, s = I1 - 2 = 2 tr(eps) + O(eps^2),
was linear in the strain: at small strain it was 2 k1 (tr eps)^2 and added 4 k1 to lam,
so k1 traded with nu (the keloid fit went to nu = -0.88; docs/realskin.md, "Strain
stiffening on the authors' model").

With e = exp(k2 s^2), W1 = dW/dIbar1 = k1 s e, W11 = d^2W/dIbar1^2 = k1 e (1 + 2 k2 s^2)
and g = dIbar1/dF = J^(-2/3) (2 F - (2/3) I1_3 a), the first Piola-Kirchhoff stress
[N/mm] and its tangent are

    P = P_NH + W1 g,                                                                (S2)

    dP_iJ/dF_kL = A_NH + W11 g_iJ g_kL + W1 dg_iJ/dF_kL,                            (S3)

    dg_iJ/dF_kL = 2 J^(-2/3) [ d_ik d_JL - (2/3) F_iJ a_kL - (2/3) a_iJ F_kL
                               + (2/9) I1_3 a_iJ a_kL + (1/3) I1_3 a_iL a_kJ ],

(using dJ/dF = J a and da_iJ/dF_kL = -a_iL a_kJ), and the parameter derivatives (F held)

    dP/dk1 = s e g,        dP/dk2 = k1 s^3 e g.                                     (S4)

Assembled exactly as the neo-Hookean model (eq. P7 there, ``Triangles``): the class below
only adds (S1)-(S4) to its parent's energy density, stress, tangent and derivatives.
Parameter order everywhere: p = (E, nu, k1, k2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.planar_neohookean import PlanarNeoHookean, _inverse_and_det

NAMES = ("E", "nu", "k1", "k2")
"""The parameters, in the order of every derivative: E [N/mm], nu, k1 [N/mm], k2 [-]."""

EXPONENT_CAP = 200.0
"""Largest k2 s^2 evaluated (exp(200) ~ 7e86); beyond it an evaluation fails. A fit sliding
to k1 -> 0, k2 -> inf would end on it; the stiffening study bounds k2 well inside
(``experiments.realskin.planarstiffening.STIFFENING_CAP``, docs/realskin.md)."""


def exponential_term(s, k1, k2):
    """W of eq. (S1) [N/mm] and (e, W1, W11) at s = Ibar1 - 3 (arrays per triangle).

    Parameters
    ----------
    s : ndarray (M',)
        Ibar1 - 3 [-].
    k1 : ndarray (M',)
        [N/mm].
    k2 : ndarray (M',)
        [-]; k2 = 0 gives the limit k1/2 s^2 (W1 = k1 s, W11 = k1).

    Returns
    -------
    energy, e, w1, w11 : ndarray (M',)
        W [N/mm], exp(k2 s^2) [-], dW/dIbar1 and d^2W/dIbar1^2 [N/mm].

    Raises
    ------
    FloatingPointError
        When k2 s^2 exceeds ``EXPONENT_CAP`` (the exponential about to overflow) or is not
        a number (k2 = inf, s = 0); a Newton line search catches it and shortens the step.
    """
    with np.errstate(invalid="ignore"):
        x = k2 * s * s
    if not np.all(x <= EXPONENT_CAP):  # also NaN: k2 = inf at s = 0
        raise FloatingPointError("the exponential term overflows (k2 s^2 too large)")
    e = np.exp(x)
    safe = np.where(k2 > 0, k2, 1.0)
    energy = np.where(k2 > 0, 0.5 * k1 * np.expm1(x) / safe, 0.5 * k1 * s * s)
    return energy, e, k1 * s * e, k1 * e * (1.0 + 2.0 * x)


@dataclass(frozen=True)
class Isochoric:
    """Ibar1 of eq. (S1) and its derivatives on a stack of F (M', 2, 2).

    Attributes
    ----------
    f, a : ndarray (M', 2, 2)
        F and F^-T [-].
    scale : ndarray (M',)
        J^(-2/3) [-].
    first : ndarray (M',)
        I1_3 = tr(F^T F) + 1 [-].
    s : ndarray (M',)
        Ibar1 - 3 [-].
    g : ndarray (M', 2, 2)
        dIbar1/dF [-].
    """

    f: np.ndarray
    a: np.ndarray
    scale: np.ndarray
    first: np.ndarray
    s: np.ndarray
    g: np.ndarray

    @classmethod
    def of(cls, f: np.ndarray) -> Isochoric:
        """From F (M', 2, 2); raises ``FloatingPointError`` on J <= 0."""
        inverse, det = _inverse_and_det(f)
        if np.any(det <= 0):
            raise FloatingPointError("an inverted triangle (J <= 0)")
        a = np.transpose(inverse, (0, 2, 1))
        scale = det ** (-2.0 / 3.0)
        first = np.einsum("miJ,miJ->m", f, f) + 1.0
        g = scale[:, None, None] * (2.0 * f - (2.0 / 3.0) * first[:, None, None] * a)
        return cls(f, a, scale, first, scale * first - 3.0, g)

    def second(self) -> np.ndarray:
        """dg_iJ/dF_kL of eq. (S3) (M', 2, 2, 2, 2) [-]."""
        f, a, c = self.f, self.a, self.first[:, None, None, None, None]
        eye = np.eye(2)
        bracket = (
            np.einsum("ik,JL->iJkL", eye, eye)
            - (2.0 / 3.0) * (np.einsum("miJ,mkL->miJkL", f, a) + np.einsum("miJ,mkL->miJkL", a, f))
            + (2.0 / 9.0) * c * np.einsum("miJ,mkL->miJkL", a, a)
            + (1.0 / 3.0) * c * np.einsum("miL,mkJ->miJkL", a, a)
        )
        return 2.0 * self.scale[:, None, None, None, None] * bracket


class PlanarStiffening(PlanarNeoHookean):
    """Eqs. (S1)-(S4) on a P1 mesh in plane strain, one (E, nu, k1, k2) per triangle.

    Parameters
    ----------
    points, triangles : ndarray
        The mesh, as ``PlanarNeoHookean``: nodes (N, 2) [mm] and counter-clockwise node
        indices (M, 3).

    Notes
    -----
    Plane strain only (the authors' reduction); the residual, stiffness, energy and pad
    force of the parent use the overridden density, stress and tangent unchanged.
    """

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        super().__init__(points, triangles, "strain")
        self.k1 = np.zeros(len(triangles))
        self.k2 = np.ones(len(triangles))

    def set_parameters(self, young, poisson, k1=0.0, k2=1.0) -> None:
        """E [N/mm], nu, k1 [N/mm] and k2 [-], scalars or one per triangle."""
        super().set_parameters(young, poisson)
        shape = self.young.shape
        self.k1 = np.broadcast_to(np.asarray(k1, dtype=float), shape).copy()
        self.k2 = np.broadcast_to(np.asarray(k2, dtype=float), shape).copy()

    def _added(self, f: np.ndarray, cells):
        """(Isochoric, W, e, W1, W11) of the triangles ``cells`` (default all)."""
        cells = slice(None) if cells is None else cells
        invariant = Isochoric.of(f)
        return invariant, *exponential_term(invariant.s, self.k1[cells], self.k2[cells])

    def energy_density(self, f: np.ndarray, cells=None) -> np.ndarray:
        """psi of eq. (S1) [N/mm] per triangle."""
        return super().energy_density(f, cells) + self._added(f, cells)[1]

    def stress(self, f: np.ndarray, cells=None) -> np.ndarray:
        """P of eq. (S2) (M', 2, 2) [N/mm]."""
        invariant, _, _, w1, _ = self._added(f, cells)
        return super().stress(f, cells) + w1[:, None, None] * invariant.g

    def tangent(self, f: np.ndarray, cells=None) -> np.ndarray:
        """dP_iJ / dF_kL of eq. (S3) (M', 2, 2, 2, 2) [N/mm]."""
        invariant, _, _, w1, w11 = self._added(f, cells)
        g = invariant.g
        result = super().tangent(f, cells)
        result = result + w11[:, None, None, None, None] * np.einsum("miJ,mkL->miJkL", g, g)
        return result + w1[:, None, None, None, None] * invariant.second()

    def stress_derivatives(self, f: np.ndarray, cells=None) -> tuple[np.ndarray, ...]:
        """dP/dE, dP/dnu (parent) and dP/dk1, dP/dk2 of eq. (S4), each (M', 2, 2) [N/mm]."""
        d_young, d_poisson = super().stress_derivatives(f, cells)
        invariant, _, e, _, _ = self._added(f, cells)
        s, g = invariant.s, invariant.g
        k1 = self.k1[slice(None) if cells is None else cells]
        d_k1 = (s * e)[:, None, None] * g
        d_k2 = (k1 * s**3 * e)[:, None, None] * g
        return d_young, d_poisson, d_k1, d_k2

    def residual_derivatives(self, u: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """dR/dp (2N, 4) for p = (E, nu, k1, k2) of the triangles with ``weights`` = 1."""
        cells = np.flatnonzero(weights)
        f = self.mesh.deformation_gradient(u)[cells]
        w = weights[cells, None, None]
        columns = [
            self.mesh.assemble_vector(w * d, cells) for d in self.stress_derivatives(f, cells)
        ]
        return np.stack(columns, axis=1)

    def edge_force_derivatives(self, u, normals, owners, weights) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobians of ``edge_force``: d/du (2, 2N) and d/dp (2, 4), p = (E, nu, k1, k2)."""
        f = self.mesh.deformation_gradient(u)[owners]
        grad, dofs, n_dof = self.mesh.grad[owners], self.mesh.dofs[owners].ravel(), self.mesh.n_dof
        local = np.einsum("niJkL,nJ,nbL->nibk", self.tangent(f, owners), normals, grad)
        by_u = np.stack([np.bincount(dofs, local[:, i].ravel(), minlength=n_dof) for i in (0, 1)])
        w = weights[owners, None, None]
        by_p = np.stack(
            [np.einsum("kiJ,kJ->i", d * w, normals) for d in self.stress_derivatives(f, owners)],
            axis=1,
        )
        return by_u, by_p
