"""Read the MultiDIC cylinder's printed column numbers, to anchor the labelling.

The cylinder's dot grid is invariant under a turn of one column spacing
(12.06 degrees) about its axis, so no geometric fit can tell which column is
which when a view does not show both ends of the grid (see
:mod:`.gridlabel`). The object itself carries the answer: every column has
its number (1 to 14) printed above its top dot. This module does not
recognise digits; it only counts the dark blobs in the label area above each
column. Numbers 1-9 are one blob, 10-14 two, so the first two-blob column
is column 10, i.e. object index ``j = 9`` under the convention that printed
column ``n`` is ``P3d[:, n - 1]``.

Only columns seen fairly face-on (column spacing at least ``min_spacing`` of
the largest) are read. The pattern must be a clean run of ones followed by
a run of twos, otherwise a ``ValueError`` asks for a manual anchor.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .dots import to_gray


@dataclass(frozen=True)
class ColumnReading:
    """Blob counts in the label areas, left to right.

    Attributes
    ----------
    top_dots : numpy.ndarray
        Index (into the detections) of the top dot of each column.
    counts : numpy.ndarray
        Blobs found above each column (-1 where the column is too oblique).
    first_two_digit : int
        Index into ``top_dots`` of the first column whose number has two digits.
    """

    top_dots: np.ndarray
    counts: np.ndarray
    first_two_digit: int

    def anchor(self, first_two_digit_number: int = 10) -> tuple[int, None, int]:
        """Anchor ``(dot, None, j)`` for :func:`~experiments.stereo.gridlabel.label_grid`."""
        return int(self.top_dots[self.first_two_digit]), None, first_two_digit_number - 1


def _columns(centers: np.ndarray, lattice: np.ndarray, valid: np.ndarray):
    """Group lattice dots into image columns (lattice lines closest to vertical)."""
    idx = np.flatnonzero(valid)
    lookup = {tuple(lattice[k]): k for k in idx}
    steps = {0: [], 1: []}
    for k in idx:
        for axis in (0, 1):
            nb = tuple(lattice[k] + np.eye(2, dtype=int)[axis])
            if nb in lookup:
                steps[axis].append(centers[lookup[nb]] - centers[k])
    vertical = []
    for axis in (0, 1):
        s = np.asarray(steps[axis]).reshape(-1, 2)
        vertical.append(np.median(np.abs(s[:, 1]) / (np.abs(s[:, 0]) + 1e-9)) if len(s) else 0)
    along = int(np.argmax(vertical))  # lattice axis running along a column
    across = 1 - along
    cols: dict[int, list[int]] = {}
    for k in idx:
        cols.setdefault(int(lattice[k, across]), []).append(int(k))
    return cols


def read_column_numbers(
    image: np.ndarray,
    centers: np.ndarray,
    lattice: np.ndarray,
    valid: np.ndarray,
    max_dot_size: int | None = None,
    min_spacing: float = 0.5,
) -> ColumnReading:
    """Count the printed digits above each column of a labelled lattice.

    Parameters
    ----------
    image : numpy.ndarray
        The image the dots were detected in (camera upright: numbers on top).
    centers, lattice, valid : numpy.ndarray
        Dot centres [px] and the output of
        :func:`experiments.stereo.lattice.grid_lattice`.
    max_dot_size : int, optional
        Black-hat kernel size [px], as in :func:`~experiments.stereo.dots.detect_dots`.
    min_spacing : float
        Columns whose spacing (mean gap to their neighbours) is below this
        fraction of the largest are too oblique to read and are skipped.

    Raises
    ------
    ValueError
        If the counts are not a clean run of 1s followed by a run of 2s.
    """
    gray = to_gray(image)
    k = int(max_dot_size or max(gray.shape) // 40) | 1
    hat = cv2.morphologyEx(
        gray, cv2.MORPH_BLACKHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    )
    thresh, _ = cv2.threshold(hat, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    cols = _columns(centers, lattice, valid)
    keys = sorted(cols, key=lambda c: np.mean(centers[cols[c], 0]))
    tops, ups, spans = [], [], []
    for c in keys:
        members = sorted(cols[c], key=lambda m: centers[m, 1])
        tops.append(members[0])
        ups.append(centers[members[0]] - centers[members[1]] if len(members) > 1 else None)
    top_xy = centers[tops]
    for n in range(len(keys)):
        gaps = [abs(top_xy[n, 0] - top_xy[m, 0]) for m in (n - 1, n + 1) if 0 <= m < len(keys)]
        spans.append(float(np.mean(gaps)) if gaps else 0.0)
    spans = np.asarray(spans)
    dot_area = np.pi * (0.25 * np.median(spans)) ** 2
    counts = np.full(len(keys), -1)
    for n in range(len(keys)):
        if ups[n] is None or spans[n] < min_spacing * spans.max():
            continue
        counts[n] = _count_blobs(hat, thresh, top_xy[n], ups[n], spans[n], 0.05 * dot_area)
    read = np.flatnonzero(counts >= 0)
    seq = counts[read]
    if (
        seq.size < 2
        or np.any((seq != 1) & (seq != 2))
        or np.any(np.diff(seq) < 0)
        or seq[0] != 1
        or seq[-1] != 2
    ):
        raise ValueError(
            f"could not read the printed column numbers (digit-blob counts {counts.tolist()}); "
            "give the labelling an anchor by hand"
        )
    first = int(read[np.argmax(seq == 2)])
    return ColumnReading(np.asarray(tops), counts, first)


def _count_blobs(
    hat: np.ndarray, thresh: float, top: np.ndarray, up: np.ndarray, span: float, min_area: float
) -> int:
    """Dark blobs whose centroid lies 0.3-1.2 row steps above ``top``, within +-span/2."""
    up_len = np.linalg.norm(up)
    u_dir = up / up_len
    side = np.array([-u_dir[1], u_dir[0]])
    corners = np.array([top + s * up + t * span * side for s in (0.3, 1.2) for t in (-0.5, 0.5)])
    h, w = hat.shape
    pad = int(span) + 2  # whole digits, even where they cross the region's edge
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int) - pad, 0)
    x1, y1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int) + pad + 1, [w, h])
    if x1 <= x0 or y1 <= y0:
        return 0
    binary = (hat[y0:y1, x0:x1] > thresh).astype(np.uint8)
    n, _, stats, cents = cv2.connectedComponentsWithStats(binary, connectivity=8)
    count = 0
    for c in range(1, n):
        if stats[c, cv2.CC_STAT_AREA] < min_area:
            continue
        rel = cents[c] + (x0, y0) - top
        s, t = rel @ u_dir / up_len, rel @ side / span
        if 0.3 <= s <= 1.2 and -0.5 <= t <= 0.5:
            count += 1
    return count
