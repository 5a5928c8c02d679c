"""VolumeSpline: control grid, evaluation and least-squares fit (docs/model.md, eq. 2-9).

The tissue layer is V(u, v, w) = J(u, v, w) B with w = 0 the inner surface
(above fascia and muscle) and w = 1 the outer surface (the skin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from symbolic.basis import BSplineBasis, VolumeBasis

PARAMETERIZATIONS = ("chord", "uniform")


@dataclass(frozen=True)
class FitReport:
    """Quality of a least-squares fit of control points to segmented points.

    Attributes
    ----------
    rms : float
        Root mean square of the point distances |V(u_i, v_j, w_k) - P_ijk| [mm].
    max : float
        Largest such distance [mm].
    n_points : int
        Number of segmented points used.
    """

    rms: float
    max: float
    n_points: int


def grid_parameters(points: np.ndarray, axis: int, method: str = "chord") -> np.ndarray:
    """Parameter values in [0, 1] along one axis of a structured point grid.

    Parameters
    ----------
    points : numpy.ndarray
        Grid of points, shape (U, V, K, 3) [mm].
    axis : int
        Grid axis 0, 1 or 2.
    method : {"chord", "uniform"}
        Chord length averaged over every grid line along ``axis``, or uniform.

    Returns
    -------
    numpy.ndarray
        Increasing parameters with the first 0 and the last 1.
    """
    if method not in PARAMETERIZATIONS:
        raise ValueError(f"parameterization must be one of {PARAMETERIZATIONS}, got {method!r}")
    count = points.shape[axis]
    if count == 1:
        return np.zeros(1)
    if method == "uniform":
        return np.linspace(0.0, 1.0, count)
    steps = np.linalg.norm(np.diff(points, axis=axis), axis=-1)
    steps = np.moveaxis(steps, axis, 0).reshape(count - 1, -1)
    lengths = np.cumsum(steps, axis=0) / steps.sum(axis=0)
    mean = np.concatenate([[0.0], lengths.mean(axis=1)])
    return mean / mean[-1]


def _checked_pseudo_solve(matrix: np.ndarray, data: np.ndarray, name: str, unit: int) -> np.ndarray:
    """Least-squares solve along one axis, with a rank check naming the direction."""
    rank = np.linalg.matrix_rank(matrix)
    if rank < matrix.shape[1]:
        raise ValueError(
            f"collocation matrix is rank deficient in {name}: {matrix.shape[0]} data values "
            f"give rank {rank} < {matrix.shape[1]} control points; use fewer control points "
            f"in {name} or more segmented points"
        )
    moved = np.moveaxis(data, unit, 0)
    solution = np.linalg.lstsq(matrix, moved.reshape(moved.shape[0], -1), rcond=None)[0]
    return np.moveaxis(solution.reshape((matrix.shape[1],) + moved.shape[1:]), 0, unit)


@dataclass(frozen=True)
class VolumeSpline:
    """A trivariate (optionally rational) B-spline volume, eq. (2).

    Parameters
    ----------
    basis : VolumeBasis
        Tensor-product basis of shape (M, N, L) and degrees (p, q, r).
    control_points : numpy.ndarray
        B, shape (M N L, 3) [mm], in the basis's C-order numbering.
    """

    basis: VolumeBasis
    control_points: np.ndarray

    def __post_init__(self) -> None:
        points = np.asarray(self.control_points, dtype=float)
        if points.shape != (self.basis.size, 3):
            raise ValueError(
                f"control_points must have shape ({self.basis.size}, 3), got {points.shape}"
            )
        if not np.all(np.isfinite(points)):
            raise ValueError("control_points contain NaN or inf")
        object.__setattr__(self, "control_points", points)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Control grid (M, N, L)."""
        return self.basis.shape

    @property
    def grid(self) -> np.ndarray:
        """Control points as an (M, N, L, 3) array."""
        return self.control_points.reshape(self.shape + (3,))

    def collocation(self, params: np.ndarray, derivative=(0, 0, 0)) -> sp.csr_matrix:
        """Sparse J (or a derivative) at parameter points (n, 3); see VolumeBasis."""
        return self.basis.collocation(params, derivative)

    def evaluate(self, params: np.ndarray, derivative=(0, 0, 0)) -> np.ndarray:
        """V (or a derivative) at parameter points, shape (n, 3) [mm]."""
        return self.collocation(params, derivative) @ self.control_points

    def outer_params(self, uv: np.ndarray) -> np.ndarray:
        """(u, v) on the outer surface -> (u, v, 1), shape (n, 3)."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        return np.column_stack([uv, np.ones(len(uv))])

    def outer_normal(self, uv: np.ndarray) -> np.ndarray:
        """Unit outward normal of the skin surface w = 1 at (u, v), shape (n, 3)."""
        params = self.outer_params(uv)
        du = self.evaluate(params, (1, 0, 0))
        dv = self.evaluate(params, (0, 1, 0))
        dw = self.evaluate(params, (0, 0, 1))
        normal = np.cross(du, dv)
        normal *= np.sign(np.sum(normal * dw, axis=1))[:, None]
        return normal / np.linalg.norm(normal, axis=1)[:, None]

    def project_to_outer(
        self, points: np.ndarray, iterations: int = 20
    ) -> tuple[np.ndarray, np.ndarray]:
        """Closest points on the outer surface: (u, v) and the distance [mm].

        A coarse search over a sampled surface gives the start of a bounded
        Gauss-Newton iteration on |V(u, v, 1) - x|^2.
        """
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
            raise ValueError("points to project must be finite with shape (n, 3)")
        samples = np.linspace(0.0, 1.0, 41)
        su, sv = np.meshgrid(samples, samples, indexing="ij")
        sample_uv = np.column_stack([su.ravel(), sv.ravel()])
        surface = self.evaluate(self.outer_params(sample_uv))
        nearest = np.argmin(((points[:, None, :] - surface[None]) ** 2).sum(-1), axis=1)
        uv = sample_uv[nearest].copy()
        for _ in range(iterations):
            params = self.outer_params(uv)
            gap = self.evaluate(params) - points
            jac = np.stack([self.evaluate(params, (1, 0, 0)), self.evaluate(params, (0, 1, 0))], -1)
            step = np.linalg.solve(
                np.einsum("nki,nkj->nij", jac, jac), np.einsum("nki,nk->ni", jac, gap)[..., None]
            )[..., 0]
            uv = np.clip(uv - step, 0.0, 1.0)
            if np.max(np.abs(step)) < 1e-13:
                break
        distance = np.linalg.norm(self.evaluate(self.outer_params(uv)) - points, axis=1)
        return uv, distance

    def with_layers(self, n_layers: int, degree: int = 1) -> VolumeSpline:
        """The same volume with ``n_layers`` control layers through the thickness.

        Exact for a volume linear in w (L = 2, r = 1): the new layers sit at
        the Greville abscissae, where B-splines reproduce linear functions.
        """
        if self.shape[2] != 2 or self.basis.degrees[2] != 1:
            raise ValueError("with_layers needs a volume that is linear in w (L = 2, r = 1)")
        if self.basis.weights is not None:
            raise ValueError("with_layers does not support rational weights")
        m, n, _ = self.shape
        basis = VolumeBasis((m, n, n_layers), self.basis.degrees[:2] + (degree,))
        g = BSplineBasis(degree, n_layers).greville()
        inner, outer = self.grid[:, :, 0], self.grid[:, :, 1]
        layers = inner[:, :, None] + g[None, None, :, None] * (outer - inner)[:, :, None]
        return VolumeSpline(basis, layers.reshape(-1, 3))

    def refined(
        self, shape: tuple[int, int, int], degrees: tuple[int, int, int] | None = None
    ) -> tuple[VolumeSpline, float]:
        """The same geometry on a finer control grid (h- and p-), and its deviation [mm].

        The new control points interpolate this volume at the Greville points of the
        finer basis (clamped uniform knots; ``degrees`` default to this volume's,
        each at most the new points minus one). Where the new space contains the
        old one (same degree and n' - p = m (n - p) spans along each direction, or a
        direction along which the geometry is linear, as w is) the geometry is
        reproduced to rounding; otherwise the result is a close interpolant and the
        returned deviation, the largest distance between the two maps on a dense
        sample, says how close.
        """
        if self.basis.weights is not None:
            raise ValueError("refinement does not support rational weights")
        shape = tuple(int(n) for n in shape)
        if any(new < old for new, old in zip(shape, self.shape)):
            raise ValueError(f"a refined grid {shape} must not be coarser than {self.shape}")
        wanted = self.basis.degrees if degrees is None else degrees
        basis = VolumeBasis(shape, tuple(min(int(d), n - 1) for d, n in zip(wanted, shape)))
        abscissae = [b.greville() for b in basis.bases]
        control = self.evaluate(basis.grid_points(*abscissae)).reshape(shape + (3,))
        for axis, (t, name) in enumerate(zip(abscissae, "uvw")):
            matrix = basis.bases[axis].evaluate_dense(t)
            control = _checked_pseudo_solve(matrix, control, name, axis)
        refined = VolumeSpline(basis, control.reshape(-1, 3))
        sample = np.linspace(0.0, 1.0, 4 * max(shape) + 1)
        params = basis.grid_points(sample, sample, np.linspace(0.0, 1.0, 5))
        deviation = np.linalg.norm(refined.evaluate(params) - self.evaluate(params), axis=1)
        return refined, float(deviation.max())

    @classmethod
    def fit(
        cls,
        points: np.ndarray,
        shape: tuple[int, int, int] = (9, 9, 2),
        degrees: tuple[int, int, int] = (3, 3, 1),
        parameterization: str = "chord",
        weights: np.ndarray | None = None,
    ) -> tuple[VolumeSpline, FitReport]:
        """Least-squares control points for a structured grid of segmented points (eq. 6-9).

        Parameters
        ----------
        points : numpy.ndarray
            Segmented points, shape (U, V, K, 3) [mm]; layer k = 0 is the inner
            surface (w = 0) and k = K-1 the outer surface (w = 1). The usual
            input has K = 2.
        shape, degrees : tuple of int
            Control grid (M, N, L) and degrees (p, q, r).
        parameterization : {"chord", "uniform"}
            How data parameters (u_i, v_j, w_k) are chosen.
        weights : numpy.ndarray, optional
            Rational weights (M, N, L); ``None`` for a plain B-spline.

        Returns
        -------
        VolumeSpline, FitReport
            The fitted volume and the RMS/max error of the fit [mm].

        Raises
        ------
        ValueError
            For a wrong shape, NaN or inf in the points, U V K < M N L, or a
            rank-deficient collocation matrix.
        """
        points = np.asarray(points, dtype=float)
        if points.ndim != 4 or points.shape[-1] != 3:
            raise ValueError(f"points must have shape (U, V, K, 3), got {points.shape}")
        bad = int(np.sum(~np.isfinite(points)))
        if bad:
            raise ValueError(
                f"segmented points contain {bad} NaN or inf values; fill or remove them first"
            )
        basis = VolumeBasis(tuple(shape), tuple(degrees), weights)
        if points[..., 0].size < basis.size:
            raise ValueError(
                f"{'*'.join(map(str, points.shape[:3]))} = {points[..., 0].size} segmented points "
                f"cannot determine {'*'.join(map(str, basis.shape))} = {basis.size} control "
                "points; use a coarser control grid or more segmented points"
            )
        u, v, w = (grid_parameters(points, axis, parameterization) for axis in range(3))
        if points.shape[2] == 1:
            raise ValueError("need at least two layers (inner and outer surface) to fit a volume")
        if weights is None:
            control = points
            for axis, (t, name) in enumerate(zip((u, v, w), "uvw")):
                matrix = basis.bases[axis].evaluate_dense(t)
                control = _checked_pseudo_solve(matrix, control, name, axis)
            volume = cls(basis, control.reshape(-1, 3))
        else:
            volume = cls(basis, cls._rational_solve(basis, points, u, v, w))
        fitted = volume.evaluate(basis.grid_points(u, v, w))
        distances = np.linalg.norm(fitted - points.reshape(-1, 3), axis=1)
        report = FitReport(
            float(np.sqrt(np.mean(distances**2))), float(distances.max()), len(distances)
        )
        return volume, report

    @staticmethod
    def _rational_solve(basis, points, u, v, w) -> np.ndarray:
        """Dense least squares for a rational basis (no Kronecker structure)."""
        matrix = basis.collocation(basis.grid_points(u, v, w)).toarray()
        rank = np.linalg.matrix_rank(matrix)
        if rank < basis.size:
            raise ValueError(
                f"collocation matrix is rank deficient: rank {rank} < {basis.size} control points"
            )
        return np.linalg.lstsq(matrix, points.reshape(-1, 3), rcond=None)[0]
