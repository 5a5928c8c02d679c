"""The compressible neo-Hookean energy on P1 triangles, in plane strain or plane stress.

The original authors' model of the skin extensometer (docs/realskin.md, "Reproducing the
authors"): a 2D body, displacement u = (u_x, u_y) [mm] linear on each triangle, with the
in-plane deformation gradient F = I + grad u (2 x 2), C = F^T F, J = det F and the
through-thickness stretch lam3. The energy per unit reference area [N/mm] is

    psi = mu/2 (tr C + lam3^2 - 3 - 2 ln(J lam3)) + lam/2 (ln(J lam3))^2,          (P1)

    mu = E / (2 (1 + nu)),      lam = E nu / ((1 + nu) (1 - 2 nu)),                 (P2)

the 3D Lame constants of Young's modulus E [N/mm, per unit depth] and Poisson's ratio nu.

* **Plane strain** (the authors'): lam3 = 1, so

      psi = mu/2 (I1 - 2 - 2 ln J) + lam/2 (ln J)^2,      I1 = tr C.               (P3)

* **Plane stress**: lam3 makes psi stationary, d psi / d lam3 = 0, i.e. on every triangle

      mu (lam3^2 - 1) + lam ln(J lam3) = 0,                                         (P4)

  solved by Newton (monotone in lam3 > 0) and condensed out of the tangent.

The first Piola-Kirchhoff stress [N/mm] (lam3 held: its own derivative vanishes by P4)

    P = mu (F - F^-T) + lam ell F^-T,        ell = ln(J lam3),                       (P5)

and its tangent dP_iJ / dF_kL, with a = F^-1,

    A = mu d_ik d_JL + (mu - lam ell) a_Jk a_Li + lam a_Ji a_Lk
        - [plane stress] (lam / lam3)^2 / psi_33 a_Ji a_Lk,                           (P6)

    psi_33 = d^2 psi / d lam3^2 = mu (1 + 1 / lam3^2) + lam (1 - ell) / lam3^2.

Assembled on the mesh (area A_e, shape gradients dN_a/dX_J constant per triangle):

    W(u) = sum_e A_e psi_e,     R_ai = sum_e A_e P_iJ dN_a/dX_J,
    K_ai,bk = sum_e A_e dN_a/dX_J A_iJkL dN_b/dX_L,                                  (P7)

all vectorised over the triangles. The nodal vector is u[2 a + i] (node a, component i);
forces come out in N because E is per unit depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

PLANES = ("strain", "stress")
"""The two planar reductions: F33 = 1 (plane strain) or P33 = 0 (plane stress)."""


def lame(young, poisson):
    """Lame constants (mu, lam) [N/mm] of eq. (P2) from E [N/mm] and nu (arrays or scalars)."""
    young, poisson = np.asarray(young, dtype=float), np.asarray(poisson, dtype=float)
    return young / (2.0 * (1.0 + poisson)), young * poisson / (
        (1.0 + poisson) * (1.0 - 2.0 * poisson)
    )


def lame_derivatives(young, poisson):
    """d(mu, lam)/dE and d(mu, lam)/dnu: ((dmu_dE, dlam_dE), (dmu_dnu, dlam_dnu))."""
    young, poisson = np.asarray(young, dtype=float), np.asarray(poisson, dtype=float)
    q = (1.0 + poisson) * (1.0 - 2.0 * poisson)
    by_young = (1.0 / (2.0 * (1.0 + poisson)), poisson / q)
    by_poisson = (
        -young / (2.0 * (1.0 + poisson) ** 2),
        young * (1.0 + 2.0 * poisson**2) / q**2,
    )
    return by_young, by_poisson


def thickness_stretch(mu, lam, det, tol: float = 1e-13, maxit: int = 50) -> np.ndarray:
    """lam3 of plane stress, the root of eq. (P4) on every triangle (Newton from 1).

    g(s) = mu (s^2 - 1) + lam ln(J s) is increasing and concave for s > 0 (mu, lam > 0),
    so Newton from s = 1 converges monotonically.
    """
    stretch = np.ones_like(det)
    for _ in range(maxit):
        g = mu * (stretch * stretch - 1.0) + lam * np.log(det * stretch)
        step = g / (2.0 * mu * stretch + lam / stretch)
        stretch = stretch - step
        if np.max(np.abs(step), initial=0.0) < tol:
            break
    return stretch


@dataclass(frozen=True)
class Triangles:
    """P1 geometry: areas, shape-function gradients and the sparse pattern.

    Attributes
    ----------
    area : ndarray (M,)
        Reference areas [mm^2].
    grad : ndarray (M, 3, 2)
        dN_a / dX_J [1/mm], constant on each triangle.
    dofs : ndarray (M, 6)
        Degrees of freedom (2 a + i) of each triangle's nodes.
    n_dof : int
        2 x the number of nodes.
    slot : ndarray (36 M,)
        Where each element matrix entry goes in the CSR data of ``indices``, ``indptr``
        (the sparse pattern, found once).
    """

    area: np.ndarray
    grad: np.ndarray
    dofs: np.ndarray
    n_dof: int
    slot: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray

    @classmethod
    def of(cls, points: np.ndarray, triangles: np.ndarray) -> Triangles:
        """From nodes (N, 2) [mm] and counter-clockwise triangles (M, 3)."""
        corners = np.asarray(points, dtype=float)[triangles]
        edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=2)
        det = edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]
        if np.any(det <= 0):
            raise ValueError("triangles must be counter-clockwise and not degenerate")
        reference = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # dN_a / dxi
        grad = np.einsum("ak,mkJ->maJ", reference, np.linalg.inv(edges))
        dofs = np.repeat(2 * np.asarray(triangles), 2, axis=1) + np.tile([0, 1], 3)
        n_dof = 2 * len(points)
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        keys, slot = np.unique(rows * n_dof + cols, return_inverse=True)
        indptr = np.searchsorted(keys // n_dof, np.arange(n_dof + 1))
        return cls(0.5 * det, grad, dofs, n_dof, slot.ravel(), keys % n_dof, indptr)

    def deformation_gradient(self, u: np.ndarray) -> np.ndarray:
        """F = I + grad u (M, 2, 2) of the nodal vector u (2N,) [mm]."""
        local = u[self.dofs].reshape(-1, 3, 2)
        return np.eye(2) + np.einsum("mai,maJ->miJ", local, self.grad)

    def assemble_vector(self, stress: np.ndarray, cells=None) -> np.ndarray:
        """sum_e A_e S_iJ dN_a/dX_J (2N,) of a per-triangle tensor S (M', 2, 2) on ``cells``."""
        cells = slice(None) if cells is None else cells
        local = self.area[cells, None, None] * np.einsum("miJ,maJ->mai", stress, self.grad[cells])
        return np.bincount(self.dofs[cells].ravel(), local.ravel(), minlength=self.n_dof)

    def assemble_matrix(self, tangent: np.ndarray) -> sp.csr_matrix:
        """K of eq. (P7) (2N, 2N) from per-triangle tangents A (M, 2, 2, 2, 2)."""
        local = np.einsum("maJ,miJkL,mbL->maibk", self.grad, tangent, self.grad, optimize=True)
        local = self.area[:, None, None, None, None] * local
        data = np.bincount(self.slot, local.ravel(), minlength=len(self.indices))
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_dof, self.n_dof))


