"""Normalised direct linear transform (DLT) for a 3x4 projection matrix.

The DLT solves ``x_k ~ P X_k`` linearly from at least six 3D-2D
correspondences of a non-planar object. Following Hartley & Zisserman
(Multiple View Geometry, 2nd ed., alg. 7.1), both point sets are first
normalised (centroid at the origin, mean distance sqrt(2) in 2D and sqrt(3)
in 3D), which makes the homogeneous least-squares problem well conditioned;
the solution is the right singular vector of the smallest singular value.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .cameras import Camera


def normalizing_transform(points: np.ndarray) -> np.ndarray:
    """Similarity ``T`` moving points (n, d) to centroid 0 and mean distance sqrt(d).

    Returns
    -------
    numpy.ndarray
        ``(d + 1) x (d + 1)`` homogeneous matrix.
    """
    pts = np.asarray(points, dtype=float)
    d = pts.shape[1]
    centroid = pts.mean(axis=0)
    mean_dist = np.linalg.norm(pts - centroid, axis=1).mean()
    if not np.isfinite(mean_dist) or mean_dist <= 0:
        raise ValueError("points are all identical; cannot normalise them")
    s = np.sqrt(d) / mean_dist
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * centroid
    return T


@dataclass(frozen=True)
class DLTResult:
    """A DLT projection matrix and its fit.

    Attributes
    ----------
    P : numpy.ndarray
        3x4 projection matrix, scaled so ``||P|| = 1`` and the object has
        positive depth (third row of ``P X`` > 0 on average).
    residuals : numpy.ndarray
        Reprojection residuals ``x_obs - proj(P, X)``, shape (n, 2) [px].
    rms : float
        Root-mean-square of the residual lengths [px].
    proper : bool
        True when ``det(P[:, :3]) > 0`` with the points in front, i.e. the
        fit is a real camera and not a mirror image of the object.
    condition : float
        Ratio of the two smallest singular values of the normalised system
        (large means a well-determined solution).
    """

    P: np.ndarray
    residuals: np.ndarray
    rms: float
    proper: bool
    condition: float


def project_matrix(P: np.ndarray, points3d: np.ndarray) -> np.ndarray:
    """Project (n, 3) world points with a 3x4 matrix; returns (n, 2) [px]."""
    X = np.asarray(points3d, dtype=float)
    h = X @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:3]


def dlt_projection(points3d: np.ndarray, pixels: np.ndarray) -> DLTResult:
    """Normalised DLT estimate of the projection matrix.

    Parameters
    ----------
    points3d : numpy.ndarray
        Object points, shape (n, 3) [world units], n >= 6, not coplanar.
    pixels : numpy.ndarray
        Their images, shape (n, 2) [px].

    Returns
    -------
    DLTResult

    Raises
    ------
    ValueError
        Too few points, mismatched shapes, or (near-)coplanar object points,
        for which the DLT has no unique solution.
    """
    X = np.asarray(points3d, dtype=float)
    x = np.asarray(pixels, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (X.shape[0], 2):
        raise ValueError(f"need points3d (n, 3) and pixels (n, 2); got {X.shape}, {x.shape}")
    n = X.shape[0]
    if n < 6:
        raise ValueError(f"the DLT needs at least 6 correspondences, got {n}")
    sv3 = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv3[2] < 1e-6 * sv3[0]:
        raise ValueError("object points are (nearly) coplanar: the DLT is degenerate")
    T2 = normalizing_transform(x)
    T3 = normalizing_transform(X)
    xn = x @ T2[:2, :2].T + T2[:2, 2]
    Xh = np.hstack([X @ T3[:3, :3].T + T3[:3, 3], np.ones((n, 1))])
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -xn[:, 0:1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -xn[:, 1:2] * Xh
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.solve(T2, Pn @ T3)
    P /= np.linalg.norm(P)
    depth = X @ P[2, :3] + P[2, 3]
    if np.mean(depth) < 0:
        P = -P
        depth = -depth
    proper = bool(np.linalg.det(P[:, :3]) > 0 and np.all(depth > 0))
    residuals = x - project_matrix(P, X)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    condition = float(s[-2] / max(s[-1], 1e-300))
    return DLTResult(P=P, residuals=residuals, rms=rms, proper=proper, condition=condition)


def decompose_projection(P: np.ndarray, image_size: tuple[int, int] | None = None) -> Camera:
    """Split ``P = K [R | t]`` into a distortion-free :class:`Camera`.

    Uses ``cv2.decomposeProjectionMatrix`` (an RQ decomposition) and fixes
    the signs so that ``K`` has a positive diagonal and ``R`` is a proper
    rotation.

    Raises
    ------
    ValueError
        If ``P[:, :3]`` is singular or a reflection (an improper camera).
    """
    P = np.asarray(P, dtype=float)
    if P.shape != (3, 4):
        raise ValueError(f"P must be 3x4, got {P.shape}")
    M = P[:, :3]
    det = np.linalg.det(M)
    if abs(det) < 1e-12 * np.linalg.norm(M) ** 3:
        raise ValueError("P[:, :3] is singular: not a finite projective camera")
    if det < 0:
        P = -P  # the same camera; the overall sign of P is arbitrary
    K, R, C_h = cv2.decomposeProjectionMatrix(P)[:3]
    signs = np.sign(np.diag(K))
    signs[signs == 0] = 1.0
    S = np.diag(signs)
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:
        raise ValueError("the projection matrix is a reflection (mirrored object labelling)")
    K = K / K[2, 2]
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    C = (C_h[:3] / C_h[3]).ravel()
    return Camera(K=K, dist=np.zeros(5), R=R, t=-R @ C, image_size=image_size)
