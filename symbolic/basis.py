"""B-spline bases as numeric sparse matrices (docs/model.md, eq. 2-3).

A basis evaluates to a matrix: row ``i`` holds every basis function (or one of
its derivatives) at the parameter value ``t[i]``. Geometry is then
``matrix @ control_points``; only the control points are ever symbolic.

The trivariate basis is the tensor product of three univariate ones. Control
points are numbered in C order of the ``(M, N, L)`` grid,
``index = a * N * L + b * L + c``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp


def clamped_uniform_knots(degree: int, n_control: int) -> np.ndarray:
    """Clamped, uniform knot vector on [0, 1].

    Parameters
    ----------
    degree : int
        Polynomial degree p >= 0.
    n_control : int
        Number of control points (basis functions), at least ``degree + 1``.

    Returns
    -------
    numpy.ndarray
        ``n_control + degree + 1`` knots: ``degree + 1`` zeros, uniform
        interior knots, ``degree + 1`` ones.
    """
    if int(degree) != degree or degree < 0:
        raise ValueError(f"degree must be a non-negative integer, got {degree!r}")
    if int(n_control) != n_control or n_control < degree + 1:
        raise ValueError(
            f"n_control must be an integer >= degree + 1 = {degree + 1}, got {n_control!r}"
        )
    n_interior = n_control - degree - 1
    interior = np.linspace(0.0, 1.0, n_interior + 2)[1:-1]
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def _safe_inverse(values: np.ndarray) -> np.ndarray:
    """1 / values, with 0 where a knot span has zero length (the 0/0 = 0 rule)."""
    out = np.zeros_like(values, dtype=float)
    nonzero = values > 0
    out[nonzero] = 1.0 / values[nonzero]
    return out


@dataclass(frozen=True)
class BSplineBasis:
    """Univariate clamped B-spline basis N_i^p(t) on [0, 1].

    Parameters
    ----------
    degree : int
        Polynomial degree p.
    n_control : int
        Number of basis functions.
    """

    degree: int
    n_control: int
    knots: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "knots", clamped_uniform_knots(self.degree, self.n_control))

    @property
    def breakpoints(self) -> np.ndarray:
        """Distinct knot values, the ends of the non-empty knot spans."""
        return np.unique(self.knots)

    def greville(self) -> np.ndarray:
        """Greville abscissae: control points placed there reproduce linear functions."""
        p = self.degree
        if p == 0:
            return 0.5 * (self.knots[:-1] + self.knots[1:])
        return np.array([self.knots[i + 1 : i + p + 1].mean() for i in range(self.n_control)])

    def span_index(self, t: np.ndarray) -> np.ndarray:
        """Index s of the knot span [knots[s], knots[s+1]) holding each t (t = 1 -> last span)."""
        s = np.searchsorted(self.knots, t, side="right") - 1
        return np.clip(s, self.degree, self.n_control - 1)

    def evaluate_dense(self, t: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Dense matrix of d^k N_i / dt^k at the points t, shape (len(t), n_control)."""
        t = np.asarray(t, dtype=float).ravel()
        if np.any(~np.isfinite(t)) or np.any(t < -1e-12) or np.any(t > 1 + 1e-12):
            raise ValueError("parameter values must be finite and lie in [0, 1]")
        if int(derivative) != derivative or derivative < 0:
            raise ValueError(f"derivative must be a non-negative integer, got {derivative!r}")
        t = np.clip(t, 0.0, 1.0)
        knots, p = self.knots, self.degree
        if derivative > p:
            return np.zeros((t.size, self.n_control))
        # Degree-0 functions: the indicator of the span holding t.
        levels = [np.zeros((t.size, knots.size - 1))]
        levels[0][np.arange(t.size), self.span_index(t)] = 1.0
        for k in range(1, p + 1):
            prev = levels[-1]
            n_k = knots.size - 1 - k
            i = np.arange(n_k)
            left = _safe_inverse(knots[i + k] - knots[i])
            right = _safe_inverse(knots[i + k + 1] - knots[i + 1])
            levels.append(
                (t[:, None] - knots[i]) * left * prev[:, :-1]
                + (knots[i + k + 1] - t[:, None]) * right * prev[:, 1:]
            )
        return self._differentiate(levels, p, derivative)

    def _differentiate(self, levels: list[np.ndarray], k: int, order: int) -> np.ndarray:
        """d^order/dt^order of the degree-k functions, by the standard recursion."""
        if order == 0:
            return levels[k]
        lower = self._differentiate(levels, k - 1, order - 1)
        i = np.arange(lower.shape[1] - 1)
        left = _safe_inverse(self.knots[i + k] - self.knots[i])
        right = _safe_inverse(self.knots[i + k + 1] - self.knots[i + 1])
        return k * (lower[:, :-1] * left - lower[:, 1:] * right)

    def evaluate(self, t: np.ndarray, derivative: int = 0) -> sp.csr_matrix:
        """Sparse collocation matrix of the basis (or a derivative) at the points t."""
        return sp.csr_matrix(self.evaluate_dense(t, derivative))

    def local(self, t: np.ndarray, derivative: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Values and indices of the p+1 functions that can be non-zero at each t.

        Returns
        -------
        values, indices : numpy.ndarray
            Both of shape (len(t), p + 1).
        """
        t = np.asarray(t, dtype=float).ravel()
        # tensor grids repeat each 1-D value many times: evaluate the distinct ones
        distinct, inverse = np.unique(t, return_inverse=True)
        dense = self.evaluate_dense(distinct, derivative)
        first = self.span_index(np.clip(distinct, 0.0, 1.0)) - self.degree
        indices = first[:, None] + np.arange(self.degree + 1)
        values = np.take_along_axis(dense, indices, axis=1)
        return values[inverse], indices[inverse]


def gauss_rule(
    basis: BSplineBasis, points_per_span: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre points and weights over every non-empty knot span of a basis.

    Parameters
    ----------
    basis : BSplineBasis
        The basis whose knot spans are integrated.
    points_per_span : int, optional
        Number of Gauss points per span; default ``degree + 1``, which is
        exact for products of two basis functions (degree 2p).

    Returns
    -------
    points, weights : numpy.ndarray
        Quadrature nodes in [0, 1] and weights summing to 1.
    """
    n = basis.degree + 1 if points_per_span is None else int(points_per_span)
    if n < 1:
        raise ValueError(f"points_per_span must be >= 1, got {points_per_span!r}")
    x, w = np.polynomial.legendre.leggauss(n)
    ends = basis.breakpoints
    a, b = ends[:-1, None], ends[1:, None]
    points = 0.5 * (b - a) * x[None, :] + 0.5 * (a + b)
    weights = 0.5 * (b - a) * w[None, :]
    return points.ravel(), weights.ravel()


DerivativeOrder = tuple[int, int, int]


@dataclass(frozen=True)
class VolumeBasis:
    """Trivariate tensor-product basis J(u, v, w) of eq. (3), optionally rational.

    Parameters
    ----------
    shape : tuple of int
        Control grid (M, N, L).
    degrees : tuple of int
        Degrees (p, q, r).
    weights : numpy.ndarray, optional
        Rational (D-NURBS) weights, shape (M, N, L), all > 0. ``None`` gives a
        plain B-spline.
    """

    shape: tuple[int, int, int]
    degrees: tuple[int, int, int]
    weights: np.ndarray | None = None
    bases: tuple[BSplineBasis, BSplineBasis, BSplineBasis] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.shape) != 3 or len(self.degrees) != 3:
            raise ValueError("shape and degrees must each have three entries (u, v, w)")
        bases = tuple(BSplineBasis(int(p), int(n)) for p, n in zip(self.degrees, self.shape))
        object.__setattr__(self, "bases", bases)
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))
        object.__setattr__(self, "degrees", tuple(int(p) for p in self.degrees))
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != self.shape:
                raise ValueError(f"weights must have shape {self.shape}, got {w.shape}")
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise ValueError("rational weights must be finite and strictly positive")
            object.__setattr__(self, "weights", w)

    @property
    def size(self) -> int:
        """Number of control points n = M N L."""
        return int(np.prod(self.shape))

    def _polynomial(
        self, points: np.ndarray, derivative: DerivativeOrder, keep_zeros: bool = False
    ) -> sp.csr_matrix:
        """Row-wise Kronecker product of the three univariate collocations (with
        ``keep_zeros`` every row holds its whole support, in one order for every
        derivative)."""
        (vu, iu), (vv, iv), (vw, iw) = (
            basis.local(points[:, k], derivative[k]) for k, basis in enumerate(self.bases)
        )
        _, n_v, n_w = self.shape
        values = vu[:, :, None, None] * vv[:, None, :, None] * vw[:, None, None, :]
        columns = (iu[:, :, None, None] * n_v + iv[:, None, :, None]) * n_w + iw[:, None, None, :]
        n_points, per_row = points.shape[0], values[0].size
        # every row holds its span's (p_u + 1)(p_v + 1)(p_w + 1) functions, their columns
        # increasing (u-major, each index range ascending): CSR as it stands, without the
        # sort and duplicate sum of a COO conversion (8 s of a 70 x 58 x 8 model's build)
        indptr = np.arange(0, n_points * per_row + 1, per_row)
        matrix = sp.csr_matrix(
            (values.reshape(-1), columns.reshape(-1), indptr), shape=(n_points, self.size)
        )
        if not keep_zeros:
            matrix.eliminate_zeros()
        return matrix

    def collocation(
        self, points: np.ndarray, derivative: DerivativeOrder = (0, 0, 0), keep_zeros=False
    ) -> sp.csr_matrix:
        """Sparse matrix of J (or a derivative of it) at parameter points.

        Parameters
        ----------
        points : numpy.ndarray
            Parameter values (u, v, w), shape (n_points, 3), in [0, 1].
        derivative : tuple of int
            Orders of differentiation in u, v and w; total order <= 2 for a
            rational basis.

        Returns
        -------
        scipy.sparse.csr_matrix
            Shape (n_points, M N L); row i is J_d(u_i, v_i, w_i), so the
            geometry derivative is ``matrix @ B``. With ``keep_zeros`` (polynomial
            bases) a row keeps the exact zeros of its support.
        """
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3), got {points.shape}")
        derivative = tuple(int(d) for d in derivative)
        if len(derivative) != 3 or min(derivative) < 0:
            raise ValueError(f"derivative must be three non-negative orders, got {derivative}")
        if self.weights is None:
            return self._polynomial(points, derivative, keep_zeros)
        return self._rational(points, derivative)

    def _rational(self, points: np.ndarray, derivative: DerivativeOrder) -> sp.csr_matrix:
        """Quotient rule for R = N w / W, W = N . w, up to second derivatives."""
        if sum(derivative) > 2:
            raise ValueError("rational bases support derivatives up to total order 2")
        w = self.weights.reshape(-1)
        scale = sp.diags(w)

        def unit(axis: int) -> tuple[int, int, int]:
            return tuple(1 if k == axis else 0 for k in range(3))

        def part(order: tuple[int, int, int]) -> tuple[sp.csr_matrix, np.ndarray]:
            n = self._polynomial(points, order)
            return n @ scale, n @ w

        n0, weight = part((0, 0, 0))
        inv = sp.diags(1.0 / weight)
        rational0 = inv @ n0
        axes = [k for k in range(3) for _ in range(derivative[k])]
        if not axes:
            return rational0.tocsr()

        def first(axis: int) -> tuple[sp.csr_matrix, np.ndarray]:
            n_i, w_i = part(unit(axis))
            return inv @ (n_i - sp.diags(w_i) @ rational0), w_i

        if len(axes) == 1:
            return first(axes[0])[0].tocsr()
        i, j = axes
        r_i, w_i = first(i)
        r_j, w_j = first(j)
        n_ij, w_ij = part(tuple(derivative))
        numerator = n_ij - sp.diags(w_j) @ r_i - sp.diags(w_i) @ r_j - sp.diags(w_ij) @ rational0
        return (inv @ numerator).tocsr()

    def grid_points(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """All (u, v, w) combinations of three 1-D parameter arrays, C order, shape (n, 3)."""
        uu, vv, ww = np.meshgrid(u, v, w, indexing="ij")
        return np.column_stack([uu.ravel(), vv.ravel(), ww.ravel()])


FIRST_DERIVATIVES: dict[str, DerivativeOrder] = {"u": (1, 0, 0), "v": (0, 1, 0), "w": (0, 0, 1)}
SECOND_DERIVATIVES: dict[str, DerivativeOrder] = {
    "uu": (2, 0, 0),
    "vv": (0, 2, 0),
    "ww": (0, 0, 2),
    "uv": (1, 1, 0),
    "uw": (1, 0, 1),
    "vw": (0, 1, 1),
}
