"""Isotropic linear elasticity in the volume spline, isogeometric (docs/continuum.md).

The paper's stiffness (docs/model.md, eq. 18) is a component-wise vector Laplacian in the
parameter cube. A continuum stores the strain energy

    W(u) = mu_L eps:eps + lambda/2 (tr eps)^2,     eps = (grad u + grad u^T) / 2,   (C1)

per unit physical volume, with grad taken in physical coordinates x(u, v, w) =
sum_i N_i(u, v, w) B0_i, the rest geometry. The displacement is the spline's own,
u(u, v, w) = sum_i N_i Delta_i (isoparametric), so

    d u_i / d x_j = sum_a (d u_i / d xi_a) (G^-1)_aj,    G_ia = d x_i / d xi_a,      (C2)

and the energy integral over the physical volume is a quadratic form in vec(Delta)
(x components of every control point first, then y, then z):

    integral W dV = 1/2 vec(Delta)^T (mu_L K_mu + lambda K_lambda) vec(Delta),        (C3)
    K_mu = integral 2 E^T E dV,    K_lambda = integral D^T D dV,

with E the rows of eps (Voigt, off-diagonals weighted sqrt 2) and D = tr eps = div u.
The integral is the spline's Gauss rule, (degree + 1) points per knot span and
direction, mapped by |det G|: exact when the geometry map is affine, and otherwise
accurate to the quadrature error of a rational integrand (measured in the tests).

Units: lengths [mm], forces [N], so mu_L and lambda are in N/mm^2 (= MPa); Young's
modulus E is quoted in kPa (``lame``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from symbolic.basis import FIRST_DERIVATIVES, BSplineBasis, VolumeBasis
from symbolic.elements import ElementAssembly
from symbolic.energy import quadrature
from symbolic.volume import VolumeSpline

KPA = 1e-3
"""1 kPa in N/mm^2."""


def lame(young_kpa, poisson):
    """Lame parameters (mu_L, lambda) [N/mm^2] of Young's modulus E [kPa] and nu [1].

    mu_L = E / (2 (1 + nu)),  lambda = E nu / ((1 + nu)(1 - 2 nu)). Works on numbers
    and on CasADi expressions.
    """
    young = KPA * young_kpa
    return young / (2 * (1 + poisson)), young * poisson / ((1 + poisson) * (1 - 2 * poisson))


def young_poisson(mu_l: float, lam: float) -> tuple[float, float]:
    """(E [kPa], nu) of the Lame pair [N/mm^2]; the inverse of ``lame``."""
    poisson = lam / (2.0 * (lam + mu_l))
    return 2.0 * mu_l * (1.0 + poisson) / KPA, poisson


def _chain_rule(derivatives: list, inverse: np.ndarray) -> tuple[sp.csr_matrix, ...]:
    """P_j = sum_a diag(d xi_a / d x_j) D_a, all three on the union pattern of the D_a
    (every basis function's support at every point, zeros kept: ``symbolic.elements``
    groups the points by it)."""
    first = derivatives[0]
    if all(
        np.array_equal(first.indptr, d.indptr) and np.array_equal(first.indices, d.indices)
        for d in derivatives[1:]
    ):  # one pattern already (a polynomial basis with its zeros kept)
        rows = np.repeat(np.arange(first.shape[0]), np.diff(first.indptr))
        pattern = (first.indices, first.indptr)
        return tuple(
            sp.csr_matrix(
                (sum(inverse[rows, a, j] * derivatives[a].data for a in range(3)), *pattern),
                first.shape,
            )
            for j in range(3)
        )
    union = sp.csr_matrix(sum(abs(sp.csr_matrix(d)) for d in derivatives))
    union.sort_indices()
    n = union.shape[1]
    rows = np.repeat(np.arange(union.shape[0]), np.diff(union.indptr))
    keys = rows.astype(np.int64) * n + union.indices
    data = []
    for d in derivatives:
        d = sp.coo_matrix(d)
        values = np.zeros(keys.size)
        values[np.searchsorted(keys, d.row.astype(np.int64) * n + d.col)] = d.data
        data.append(values)
    return tuple(
        sp.csr_matrix(
            (sum(inverse[rows, a, j] * data[a] for a in range(3)), union.indices, union.indptr),
            union.shape,
        )
        for j in range(3)
    )


@dataclass(frozen=True)
class PhysicalGradient:
    """The physical-gradient operators of a volume spline at quadrature points.

    Attributes
    ----------
    operators : tuple of scipy.sparse.csr_matrix
        P_j, (n_q, n): P_j @ f is d f / d x_j at the points for a scalar spline f with
        control values f (eq. C2).
    volume : numpy.ndarray
        Quadrature weight times |det G| at each point [mm^3].
    points : numpy.ndarray
        The parameter points (n_q, 3).
    """

    operators: tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]
    volume: np.ndarray
    points: np.ndarray

    @classmethod
    def of(cls, volume: VolumeSpline, extra_points: int = 0) -> PhysicalGradient:
        """The operators at the spline's Gauss rule (plus ``extra_points`` per span)."""
        points, weights = quadrature(volume.basis, extra_points)
        derivatives = [
            volume.basis.collocation(points, d, keep_zeros=True) for d in FIRST_DERIVATIVES.values()
        ]
        jacobian = np.stack([d @ volume.control_points for d in derivatives], axis=-1)
        determinant = np.linalg.det(jacobian)  # jacobian[q, i, a] = d x_i / d xi_a
        if np.any(np.abs(determinant) <= 1e-12 * np.max(np.abs(determinant))):
            raise ValueError("the geometry map is singular at a quadrature point (folded volume)")
        inverse = np.linalg.inv(jacobian)  # inverse[q, a, j] = d xi_a / d x_j
        return cls(_chain_rule(derivatives, inverse), weights * np.abs(determinant), points)

    def stacked(self, component: int, direction: int) -> sp.csr_matrix:
        """d u_component / d x_direction as an (n_q, 3 n) operator on vec(Delta)."""
        operator = self.operators[direction]
        zero = sp.csr_matrix(operator.shape)
        return sp.hstack([operator if k == component else zero for k in range(3)]).tocsr()

    def divergence(self) -> sp.csr_matrix:
        """D = div u = tr eps, (n_q, 3 n) on vec(Delta)."""
        return sum(self.stacked(i, i) for i in range(3)).tocsr()

    def strain(self) -> list[sp.csr_matrix]:
        """The six Voigt rows of eps, off-diagonals times sqrt 2, so that
        sum_rows (row Delta)^2 = eps:eps."""
        rows = [self.stacked(i, i) for i in range(3)]
        for i, j in ((0, 1), (0, 2), (1, 2)):
            rows.append((self.stacked(i, j) + self.stacked(j, i)) / np.sqrt(2.0))
        return rows

    def elasticity(self, field=None) -> dict[str, sp.csr_matrix]:
        """K_mu and K_lambda of eq. (C3), both moduli scaled by ``field`` (default 1).

        Assembled from the nine scalar blocks G_ab = integral f P_a^T P_b dV (six
        products, G_ba = G_ab^T): with div u = sum_i P_i u_i and
        2 eps:eps = sum_ij (P_j u_i)^2 + sum_ij (P_j u_i)(P_i u_j),

            K_lambda[i, k] = G_ik,        K_mu[i, k] = delta_ik sum_j G_jj + G_ki

        (blocks of the stacked order). The same matrices as ``gram`` of ``strain`` and
        ``divergence`` (tested), in a quarter of the sparse products.
        """
        scale = 1.0 if field is None else np.asarray(field(self.points), dtype=float)
        weight = scale * self.volume
        if self._assembly is not None and np.all(weight != 0.0):
            return self._batched(weight)
        keep = np.flatnonzero(weight)  # a local field: only the points of its support
        operators = [op[keep] for op in self.operators] if keep.size < weight.size else None
        operators = operators or list(self.operators)
        weighted = [sp.csr_matrix(op.multiply(weight[keep][:, None])) for op in operators]
        blocks = {}
        for a in range(3):
            for b in range(a, 3):
                block = sp.csr_matrix(operators[a].T @ weighted[b])
                if a == b:  # symmetric up to rounding: made exactly so, block by block
                    block = sp.csr_matrix(0.5 * (block + block.T))
                blocks[a, b] = block
                blocks[b, a] = sp.csr_matrix(block.T)
        laplacian = blocks[0, 0] + blocks[1, 1] + blocks[2, 2]
        volumetric = sp.bmat([[blocks[i, k] for k in range(3)] for i in range(3)], format="csr")
        shear = sp.bmat(
            [[blocks[k, i] + (laplacian if i == k else 0) for k in range(3)] for i in range(3)],
            format="csr",
        )  # block (k, i) is block (i, k) transposed: both exactly symmetric
        return {"shear": shear, "volumetric": volumetric}

    def elasticity_product(self, u: np.ndarray, field=None) -> dict[str, np.ndarray]:
        """K_mu u and K_lambda u of ``elasticity(field)`` without forming either matrix.

        With U_i the component blocks of u (stacked order) and D_ai = P_a U_i at the
        points, weighted by w = f |det G| w_q:

            (K_lambda u)_i = P_i^T w sum_k D_kk,    (K_mu u)_i = sum_j P_j^T w (D_ji + D_ij).

        Parameters
        ----------
        u : numpy.ndarray
            Displacements on all points, stacked, (3 n,) or (3 n, m) [mm].
        """
        scale = 1.0 if field is None else np.asarray(field(self.points), dtype=float)
        weight = scale * self.volume
        u = np.asarray(u, dtype=float)
        n = self.operators[0].shape[1]
        blocks = u.reshape((3, n) + u.shape[1:])
        w = weight.reshape((-1,) + (1,) * (u.ndim - 1))
        d = [[self.operators[a] @ blocks[i] for i in range(3)] for a in range(3)]
        divergence = w * (d[0][0] + d[1][1] + d[2][2])
        volumetric = [self.operators[i].T @ divergence for i in range(3)]
        shear = [
            sum(self.operators[j].T @ (w * (d[j][i] + d[i][j])) for j in range(3)) for i in range(3)
        ]
        return {
            "shear": np.concatenate(shear).reshape(u.shape),
            "volumetric": np.concatenate(volumetric).reshape(u.shape),
        }

    @cached_property
    def _assembly(self) -> ElementAssembly | None:
        """The points grouped by element (``symbolic.elements``), or None."""
        return ElementAssembly.of(self.operators)

    def _batched(self, weight: np.ndarray) -> dict[str, sp.csr_matrix]:
        """``elasticity`` by element-batched assembly: the same blocks, no sparse product."""
        assembly = self._assembly
        blocks = assembly.scalar_blocks(weight)
        laplacian = blocks[0, 0] + blocks[1, 1] + blocks[2, 2]
        shear = {(i, k): blocks[k, i] + (laplacian if i == k else 0.0) for i, k in blocks}
        return {"shear": assembly.stacked(shear), "volumetric": assembly.stacked(blocks)}

    def gram(self, rows: list[sp.csr_matrix], factor: float = 1.0, field=None) -> sp.csr_matrix:
        """factor * integral f sum_rows row^T row dV, symmetrised (3 n, 3 n).

        ``field`` f is a callable of the parameter points (n_q, 3), default 1.
        """
        scale = 1.0 if field is None else np.asarray(field(self.points), dtype=float)
        weight = factor * scale * self.volume
        keep = np.flatnonzero(weight)  # a local field: only the points of its support
        if keep.size < weight.size:
            rows, weight = [row[keep] for row in rows], weight[keep]
        total = sum(row.T @ sp.diags(weight) @ row for row in rows)
        return sp.csr_matrix(0.5 * (total + total.T))


