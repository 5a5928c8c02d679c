"""Multi-view triangulation: linear DLT, then reprojection-error refinement.

Every point seen in two or more calibrated views is first triangulated
linearly (homogeneous DLT on undistorted normalised image coordinates,
solved by SVD), then refined by minimising its reprojection error through
the full distortion model (``cv2.projectPoints``) with
``scipy.optimize.least_squares``. The 3x3 covariance of each point is the
Gauss-Newton one, ``sigma^2 (J^T J)^-1``, where ``sigma`` [px] is the
image-noise level, by default pooled from the reprojection residuals of all
points.

Checks that raise ``ValueError`` rather than return garbage: fewer than two
views of a point, observations outside a camera's image (a calibration made
for another image size), points behind a camera, and nearly parallel rays
(baseline negligible relative to depth).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .cameras import Camera


@dataclass(frozen=True)
class Triangulation:
    """Triangulated points and their uncertainty.

    Attributes
    ----------
    points : numpy.ndarray
        World points, (n, 3) [world units].
    covariances : numpy.ndarray
        Their covariances, (n, 3, 3) [world units^2], for pixel noise ``sigma``.
    residuals : numpy.ndarray
        Observed minus reprojected pixels, (n_views, n, 2) [px]; NaN where a
        view does not see the point.
    rms : float
        RMS reprojection error over all observations [px] (per image
        coordinate pair, i.e. the RMS residual length).
    sigma : float
        Pixel noise used for the covariances [px per coordinate].
    ray_angle : numpy.ndarray
        Largest angle between the viewing rays of each point [deg].
    """

    points: np.ndarray
    covariances: np.ndarray
    residuals: np.ndarray
    rms: float
    sigma: float
    ray_angle: np.ndarray

    @property
    def std(self) -> np.ndarray:
        """Per-axis standard deviations, (n, 3) [world units]."""
        return np.sqrt(np.einsum("nii->ni", self.covariances))


def _observations(cameras: Sequence[Camera], pixels: Sequence[np.ndarray]) -> np.ndarray:
    if len(cameras) < 2:
        raise ValueError(f"triangulation needs at least 2 views, got {len(cameras)}")
    if len(pixels) != len(cameras):
        raise ValueError(f"got {len(cameras)} cameras but {len(pixels)} pixel arrays")
    obs = [np.asarray(p, dtype=float) for p in pixels]
    n = obs[0].shape[0] if obs[0].ndim == 2 else -1
    for k, p in enumerate(obs):
        if p.ndim != 2 or p.shape != (n, 2):
            raise ValueError(f"pixels[{k}] must have shape ({n}, 2), got {p.shape}")
        if not isinstance(cameras[k], Camera):
            raise ValueError(f"cameras[{k}] is not a Camera")
        seen = np.all(np.isfinite(p), axis=1)
        inside = cameras[k].in_image(p[seen])
        if not np.all(inside):
            size = cameras[k].image_size
            raise ValueError(
                f"{np.count_nonzero(~inside)} observations in view {k} lie outside its "
                f"{size[0]}x{size[1]} image: the calibration does not match these images"
            )
    return np.stack(obs)


def _rays(cameras: Sequence[Camera], obs: np.ndarray) -> np.ndarray:
    """Unit viewing directions in world coordinates, (n_views, n, 3); NaN if unseen."""
    out = np.full(obs.shape[:2] + (3,), np.nan)
    for k, cam in enumerate(cameras):
        seen = np.all(np.isfinite(obs[k]), axis=1)
        if np.any(seen):
            xn = cam.undistort_normalized(obs[k][seen])
            d = np.hstack([xn, np.ones((xn.shape[0], 1))]) @ cam.R  # R^T d, row-wise
            out[k, seen] = d / np.linalg.norm(d, axis=1, keepdims=True)
    return out


def max_ray_angle(rays: np.ndarray) -> np.ndarray:
    """Largest pairwise angle between the available rays of each point [deg]."""
    n_views, n = rays.shape[:2]
    best = np.zeros(n)
    for a in range(n_views):
        for b in range(a + 1, n_views):
            cos = np.einsum("ni,ni->n", rays[a], rays[b])
            ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
            best = np.fmax(best, np.where(np.isfinite(ang), ang, 0.0))
    return best


def triangulate_linear(cameras: Sequence[Camera], obs: np.ndarray) -> np.ndarray:
    """Homogeneous DLT triangulation, (n, 3), from undistorted normalised coordinates."""
    centers = np.array([c.center() for c in cameras])
    origin = centers.mean(axis=0)
    scale = max(np.linalg.norm(centers - origin, axis=1).mean(), 1e-12)
    # World -> normalised world: X = origin + scale * Y, so P Xh = P T Yh.
    T = np.diag([scale, scale, scale, 1.0])
    T[:3, 3] = origin
    n = obs.shape[1]
    rows = np.full((n, 2 * len(cameras), 4), 0.0)
    for k, cam in enumerate(cameras):
        seen = np.all(np.isfinite(obs[k]), axis=1)
        Pk = np.hstack([cam.R, cam.t[:, None]]) @ T
        xn = np.zeros((n, 2))
        xn[seen] = cam.undistort_normalized(obs[k][seen])
        r1 = xn[:, 0:1] * Pk[2] - Pk[0]
        r2 = xn[:, 1:2] * Pk[2] - Pk[1]
        for j, r in ((0, r1), (1, r2)):
            r = r / np.linalg.norm(r, axis=1, keepdims=True)
            rows[:, 2 * k + j] = np.where(seen[:, None], r, 0.0)
    _, _, vt = np.linalg.svd(rows)
    Yh = vt[:, -1, :]
    if np.any(np.abs(Yh[:, 3]) < 1e-12 * np.linalg.norm(Yh, axis=1)):
        raise ValueError("a linear solution is at infinity: the rays are parallel")
    return origin + scale * Yh[:, :3] / Yh[:, 3:4]


def triangulate(
    cameras: Sequence[Camera],
    pixels: Sequence[np.ndarray],
    sigma: float | None = None,
    min_ray_angle: float = 1.0,
    refine: bool = True,
) -> Triangulation:
    """Triangulate points seen in two or more calibrated views.

    Parameters
    ----------
    cameras : sequence of Camera
        The calibrated views (all in one world frame).
    pixels : sequence of numpy.ndarray
        Observations per view, each (n, 2) [px], rows in the same point order;
        NaN rows mark points a view does not see.
    sigma : float, optional
        Pixel noise [px] for the covariances; by default estimated from the
        residuals, ``sqrt(sum r^2 / (n_obs_coords - 3 n))``.
    min_ray_angle : float
        Smallest acceptable largest angle between the rays of a point [deg];
        below it depth is undetermined (baseline ~ 0 relative to depth).
    refine : bool
        Refine the linear solution by minimising the reprojection error.

    Returns
    -------
    Triangulation

    Raises
    ------
    ValueError
        For fewer than 2 views (of any point), observations outside a
        camera's image, nearly parallel rays, points behind a camera, or an
        unestimable noise level.
    """
    obs = _observations(cameras, pixels)
    seen = np.all(np.isfinite(obs), axis=2)
    n_seen = seen.sum(axis=0)
    if np.any(n_seen < 2):
        raise ValueError(f"{np.count_nonzero(n_seen < 2)} points are seen in fewer than 2 views")
    rays = _rays(cameras, obs)
    angle = max_ray_angle(rays)
    if np.any(angle < min_ray_angle):
        raise ValueError(
            f"{np.count_nonzero(angle < min_ray_angle)} of {angle.size} points have viewing "
            f"rays within {min_ray_angle} deg of parallel (smallest {angle.min():.3g} deg): "
            "the baseline is negligible relative to the depth, so depth is undetermined"
        )
    X = triangulate_linear(cameras, obs)
    _check_in_front(cameras, X, seen)
    n = X.shape[0]
    jacs = np.zeros((n, 2 * len(cameras), 3))
    for p in range(n):
        if refine:
            X[p] = least_squares(
                _residual,
                X[p],
                jac=_jacobian,
                method="lm",
                args=(cameras, obs[:, p], seen[:, p]),
                xtol=1e-12,
            ).x
        jacs[p] = _jacobian(X[p], cameras, obs[:, p], seen[:, p])
    _check_in_front(cameras, X, seen)
    residuals = np.full(obs.shape, np.nan)
    for k, cam in enumerate(cameras):
        residuals[k, seen[k]] = obs[k, seen[k]] - cam.project(X[seen[k]])
    sq = np.nansum(residuals**2)
    rms = float(np.sqrt(sq / seen.sum()))
    if sigma is None:
        dof = 2 * seen.sum() - 3 * n
        if dof <= 0:
            raise ValueError("cannot estimate the pixel noise with zero redundancy; pass sigma")
        sigma = float(np.sqrt(sq / dof))
    info = np.einsum("nki,nkj->nij", jacs, jacs)
    if np.any(np.linalg.cond(info) > 1e12):
        raise ValueError("ill-conditioned point geometry: depth is undetermined")
    cov = sigma**2 * np.linalg.inv(info)
    return Triangulation(X, cov, residuals, rms, float(sigma), angle)


def _check_in_front(cameras: Sequence[Camera], X: np.ndarray, seen: np.ndarray) -> None:
    for k, cam in enumerate(cameras):
        behind = seen[k] & (cam.depth(X) <= 0)
        if np.any(behind):
            raise ValueError(
                f"{np.count_nonzero(behind)} points triangulate behind camera {k}: "
                "the calibration does not match the observations"
            )


def _residual(x, cameras, obs, seen):
    out = np.zeros(2 * len(cameras))
    for k, cam in enumerate(cameras):
        if seen[k]:
            out[2 * k : 2 * k + 2] = cam.project(x[None])[0] - obs[k]
    return out


def _jacobian(x, cameras, obs, seen):
    out = np.zeros((2 * len(cameras), 3))
    for k, cam in enumerate(cameras):
        if seen[k]:
            out[2 * k : 2 * k + 2] = cam.project_with_jacobian(x[None])[1][0]
    return out
