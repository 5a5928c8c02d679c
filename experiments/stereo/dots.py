"""Sub-pixel detection of dark dots on a bright background.

:func:`detect_dots` finds dark blobs with a morphological black-hat (closing
minus image, so large dark regions such as the scene background vanish), an
Otsu threshold, connected components and shape filters (square dots seen in
perspective are convex quadrilaterals; printed digits and clutter are not).
Each centre is the black-hat-weighted centroid of the blob grown by 2 px
(sub-pixel). :func:`detect_near` looks for single dots at predicted
positions. The grid structure is recovered in :mod:`.lattice`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Dots:
    """Detected dots.

    Attributes
    ----------
    centers : numpy.ndarray
        Sub-pixel centres ``(u, v)``, shape (n, 2) [px].
    areas : numpy.ndarray
        Blob areas, shape (n,) [px^2].
    """

    centers: np.ndarray
    areas: np.ndarray


def to_gray(image: np.ndarray) -> np.ndarray:
    """Grey uint8 view of a grey or BGR image (other dtypes are rescaled to 0-255)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"expected a grey or BGR image, got shape {np.shape(image)}")
    if img.dtype != np.uint8:
        img = cv2.normalize(img.astype(np.float64), None, 0, 255, cv2.NORM_MINMAX)
        img = img.astype(np.uint8)
    return img


def black_hat(gray: np.ndarray, max_dot_size: int | None = None):
    """Black-hat (closing minus image) and its Otsu threshold.

    Returns
    -------
    hat : numpy.ndarray
        uint8 image, large where a pixel is darker than its surroundings
        within a ``k x k`` window.
    thresh : float
        Otsu threshold of ``hat``.
    k : int
        Kernel size used [px] (odd; default 1/40 of the larger image side).
    """
    k = int(max_dot_size or max(gray.shape) // 40) | 1
    if k < 5:
        raise ValueError(f"max_dot_size must be >= 5 px, got {k}")
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    hat = cv2.morphologyEx(gray, cv2.MORPH_BLACKHAT, kernel)
    thresh, _ = cv2.threshold(hat, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return hat, float(thresh), k


def _is_square_like(mask: np.ndarray, area: float, min_fill: float, min_solidity: float) -> bool:
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=cv2.contourArea)
    (_, _), (rw, rh), _ = cv2.minAreaRect(contour)
    hull_area = cv2.contourArea(cv2.convexHull(contour))
    return area >= min_fill * max(rw * rh, 1.0) and area >= min_solidity * hull_area


_GROW = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))


def _weighted_centroid(hat: np.ndarray, mask: np.ndarray, x0: int, y0: int) -> tuple:
    """Black-hat-weighted centroid of a blob grown by 2 px (so its blurred edge counts)."""
    wts = hat * cv2.dilate(mask, _GROW).astype(bool)
    total = wts.sum()
    yy, xx = np.mgrid[0 : hat.shape[0], 0 : hat.shape[1]]
    return (x0 + (wts * xx).sum() / total, y0 + (wts * yy).sum() / total)


def detect_dots(
    image: np.ndarray,
    max_dot_size: int | None = None,
    min_area: int = 12,
    min_fill: float = 0.6,
    min_solidity: float = 0.88,
) -> Dots:
    """Detect dark dots on a bright background with sub-pixel centres.

    Parameters
    ----------
    image : numpy.ndarray
        Grey or BGR image.
    max_dot_size : int, optional
        Side [px] of the black-hat structuring element; must exceed the
        largest dot. Default: 1/40 of the larger image side.
    min_area : int
        Smallest blob kept [px^2].
    min_fill : float
        Smallest ratio of blob area to its minimum-area rectangle (square
        dots seen in perspective stay close to 1; letters and clutter do not).
    min_solidity : float
        Smallest ratio of blob area to the area of its convex hull (convex
        quadrilaterals give about 1; printed digits 0.7-0.8).

    Returns
    -------
    Dots
    """
    gray = to_gray(image)
    hat, thresh, k = black_hat(gray, max_dot_size)
    binary = (hat > thresh).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    h, w = gray.shape
    hat_f = hat.astype(np.float64)
    centers, areas = [], []
    for c in range(1, n):
        x, y, bw, bh, area = stats[c]
        if area < min_area or bw >= k or bh >= k:
            continue
        if x <= 2 or y <= 2 or x + bw >= w - 2 or y + bh >= h - 2:
            continue  # touching the border: the centroid would be biased
        x0, y0 = max(x - 3, 0), max(y - 3, 0)
        x1, y1 = min(x + bw + 3, w), min(y + bh + 3, h)
        mask = (labels[y0:y1, x0:x1] == c).astype(np.uint8)
        if not _is_square_like(mask, area, min_fill, min_solidity):
            continue
        centers.append(_weighted_centroid(hat_f[y0:y1, x0:x1], mask, x0, y0))
        areas.append(float(area))
    return Dots(
        centers=np.asarray(centers, dtype=float).reshape(-1, 2),
        areas=np.asarray(areas, dtype=float),
    )


def detect_near(
    image: np.ndarray,
    predictions: np.ndarray,
    spacing: np.ndarray,
    max_dot_size: int | None = None,
    accept: float = 0.2,
    min_area: int = 6,
    min_contrast: float = 20.0,
) -> np.ndarray:
    """Look for one dark dot near each predicted position (guided detection).

    Used for dots that a calibrated model says are visible but that the
    global detector missed, e.g. thin slivers near a silhouette merged with
    the dark background, or dots washed out by glare. Inside a window of
    half-size ``spacing / 2`` around a prediction, the black-hat blob
    nearest the prediction is accepted only
    if it does not touch the window edge (so it is not part of something
    larger) and its centroid lies within ``accept * spacing`` of the
    prediction (a neighbouring dot is a whole spacing away).

    Parameters
    ----------
    image : numpy.ndarray
        Grey or BGR image.
    predictions : numpy.ndarray
        Predicted centres, (m, 2) [px].
    spacing : numpy.ndarray
        Smallest local grid spacing at each prediction, (m,) [px].
    max_dot_size : int, optional
        Black-hat kernel size [px], as in :func:`detect_dots`.
    accept : float
        Acceptance radius as a fraction of ``spacing``.
    min_area : int
        Smallest blob [px^2].
    min_contrast : float
        Smallest black-hat contrast [grey levels] near the prediction for a
        dot to be looked for; the blob is segmented at half that contrast.

    Returns
    -------
    numpy.ndarray
        (m, 2) centres [px]; NaN where no acceptable dot was found.
    """
    gray = to_gray(image)
    hat, thresh, _ = black_hat(gray, max_dot_size)
    hat_f = hat.astype(np.float64)
    h, w = gray.shape
    pred = np.asarray(predictions, dtype=float).reshape(-1, 2)
    out = np.full(pred.shape, np.nan)
    for m, (p, sp) in enumerate(zip(pred, np.asarray(spacing, dtype=float).ravel())):
        half = max(int(0.5 * sp), 3)
        cx, cy = int(round(p[0])), int(round(p[1]))
        x0, y0, x1, y1 = cx - half, cy - half, cx + half + 1, cy + half + 1
        if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
            continue
        # Local threshold at half the contrast found near the prediction, so
        # dots washed out by glare are segmented whole.
        r = max(int(accept * sp), 2)
        peak = np.percentile(hat[cy - r : cy + r + 1, cx - r : cx + r + 1], 95)
        if peak < min_contrast:
            continue
        binary = (hat[y0:y1, x0:x1] > min(0.5 * peak, thresh)).astype(np.uint8)
        n, labels, stats, cents = cv2.connectedComponentsWithStats(binary, connectivity=8)
        if n < 2:
            continue
        c = 1 + int(np.argmin(np.linalg.norm(cents[1:] + (x0, y0) - p, axis=1)))
        bx, by, bw, bh, area = stats[c]
        if area < min_area or bx == 0 or by == 0 or bx + bw == x1 - x0 or by + bh == y1 - y0:
            continue
        mask = (labels == c).astype(np.uint8)
        centre = np.array(_weighted_centroid(hat_f[y0:y1, x0:x1], mask, x0, y0))
        if np.linalg.norm(centre - p) <= accept * sp:
            out[m] = centre
    return out
