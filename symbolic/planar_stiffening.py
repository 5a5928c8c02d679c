"""A strain-stiffening plane-strain energy on P1 triangles: neo-Hookean plus an exponential.

The neo-Hookean plane-strain energy of ``symbolic.planar_neohookean`` (eq. P3 there) plus
the isotropic exponential term of Holzapfel-Gasser-Ogden type, written in 2D plane strain
with I1 = tr C of the 2 x 2 C = F^T F (so I1 = 2 at rest):

    psi = psi_NH(E, nu) + k1 / (2 k2) (exp(k2 s^2) - 1),      s = I1 - 2,          (S1)

    psi_NH = mu/2 (I1 - 2 - 2 ln J) + lam/2 (ln J)^2,

with E [N/mm per unit depth], nu, k1 [N/mm] and k2 [-]. The added term and its stress
are zero at rest; at k1 = 0 the energy is the neo-Hookean one exactly. Its stiffness at
rest is **not** zero: s = I1 - 2 = 2 tr(eps) + O(eps^2) is linear in the strain, so at
small strain the term is 2 k1 (tr eps)^2, a bulk stiffness that adds 4 k1 to lam (the
tangent gains 4 k1 d_iJ d_kL at F = I). It stiffens exponentially as s grows. As k2 -> 0
it tends to k1/2 s^2 (used at k2 = 0).

With W(I1) the added term, W1 = dW/dI1 = k1 s e, e = exp(k2 s^2), and
W11 = d^2W/dI1^2 = k1 e (1 + 2 k2 s^2), the first Piola-Kirchhoff stress [N/mm] and its
tangent are

    P = P_NH + 2 W1 F,                                                              (S2)

    dP_iJ/dF_kL = A_NH + 2 W1 d_ik d_JL + 4 W11 F_iJ F_kL,                          (S3)

and the parameter derivatives (F held)

    dP/dk1 = 2 s e F,        dP/dk2 = 2 k1 s^3 e F.                                 (S4)

Assembled exactly as the neo-Hookean model (eq. P7 there, ``Triangles``): the class below
only adds (S1)-(S4) to its parent's energy density, stress, tangent and derivatives.
Parameter order everywhere: p = (E, nu, k1, k2).
"""

from __future__ import annotations

import numpy as np

from symbolic.planar_neohookean import PlanarNeoHookean

NAMES = ("E", "nu", "k1", "k2")
"""The parameters, in the order of every derivative: E [N/mm], nu, k1 [N/mm], k2 [-]."""

EXPONENT_CAP = 200.0
"""Largest k2 s^2 evaluated (exp(200) ~ 7e86, far beyond any equilibrium of the data)."""


def exponential_term(first, k1, k2):
    """W of eq. (S1) [N/mm] and (s, e, W1, W11) at I1 = ``first`` (arrays per triangle).

    k2 = 0 gives the limit k1/2 s^2 (W1 = k1 s, W11 = k1).

    Raises
    ------
    FloatingPointError
        When k2 s^2 exceeds ``EXPONENT_CAP`` (the exponential about to overflow); a Newton
        line search catches it and shortens the step.
    """
    s = first - 2.0
    if np.any(k2 * s * s > EXPONENT_CAP):
        raise FloatingPointError("the exponential term overflows (k2 s^2 too large)")
    e = np.exp(k2 * s * s)
    safe = np.where(k2 > 0, k2, 1.0)
    energy = np.where(k2 > 0, 0.5 * k1 * np.expm1(k2 * s * s) / safe, 0.5 * k1 * s * s)
    return energy, s, e, k1 * s * e, k1 * e * (1.0 + 2.0 * k2 * s * s)


class PlanarStiffening(PlanarNeoHookean):
    """Eqs. (S1)-(S4) on a P1 mesh in plane strain, one (E, nu, k1, k2) per triangle.

    Parameters
    ----------
    points : ndarray (N, 2)
        Nodes [mm].
    triangles : ndarray (M, 3)
        Counter-clockwise node indices.

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
        cells = slice(None) if cells is None else cells
        first = np.einsum("miJ,miJ->m", f, f)
        return exponential_term(first, self.k1[cells], self.k2[cells])

    def energy_density(self, f: np.ndarray, cells=None) -> np.ndarray:
        """psi of eq. (S1) [N/mm] per triangle."""
        return super().energy_density(f, cells) + self._added(f, cells)[0]

    def stress(self, f: np.ndarray, cells=None) -> np.ndarray:
        """P of eq. (S2) (M', 2, 2) [N/mm]."""
        w1 = self._added(f, cells)[3]
        return super().stress(f, cells) + 2.0 * w1[:, None, None] * f

    def tangent(self, f: np.ndarray, cells=None) -> np.ndarray:
        """dP_iJ / dF_kL of eq. (S3) (M', 2, 2, 2, 2) [N/mm]."""
        _, _, _, w1, w11 = self._added(f, cells)
        eye = np.eye(2)
        result = super().tangent(f, cells)
        result = result + 2.0 * w1[:, None, None, None, None] * np.einsum("ik,JL->iJkL", eye, eye)
        return result + 4.0 * w11[:, None, None, None, None] * np.einsum("miJ,mkL->miJkL", f, f)

    def stress_derivatives(self, f: np.ndarray, cells=None) -> tuple[np.ndarray, ...]:
        """dP/dE, dP/dnu (parent) and dP/dk1, dP/dk2 of eq. (S4), each (M', 2, 2)."""
        d_young, d_poisson = super().stress_derivatives(f, cells)
        _, s, e, _, _ = self._added(f, cells)
        k1 = self.k1[slice(None) if cells is None else cells]
        d_k1 = (2.0 * s * e)[:, None, None] * f
        d_k2 = (2.0 * k1 * s**3 * e)[:, None, None] * f
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