def elasticity_matrices(
    volume: VolumeSpline, extra_points: int = 0, field=None
) -> dict[str, sp.csr_matrix]:
    """K_mu and K_lambda of eq. (C3) on every control point, stacked (3 n, 3 n) [mm].

    K = mu_L K_mu + lambda K_lambda [N/mm] for the Lame pair [N/mm^2]. With ``field``
    f(u, v, w) (a callable of parameter points) both moduli are scaled by f: the
    terms of a spatially varying material.
    """
    return PhysicalGradient.of(volume, extra_points).elasticity(field)


def body_force_vector(
    volume: VolumeSpline, density: Callable[[np.ndarray], np.ndarray], extra_points: int = 2
) -> np.ndarray:
    """Generalised force F_i = integral N_i f(x) dV of a body force f [N/mm^3], (n, 3) [N].

    ``density`` maps physical points (n_q, 3) [mm] to forces per volume (n_q, 3).
    """
    gradient = PhysicalGradient.of(volume, extra_points)
    values = volume.collocation(gradient.points)
    physical = values @ volume.control_points
    f = np.asarray(density(physical), dtype=float)
    if f.shape != physical.shape:
        raise ValueError(f"the body force must give an (n, 3) array, got {f.shape}")
    return values.T @ (gradient.volume[:, None] * f)


def box_volume(
    lengths: tuple[float, float, float],
    shape: tuple[int, int, int],
    degrees: tuple[int, int, int],
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> VolumeSpline:
    """A box [origin, origin + lengths] [mm] as a B-spline volume with uniform knots.

    The control points sit at the Greville abscissae, so the geometry map is affine
    (exactly x = origin + lengths * (u, v, w)).
    """
    basis = VolumeBasis(tuple(shape), tuple(degrees))
    greville = [BSplineBasis(p, n).greville() for p, n in zip(degrees, shape)]
    grid = basis.grid_points(*greville)
    return VolumeSpline(basis, np.asarray(origin) + grid * np.asarray(lengths))
