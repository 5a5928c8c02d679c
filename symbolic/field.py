"""A stiffness field over the tissue: log E as a B-spline in the volume's parameters.

Stiffness imaging (docs/imaging.md) replaces the constant Young's modulus of the
linear-elastic energy (eq. C3) by a field

    E(u, v, w) = E_ref exp(s(u, v, w)),     s = sum_k c_k phi_k(u, v, w),          (I1)

with phi_k a tensor-product B-spline basis over the volume's parameter cube and c its
N coefficients. The logarithm keeps E positive for every c and makes a contrast of 2
and of 1/2 equally far from 0. The field lives in the model's own (u, v, w), so a
coefficient sits over the same tissue whatever the deformation.

Three layouts (``over``):

- ``"surface"``: s(u, v), the same through the thickness (N = n_u n_v);
- ``"layers"``: one s(u, v) per layer, piecewise constant across the thickness's
  ``n_w`` equal spans (N = n_u n_v n_w);
- ``"volume"``: s(u, v, w), degree 1 through the thickness (N = n_u n_v n_w).

With degree 1 (the default) the coefficients are the field's values at its nodes (the
Greville points), so a pointwise standard deviation of c is one of the map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from symbolic.basis import BSplineBasis, gauss_rule

LAYOUTS = ("surface", "layers", "volume")


@dataclass(frozen=True)
class StiffnessField:
    """The basis phi_k of eq. (I1).

    Parameters
    ----------
    shape : tuple of int
        (n_u, n_v) for ``over="surface"``, (n_u, n_v, n_w) otherwise.
    over : str
        One of ``LAYOUTS``.
    degree : int
        Degree along u and v (1: piecewise bilinear, coefficients are nodal values).
    """

    shape: tuple[int, ...]
    over: str = "surface"
    degree: int = 1

    def __post_init__(self) -> None:
        if self.over not in LAYOUTS:
            raise ValueError(f"a field lies over one of {LAYOUTS}, not {self.over!r}")
        wanted = 2 if self.over == "surface" else 3
        if len(self.shape) != wanted or min(self.shape) < 1:
            raise ValueError(f"a {self.over} field needs {wanted} positive sizes, got {self.shape}")
        if self.degree < 1 or min(self.shape[:2]) <= self.degree:
            raise ValueError(f"need more than degree {self.degree} coefficients along u and v")
        if self.over == "volume" and self.shape[2] < 2:
            raise ValueError("a volume field needs at least 2 coefficients through the thickness")

    @property
    def size(self) -> int:
        """N, the number of coefficients."""
        return int(np.prod(self.shape))

    def bases(self) -> tuple[BSplineBasis, BSplineBasis, BSplineBasis]:
        """The univariate bases along u, v and w."""
        u = BSplineBasis(self.degree, self.shape[0])
        v = BSplineBasis(self.degree, self.shape[1])
        if self.over == "surface":
            return u, v, BSplineBasis(0, 1)
        if self.over == "layers":
            return u, v, BSplineBasis(0, self.shape[2])
        return u, v, BSplineBasis(1, self.shape[2])

    def collocation(self, points: np.ndarray, derivative=(0, 0, 0)) -> sp.csr_matrix:
        """phi_k (or a partial derivative) at parameter points (n, 3): (n, N), sparse.

        The coefficient index is k = (i n_v + j) n_w + l for (u, v, w) indices (i, j, l).
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        factors = []
        for axis, (basis, order) in enumerate(zip(self.bases(), derivative)):
            if order > basis.degree:
                return sp.csr_matrix((len(points), self.size))
            factors.append(basis.local(points[:, axis], order))
        (vu, iu), (vv, iv), (vw, iw) = factors
        n_v, n_w = self.shape[1], self.bases()[2].n_control
        values = vu[:, :, None, None] * vv[:, None, :, None] * vw[:, None, None, :]
        index = (iu[:, :, None, None] * n_v + iv[:, None, :, None]) * n_w + iw[:, None, None, :]
        rows = np.broadcast_to(np.arange(len(points))[:, None, None, None], values.shape)
        matrix = sp.coo_matrix(
            (values.ravel(), (rows.ravel(), index.ravel())), shape=(len(points), self.size)
        )
        return matrix.tocsr()

    def nodes(self) -> np.ndarray:
        """Parameter points of the coefficients (Greville points; layer centres), (N, 3)."""
        u, v, w = (basis.greville() for basis in self.bases())
        grid = np.stack(np.meshgrid(u, v, w, indexing="ij"), axis=-1)
        return grid.reshape(-1, 3)

    def rule(self) -> tuple[np.ndarray, np.ndarray]:
        """The field's Gauss rule over the parameter cube: points (n_q, 3), weights (sum 1)."""
        rules = [gauss_rule(basis, basis.degree + 1) for basis in self.bases()]
        grids = np.meshgrid(*[points for points, _ in rules], indexing="ij")
        points = np.stack(grids, axis=-1).reshape(-1, 3)
        return points, np.einsum("i,j,k->ijk", *[w for _, w in rules]).ravel()

    def gradient_rule(
        self, lengths: tuple[float, float, float]
    ) -> tuple[list[sp.csr_matrix], np.ndarray]:
        """The field's physical gradient at its own Gauss points, for regularisation.

        Parameters
        ----------
        lengths : tuple of float
            The tissue's extent along u, v and w [mm]; d/dx ~ (d/du) / L_u.

        Returns
        -------
        operators : list of scipy.sparse.csr_matrix
            D_d with (D_d c)_q = d s / d x_d at point q [1/mm], one per direction the
            field varies in.
        weights : numpy.ndarray
            Quadrature weight times the cell volume at each point [mm^3].
        """
        points, weights = self.rule()
        weights = weights * np.prod(lengths)
        directions = (0, 1, 2) if self.over == "volume" else (0, 1)
        operators = []
        for axis in directions:
            order = tuple(int(a == axis) for a in range(3))
            operators.append(self.collocation(points, order) / lengths[axis])
        return operators, weights


def tissue_lengths(model) -> tuple[float, float, float]:
    """Lengths of the volume's mid-lines along u, v and w [mm] (a field's physical scale)."""
    t = np.linspace(0.0, 1.0, 41)
    lengths = []
    for axis in range(3):
        points = np.full((t.size, 3), 0.5)
        points[:, axis] = t
        xyz = model.volume.collocation(points) @ model.rest
        lengths.append(float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()))
    return tuple(lengths)
