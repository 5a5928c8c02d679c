"""Bicubic B-spline surfaces fitted to scattered 3D points, and rigid registration.

The surface is the tensor product ``S(u, v) = sum_ab N_a(u) M_b(v) C_ab`` of
two clamped uniform bases of :class:`symbolic.basis.BSplineBasis` on
[0, 1]; control points are numbered ``a * n_v + b``. Fitting solves the
collocation system ``A C = X`` in the least-squares sense with
``numpy.linalg.lstsq`` (an orthogonal factorisation; the normal equations,
which square the condition number, are never formed).

Registration: :func:`rigid_align` is the Kabsch/Umeyama closed form (with
optional scale) for corresponding points; :func:`icp_to_surface` aligns a
point cloud to a fitted surface without correspondences (point-to-surface
ICP: closest surface points by Gauss-Newton in ``(u, v)``, then a
linearised point-to-plane rigid update).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.basis import BSplineBasis


def grid_parameters(ij: np.ndarray) -> np.ndarray:
    """Map integer grid indices (n, 2) linearly onto [0, 1]^2 (per axis, over their range)."""
    ij = np.asarray(ij, dtype=float)
    lo, hi = ij.min(axis=0), ij.max(axis=0)
    if np.any(hi <= lo):
        raise ValueError("grid indices must span at least two values along each axis")
    return (ij - lo) / (hi - lo)


@dataclass(frozen=True)
class SplineSurface:
    """A fitted tensor-product B-spline surface.

    Attributes
    ----------
    basis_u, basis_v : BSplineBasis
        The two univariate bases.
    control : numpy.ndarray
        Control points, (n_u, n_v, 3) [world units].
    residuals : numpy.ndarray
        Fitted minus data points at the data parameters, (n, 3).
    rms, max : float
        RMS and largest residual length [world units].
    """

    basis_u: BSplineBasis
    basis_v: BSplineBasis
    control: np.ndarray
    residuals: np.ndarray
    rms: float
    max: float

    def _matrix(self, uv: np.ndarray, du: int = 0, dv: int = 0) -> np.ndarray:
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        bu = self.basis_u.evaluate_dense(uv[:, 0], du)
        bv = self.basis_v.evaluate_dense(uv[:, 1], dv)
        return (bu[:, :, None] * bv[:, None, :]).reshape(uv.shape[0], -1)

    def evaluate(self, uv: np.ndarray, du: int = 0, dv: int = 0) -> np.ndarray:
        """Surface points (or partial derivatives) at parameters (n, 2); returns (n, 3)."""
        return self._matrix(uv, du, dv) @ self.control.reshape(-1, 3)

    def normals(self, uv: np.ndarray) -> np.ndarray:
        """Unit normals ``S_u x S_v`` at parameters (n, 2); returns (n, 3)."""
        n = np.cross(self.evaluate(uv, 1, 0), self.evaluate(uv, 0, 1))
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def closest(
        self, points: np.ndarray, uv0: np.ndarray, iterations: int = 20
    ) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points to ``points`` (n, 3), by Gauss-Newton from ``uv0`` (n, 2).

        Returns the parameters (n, 2), clipped to [0, 1], and the surface points (n, 3).
        """
        uv = np.clip(np.asarray(uv0, dtype=float).copy(), 0.0, 1.0)
        pts = np.asarray(points, dtype=float)
        for _ in range(iterations):
            r = self.evaluate(uv) - pts
            su, sv = self.evaluate(uv, 1, 0), self.evaluate(uv, 0, 1)
            J = np.stack([su, sv], axis=2)  # (n, 3, 2)
            JtJ = np.einsum("nki,nkj->nij", J, J) + 1e-12 * np.eye(2)
            step = np.linalg.solve(JtJ, np.einsum("nki,nk->ni", J, r)[..., None])[..., 0]
            uv = np.clip(uv - step, 0.0, 1.0)
            if np.max(np.abs(step)) < 1e-12:
                break
        return uv, self.evaluate(uv)