def _inverse_and_det(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    det = f[:, 0, 0] * f[:, 1, 1] - f[:, 0, 1] * f[:, 1, 0]
    inverse = np.stack(
        [np.stack([f[:, 1, 1], -f[:, 0, 1]], 1), np.stack([-f[:, 1, 0], f[:, 0, 0]], 1)], 1
    )
    return inverse / det[:, None, None], det


class PlanarNeoHookean:
    """Eqs. (P1)-(P7) on a P1 mesh, with one (E, nu) per triangle.

    Parameters
    ----------
    points : ndarray (N, 2)
        Nodes [mm].
    triangles : ndarray (M, 3)
        Counter-clockwise node indices.
    plane : {"strain", "stress"}
        The planar reduction (eq. P3 or P4).

    Notes
    -----
    An inverted triangle (J <= 0) raises ``FloatingPointError``; a Newton line search
    catches it and shortens the step.
    """

    def __init__(self, points: np.ndarray, triangles: np.ndarray, plane: str = "strain"):
        if plane not in PLANES:
            raise ValueError(f"plane must be one of {PLANES}, got {plane!r}")
        self.plane = plane
        self.mesh = Triangles.of(points, triangles)
        self.young = np.ones(len(triangles))
        self.poisson = np.zeros(len(triangles))

    def set_parameters(self, young, poisson) -> None:
        """E [N/mm] and nu, scalars or one per triangle."""
        shape = self.young.shape
        self.young = np.broadcast_to(np.asarray(young, dtype=float), shape).copy()
        self.poisson = np.broadcast_to(np.asarray(poisson, dtype=float), shape).copy()

    # -------------------------------------------------------------------- the law
    def _state(self, f: np.ndarray, cells):
        cells = slice(None) if cells is None else cells
        mu, lam = lame(self.young[cells], self.poisson[cells])
        inverse, det = _inverse_and_det(f)
        if np.any(det <= 0):
            raise FloatingPointError("an inverted triangle (J <= 0)")
        stretch = thickness_stretch(mu, lam, det) if self.plane == "stress" else np.ones_like(det)
        return mu, lam, inverse, det, stretch, np.log(det * stretch)

    def energy_density(self, f: np.ndarray, cells=None) -> np.ndarray:
        """psi of eq. (P1) [N/mm] per triangle, F (M', 2, 2) on ``cells`` (default all)."""
        mu, lam, _, _, stretch, ell = self._state(f, cells)
        first = np.einsum("miJ,miJ->m", f, f)
        return 0.5 * mu * (first + stretch**2 - 3.0 - 2.0 * ell) + 0.5 * lam * ell**2

    def stress(self, f: np.ndarray, cells=None) -> np.ndarray:
        """P of eq. (P5) (M', 2, 2) [N/mm]."""
        mu, lam, inverse, _, _, ell = self._state(f, cells)
        inverse_t = np.transpose(inverse, (0, 2, 1))
        return mu[:, None, None] * (f - inverse_t) + (lam * ell)[:, None, None] * inverse_t

    def tangent(self, f: np.ndarray, cells=None) -> np.ndarray:
        """dP_iJ / dF_kL of eq. (P6) (M', 2, 2, 2, 2) [N/mm]."""
        mu, lam, a, _, stretch, ell = self._state(f, cells)
        eye = np.eye(2)
        volumetric = np.einsum("mJi,mLk->miJkL", a, a)
        result = mu[:, None, None, None, None] * np.einsum("ik,JL->iJkL", eye, eye)
        result = result + (mu - lam * ell)[:, None, None, None, None] * np.einsum(
            "mJk,mLi->miJkL", a, a
        )
        factor = lam
        if self.plane == "stress":
            psi33 = mu * (1.0 + 1.0 / stretch**2) + lam * (1.0 - ell) / stretch**2
            factor = lam - (lam / stretch) ** 2 / psi33
        return result + factor[:, None, None, None, None] * volumetric

    def stress_derivatives(self, f: np.ndarray, cells=None) -> tuple[np.ndarray, np.ndarray]:
        """dP/dE and dP/dnu (each (M', 2, 2)) of each triangle's own E and nu, F held.

        From eq. (P5): dP/dmu = F - F^-T + lam dell/dmu F^-T, dP/dlam = (ell + lam
        dell/dlam) F^-T, with dell = dlam3 / lam3 and, in plane stress, dlam3/dmu =
        -(lam3^2 - 1) / D, dlam3/dlam = -ell / D, D = 2 mu lam3 + lam / lam3 (eq. P4).
        """
        mu, lam, inverse, _, stretch, ell = self._state(f, cells)
        inverse_t = np.transpose(inverse, (0, 2, 1))
        if self.plane == "stress":
            slope = 2.0 * mu * stretch + lam / stretch
            ell_mu, ell_lam = -(stretch**2 - 1.0) / slope / stretch, -ell / slope / stretch
        else:
            ell_mu = ell_lam = np.zeros_like(ell)
        by_mu = f - inverse_t + (lam * ell_mu)[:, None, None] * inverse_t
        by_lam = (ell + lam * ell_lam)[:, None, None] * inverse_t
        cells = slice(None) if cells is None else cells
        (mu_e, lam_e), (mu_n, lam_n) = lame_derivatives(self.young[cells], self.poisson[cells])
        d_young = mu_e[:, None, None] * by_mu + lam_e[:, None, None] * by_lam
        d_poisson = mu_n[:, None, None] * by_mu + lam_n[:, None, None] * by_lam
        return d_young, d_poisson

    # ------------------------------------------------------------------ assembled
    def energy(self, u: np.ndarray) -> float:
        """W(u) of eq. (P7) [N mm]."""
        density = self.energy_density(self.mesh.deformation_gradient(u))
        return float(np.sum(self.mesh.area * density))

    def residual(self, u: np.ndarray) -> np.ndarray:
        """R = dW/du (2N,) [N]: the internal force on every node."""
        return self.mesh.assemble_vector(self.stress(self.mesh.deformation_gradient(u)))

    def stiffness(self, u: np.ndarray) -> sp.csr_matrix:
        """K = dR/du (2N, 2N) [N/mm], symmetric."""
        return self.mesh.assemble_matrix(self.tangent(self.mesh.deformation_gradient(u)))

    def residual_derivatives(self, u: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """dR/dp (2N, 2) for p = (E, nu) of the triangles with ``weights`` (M,) = 1.

        A triangle's E (and nu) is weights x p plus what is held; 0 means held.
        """
        cells = np.flatnonzero(weights)
        f = self.mesh.deformation_gradient(u)[cells]
        d_young, d_poisson = self.stress_derivatives(f, cells)
        w = weights[cells, None, None]
        return np.stack(
            [
                self.mesh.assemble_vector(w * d_young, cells),
                self.mesh.assemble_vector(w * d_poisson, cells),
            ],
            axis=1,
        )

    # -------------------------------------------------------------- edge traction
    def edge_force(self, u: np.ndarray, normals: np.ndarray, owners: np.ndarray) -> np.ndarray:
        """sum_k P(F of triangle owners[k]) normals[k] (2,) [N]: the net traction across
        boundary edges with length-weighted outward normals (K, 2) [mm]."""
        f = self.mesh.deformation_gradient(u)[owners]
        return np.einsum("kiJ,kJ->i", self.stress(f, owners), normals)

    def edge_force_derivatives(self, u, normals, owners, weights) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobians of ``edge_force``: d/du (2, 2N) and d/dp (2, 2) for p = (E, nu) of
        the triangles with ``weights`` (as in ``residual_derivatives``)."""
        f = self.mesh.deformation_gradient(u)[owners]
        tangent = self.tangent(f, owners)
        local = np.einsum("niJkL,nJ,nbL->nibk", tangent, normals, self.mesh.grad[owners])
        by_u = np.zeros((2, self.mesh.n_dof))
        for i in range(2):
            by_u[i] = np.bincount(
                self.mesh.dofs[owners].ravel(), local[:, i].ravel(), minlength=self.mesh.n_dof
            )
        d_young, d_poisson = self.stress_derivatives(f, owners)
        w = weights[owners, None]
        by_p = np.stack(
            [np.einsum("kiJ,kJ->i", d * w[:, :, None], normals) for d in (d_young, d_poisson)],
            axis=1,
        )
        return by_u, by_p
