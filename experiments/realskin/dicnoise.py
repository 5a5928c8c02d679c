"""The DIC's noise: spurious points (robust, against their neighbours) and the spatial
noise per frame of the real skin data (docs/realskin-data.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

SPURIOUS_K = 5.0
"""Threshold of the normalised median test (robust standard deviations)."""


NEIGHBOUR_RADIUS = 1.5
"""Neighbourhood radius in median DIC grid spacings (the 8 grid neighbours)."""


_MAD = 1.4826  # MAD -> standard deviation for Gaussian data


def _neighbours(ref: np.ndarray, keep: np.ndarray | None = None) -> list[np.ndarray]:
    """Indices of each point's neighbours within NEIGHBOUR_RADIUS grid spacings."""
    keep = np.ones(len(ref), bool) if keep is None else keep
    tree = cKDTree(ref)
    spacing = float(np.median(tree.query(ref, k=2)[0][:, 1]))
    lists = tree.query_ball_point(ref, NEIGHBOUR_RADIUS * spacing)
    return [np.array([j for j in n if j != i and keep[j]], dtype=int) for i, n in enumerate(lists)]


def _detrend(ref: np.ndarray, disp: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``disp`` (F, P, 2) minus its least-squares cubic polynomial in x, y (fitted on
    ``rows``, per frame and component); other rows become NaN."""
    x, y = ((ref - ref[rows].mean(0)) / ref[rows].std(0)).T
    basis = np.stack([x**a * y**b for a in range(4) for b in range(4 - a)], axis=1)
    flat = disp.transpose(1, 0, 2).reshape(len(ref), -1)
    coef = np.linalg.lstsq(basis[rows], flat[rows], rcond=None)[0]
    out = np.where(rows[:, None], flat - basis @ coef, np.nan)
    return out.reshape(len(ref), *disp.shape[::2]).transpose(1, 0, 2)


def spurious_points(ref_mm: np.ndarray, disp_mm: np.ndarray, k: float = SPURIOUS_K) -> np.ndarray:
    """Spurious DIC points: non-finite values or a failed normalised median test.

    Parameters
    ----------
    ref_mm : ndarray (P, 2)
        Reference positions [mm].
    disp_mm : ndarray (F, P, 2)
        Displacements [mm] per frame.
    k : float
        Threshold in robust standard deviations.

    Returns
    -------
    ndarray (P,) of bool
        True for a discarded point.

    Notes
    -----
    The cubic trend of each frame is removed first (so one-sided neighbourhoods at the
    border see no large gradient). Then, per frame, point and component, ``r = u - med``
    with ``med`` the median of the grid neighbours; the point is spurious when
    ``|r| > k (1.4826 rm + sigma)`` in any frame, ``rm`` being the median of
    ``|u_j - med|`` over the neighbours (local spread: steep but smooth gradients pass)
    and ``sigma`` the frame's robust standard deviation of ``r`` (noise floor).
    Points without neighbours are kept.
    """
    ref = np.asarray(ref_mm, dtype=float)
    disp = np.asarray(disp_mm, dtype=float)
    bad = ~np.isfinite(disp).all(axis=(0, 2)) | ~np.isfinite(ref).all(axis=1)
    ref = np.where(bad[:, None], 0.0, ref)
    disp = _detrend(ref, np.where(np.isfinite(disp), disp, 0.0), ~bad)
    resid = np.full(disp.shape, np.nan)
    spread = np.full(disp.shape, np.nan)
    for i, nbrs in enumerate(_neighbours(ref, ~bad)):
        if len(nbrs) and not bad[i]:
            med = np.median(disp[:, nbrs, :], axis=1)
            resid[:, i] = disp[:, i] - med
            spread[:, i] = np.median(np.abs(disp[:, nbrs, :] - med[:, None]), axis=1)
    sigma = np.maximum(_MAD * np.nanmedian(np.abs(resid), axis=1, keepdims=True), 1e-9)
    with np.errstate(invalid="ignore"):
        return bad | (np.abs(resid) > k * (_MAD * spread + sigma)).any(axis=(0, 2))


def spatial_noise_per_frame(ref_mm: np.ndarray, disp_mm: np.ndarray) -> np.ndarray:
    """DIC noise per frame from residuals of a local plane fit.

    Parameters
    ----------
    ref_mm : ndarray (P, 2)
        Reference positions [mm] (spurious points already removed).
    disp_mm : ndarray (F, P, 2)
        Displacements [mm].

    Returns
    -------
    ndarray (F,)
        Noise standard deviation [mm] of one displacement component, per frame.

    Notes
    -----
    Each point is predicted by a least-squares plane through its (>= 3) neighbours; the
    residual is divided by ``sqrt(1 + ||e0 pinv(A)||^2)`` (the prediction's own variance
    factor) and the noise is 1.4826 x the median absolute residual over points and both
    components. Unresolved sub-grid field curvature is counted as noise (upper bound).
    """
    disp = np.asarray(disp_mm, dtype=float)
    resid = np.full(disp.shape, np.nan)
    for i, nbrs in enumerate(_neighbours(ref_mm)):
        if len(nbrs) >= 3:
            weights = np.linalg.pinv(np.c_[np.ones(len(nbrs)), ref_mm[nbrs] - ref_mm[i]])[0]
            pred = np.einsum("k,fkc->fc", weights, disp[:, nbrs, :])
            resid[:, i] = (disp[:, i] - pred) / np.sqrt(1.0 + weights @ weights)
    return _MAD * np.nanmedian(np.abs(resid).reshape(len(disp), -1), axis=1)