def fit_surface(
    points: np.ndarray, uv: np.ndarray, n_control: tuple[int, int] = (8, 6), degree: int = 3
) -> SplineSurface:
    """Least-squares tensor-product B-spline surface through scattered points.

    Parameters
    ----------
    points : numpy.ndarray
        Data points, (n, 3) [world units].
    uv : numpy.ndarray
        Their surface parameters in [0, 1]^2, (n, 2) (e.g. :func:`grid_parameters`).
    n_control : tuple of int
        Control points along u and v.
    degree : int
        Degree along both directions (3: bicubic).

    Raises
    ------
    ValueError
        Fewer points than control points, or a rank-deficient collocation
        matrix (the data leave some control points undetermined).
    """
    X = np.asarray(points, dtype=float)
    uv = np.asarray(uv, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3 or uv.shape != (X.shape[0], 2):
        raise ValueError(f"need points (n, 3) and uv (n, 2); got {X.shape} and {uv.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(uv))):
        raise ValueError("points and parameters must be finite")
    bu, bv = BSplineBasis(degree, n_control[0]), BSplineBasis(degree, n_control[1])
    unknowns = n_control[0] * n_control[1]
    if X.shape[0] < unknowns:
        raise ValueError(f"{X.shape[0]} points cannot determine {unknowns} control points")
    A_u = bu.evaluate(uv[:, 0]).toarray()
    A_v = bv.evaluate(uv[:, 1]).toarray()
    A = (A_u[:, :, None] * A_v[:, None, :]).reshape(X.shape[0], unknowns)
    coef, _, rank, sv = np.linalg.lstsq(A, X, rcond=None)
    if rank < unknowns or sv[-1] < 1e-10 * sv[0]:
        raise ValueError(
            f"rank-deficient fit (rank {rank} < {unknowns} control points): the parameters "
            "do not cover every basis function's support"
        )
    res = A @ coef - X
    lengths = np.linalg.norm(res, axis=1)
    return SplineSurface(
        bu,
        bv,
        coef.reshape(n_control[0], n_control[1], 3),
        res,
        float(np.sqrt(np.mean(lengths**2))),
        float(lengths.max()),
    )


def rigid_align(
    source: np.ndarray, target: np.ndarray, scale: bool = False
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``target ~ s R source + t`` (Kabsch / Umeyama 1991).

    Parameters
    ----------
    source, target : numpy.ndarray
        Corresponding points, (n, 3), n >= 3 and not collinear.
    scale : bool
        Estimate the scale ``s`` (Umeyama); otherwise ``s = 1`` (Kabsch).

    Returns
    -------
    s, R, t : float, numpy.ndarray, numpy.ndarray
        Scale, proper rotation (3, 3) and translation (3,).
    """
    P = np.asarray(source, dtype=float)
    Q = np.asarray(target, dtype=float)
    if P.shape != Q.shape or P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 3:
        raise ValueError(f"need two (n, 3) arrays with n >= 3; got {P.shape}, {Q.shape}")
    mp, mq = P.mean(axis=0), Q.mean(axis=0)
    Pc, Qc = P - mp, Q - mq
    U, S, Vt = np.linalg.svd(Qc.T @ Pc / P.shape[0])
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise ValueError("points are collinear: the rotation is undetermined")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.mean(np.sum(Pc**2, axis=1))) if scale else 1.0
    return s, R, mq - s * R @ mp


def icp_to_surface(
    points: np.ndarray,
    surface: SplineSurface,
    uv0: np.ndarray,
    iterations: int = 50,
    tol: float = 1e-12,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Rigidly align a point cloud to a surface (point-to-plane ICP).

    Each iteration finds every point's closest surface point ``q``
    (:meth:`SplineSurface.closest`) and solves the linearised problem
    ``min sum(((w x (p - c) + tau + p - q) . n)^2)`` (point-to-plane; the
    full 3D gap where ``q`` lies on the patch's edge) for a small rotation
    ``w`` about the cloud's centroid ``c`` and a translation ``tau``, with
    Levenberg-Marquardt damping: a step is kept only if the RMS distance
    falls. A surface with a continuous symmetry (a cylinder
    slides along and turns about its axis) leaves those motions
    undetermined; the damping keeps them from wandering.

    Parameters
    ----------
    points : numpy.ndarray
        Cloud to move, (n, 3).
    surface : SplineSurface
        Reference surface.
    uv0 : numpy.ndarray
        Starting guesses of each point's closest-point parameters, (n, 2).
    iterations : int
        Maximum number of accepted steps.
    tol : float
        Stop when the RMS distance improves by less than this [world units].

    Returns
    -------
    R, t : numpy.ndarray
        Rotation and translation with ``R @ p + t`` on the surface.
    rms : float
        RMS point-to-surface distance after alignment [world units].
    """
    P = np.asarray(points, dtype=float)

    def state(R, t, uv):
        moved = P @ R.T + t
        uv, closest = surface.closest(moved, uv)
        gap = moved - closest
        return moved, uv, gap, float(np.sqrt(np.mean(np.sum(gap**2, axis=1))))

    def linearise(moved, uv, gap):
        """Rows of d(gap)/d(w, tau) and the residuals: point-to-plane inside the
        patch, point-to-point where the closest point sits on the patch's edge."""
        centre = moved.mean(axis=0)
        q = moved - centre
        edge = np.any((uv <= 0.0) | (uv >= 1.0), axis=1)
        normal = surface.normals(uv[~edge])
        rows = [np.hstack([np.cross(q[~edge], normal), normal])]
        res = [np.einsum("nk,nk->n", gap[~edge], normal)]
        for qk, gk in zip(q[edge], gap[edge]):
            skew = np.array([[0, -qk[2], qk[1]], [qk[2], 0, -qk[0]], [-qk[1], qk[0], 0]])
            rows.append(np.hstack([-skew, np.eye(3)]))
            res.append(gk)
        return centre, np.vstack(rows), np.concatenate(res)

    R, t = np.eye(3), np.zeros(3)
    moved, uv, gap, rms = state(R, t, np.asarray(uv0, dtype=float))
    lam = 1e-4
    for _ in range(iterations):
        centre, A, b = linearise(moved, uv, gap)
        H, g = A.T @ A, A.T @ b
        improved = False
        for _ in range(20):
            step = np.linalg.solve(H + lam * np.diag(np.diag(H)) + 1e-15 * np.eye(6), -g)
            dR = _rotation(step[:3])
            R_new, t_new = dR @ R, dR @ (t - centre) + centre + step[3:]
            trial = state(R_new, t_new, uv)
            if trial[-1] < rms:
                improved = rms - trial[-1] >= tol
                R, t = R_new, t_new
                moved, uv, gap, rms = trial
                lam = max(lam / 3.0, 1e-12)
                break
            lam *= 10.0
        if not improved:
            break
    return R, t, rms


def _rotation(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` [rad] (Rodrigues' formula)."""
    angle = np.linalg.norm(w)
    if angle < 1e-15:
        return np.eye(3)
    k = w / angle
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx
