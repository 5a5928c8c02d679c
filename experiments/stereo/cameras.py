"""A calibrated pinhole camera with lens distortion, in OpenCV's conventions.

A world point ``X`` (world units: mm for the MultiDIC object, chessboard
squares for the OpenCV samples) is mapped to camera coordinates by
``x_cam = R @ X + t``; the camera looks along its +z axis, x to the right and
y down in the image. Pixels are ``(u, v)`` with ``u`` along image columns and
``v`` along rows; OpenCV puts the centre of the top-left pixel at (0, 0).
Distortion follows ``cv2.projectPoints`` (k1, k2, p1, p2[, k3[, k4, k5, k6]]).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

_VALID_DIST_SIZES = (0, 4, 5, 8, 12, 14)


def _as_points3d(points3d: np.ndarray) -> np.ndarray:
    """Validate and return an (n, 3) float64 array of 3D points."""
    pts = np.asarray(points3d, dtype=float)
    if pts.ndim == 1 and pts.size == 3:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points3d must have shape (n, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points3d must be finite")
    return pts


@dataclass(frozen=True)
class Camera:
    """Pinhole camera with OpenCV distortion: ``x_cam = R @ X + t``.

    Parameters
    ----------
    K : numpy.ndarray
        3x3 intrinsic matrix [px]: focal lengths ``fx, fy`` and principal
        point ``cx, cy``; ``K[2] == [0, 0, 1]``.
    dist : numpy.ndarray
        Distortion coefficients (k1, k2, p1, p2[, k3, ...]), dimensionless;
        0, 4, 5, 8, 12 or 14 values. Empty means no distortion.
    R : numpy.ndarray
        3x3 rotation, world -> camera (proper: ``det(R) = +1``).
    t : numpy.ndarray
        Translation [world units], world -> camera.
    image_size : tuple of int, optional
        ``(width, height)`` [px] of the images this camera was calibrated
        on; used to reject observations that cannot come from it.
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    image_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 matrix, got shape {K.shape}")
        if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
            raise ValueError("K must be upper triangular with last row [0, 0, 1]")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        dist = np.asarray(self.dist, dtype=float).ravel()
        if dist.size not in _VALID_DIST_SIZES or not np.all(np.isfinite(dist)):
            raise ValueError(
                f"dist must hold {_VALID_DIST_SIZES} finite coefficients, got {dist.size}"
            )
        R = np.asarray(self.R, dtype=float)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError(f"R must be a finite 3x3 matrix, got shape {R.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("R must be a proper rotation (R R^T = I, det R = +1)")
        t = np.asarray(self.t, dtype=float).ravel()
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t must be a finite 3-vector, got shape {t.shape}")
        size = self.image_size
        if size is not None:
            if len(size) != 2 or min(size) <= 0:
                raise ValueError(f"image_size must be (width, height) > 0, got {size!r}")
            size = (int(size[0]), int(size[1]))
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "image_size", size)

    @classmethod
    def from_rvec(cls, K, dist, rvec, tvec, image_size=None) -> Camera:
        """Build a camera from an OpenCV Rodrigues vector ``rvec`` and ``tvec``."""
        R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))
        return cls(
            K=K, dist=dist, R=R, t=np.asarray(tvec, dtype=float).ravel(), image_size=image_size
        )

    @property
    def rvec(self) -> np.ndarray:
        """Rodrigues rotation vector of ``R`` [rad], shape (3,)."""
        return cv2.Rodrigues(self.R)[0].ravel()

    def projection_matrix(self) -> np.ndarray:
        """Undistorted 3x4 projection matrix ``K [R | t]`` (world units -> px)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``-R^T t`` [world units]."""
        return -self.R.T @ self.t

    def to_camera(self, points3d: np.ndarray) -> np.ndarray:
        """World points (n, 3) to camera coordinates (n, 3); depth is column 2."""
        pts = _as_points3d(points3d)
        return pts @ self.R.T + self.t

    def depth(self, points3d: np.ndarray) -> np.ndarray:
        """Depth ``z_cam`` of world points along the optical axis [world units]."""
        return self.to_camera(points3d)[:, 2]

    def project(self, points3d: np.ndarray) -> np.ndarray:
        """Project world points with distortion (``cv2.projectPoints``).

        Parameters
        ----------
        points3d : numpy.ndarray
            World points, shape (n, 3) [world units].

        Returns
        -------
        numpy.ndarray
            Pixel coordinates ``(u, v)``, shape (n, 2) [px].
        """
        pts = _as_points3d(points3d)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        uv, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), self.rvec, self.t, self.K, self.dist)
        return uv.reshape(-1, 2)

    def project_with_jacobian(self, points3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projections (n, 2) [px] and their derivatives d(u, v)/dX, shape (n, 2, 3) [px/unit].

        The derivative with respect to the world point equals the one with
        respect to ``t`` rotated back to the world frame: ``d uv/dX = d uv/dt R``.
        """
        pts = _as_points3d(points3d)
        if pts.shape[0] == 0:  # OpenCV returns None for no points
            return np.zeros((0, 2)), np.zeros((0, 2, 3))
        uv, jac = cv2.projectPoints(pts.reshape(-1, 1, 3), self.rvec, self.t, self.K, self.dist)
        d_dt = jac[:, 3:6].reshape(-1, 2, 3)
        return uv.reshape(-1, 2), d_dt @ self.R

    def undistort_normalized(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) [px] to undistorted normalised coordinates ``x/z, y/z``, (n, 2)."""
        px = np.asarray(pixels, dtype=float).reshape(-1, 1, 2)
        if px.shape[0] == 0:  # OpenCV returns None for no points
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        return cv2.undistortPoints(px, self.K, self.dist, criteria=criteria).reshape(-1, 2)

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels inside the image (all True if the size is unknown)."""
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        if self.image_size is None:
            return np.ones(px.shape[0], dtype=bool)
        w, h = self.image_size
        return (
            (px[:, 0] >= -0.5 - margin)
            & (px[:, 0] <= w - 0.5 + margin)
            & (px[:, 1] >= -0.5 - margin)
            & (px[:, 1] <= h - 0.5 + margin)
        )
