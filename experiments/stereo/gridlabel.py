"""Which detected dot is which object dot: resolving the lattice labelling.

:func:`experiments.stereo.lattice.grid_lattice` gives each dot lattice
coordinates ``(a, b)`` that are right up to the lattice's unknown
orientation and origin. The object's indices are ``(i, j) = T (a, b) + o``
for one of the 8 signed axis permutations ``T`` and an integer offset ``o``.
:func:`label_grid` tries every ``(T, o)`` that keeps at least
``min_in_range`` of the dots inside the object's index range and scores it
by fitting a normalised DLT to the implied 3D-2D pairs:

1. **Geometry.** Only proper fits (not a mirror image) count, scored by the
   number of DLT inliers. A wrong labelling that distorts the object fits
   badly, and a shift that pushes real rows out of range loses inliers.
2. **Up prior.** A symmetric object can fit equally well several ways. The
   MultiDIC cylinder (equal spacing in angle and height) is invariant under
   a 180-degree turn, so with ``up_axis`` (default world +z) the labelling
   in which that axis points up in the image is preferred.
3. **Anchors.** Shifts along a direction the view does not span completely
   (columns of the cylinder: a 12-degree turn about its axis moves the whole
   grid onto itself) are undetectable by any geometric test. An anchor
   ``(dot, i, j)`` fixes them; :mod:`.colnumbers` reads one from the
   cylinder's printed column numbers.

If more than one labelling survives, a ``ValueError`` says so: the labelling
is never picked silently. The chosen labelling is then verified after a full
calibration with lens distortion: a dot whose reprojection misses its
detection by more than ``reject_px`` is dropped (a wrong index is a whole
grid spacing away).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .calibration import ObjectCalibration, calibrate_from_object
from .dlt import dlt_projection, project_matrix

_TRANSFORMS = [
    np.array(m) * s
    for m in ([[1, 0], [0, 1]], [[0, 1], [1, 0]])
    for s in (
        np.array([[1], [1]]),
        np.array([[1], [-1]]),
        np.array([[-1], [1]]),
        np.array([[-1], [-1]]),
    )
]


@dataclass(frozen=True)
class Labelling:
    """Object indices for detected dots.

    Attributes
    ----------
    ij : numpy.ndarray
        (n, 2) int object indices per detected dot; ``-1`` where unlabelled.
    calibration : ObjectCalibration
        The camera calibrated from the labelled dots (after rejection).
    n_equivalent : int
        Labellings that fit the geometry equally well before the up prior and
        anchors were applied (1 means the geometry alone decided).
    rejected : int
        Dots dropped by the final reprojection check.
    """

    ij: np.ndarray
    calibration: ObjectCalibration
    n_equivalent: int
    rejected: int

    @property
    def labelled(self) -> np.ndarray:
        """Boolean mask of labelled dots."""
        return self.ij[:, 0] >= 0


@dataclass
class _Candidate:
    transform: np.ndarray
    offset: np.ndarray
    ij: np.ndarray
    in_range: np.ndarray
    inliers: int
    P: np.ndarray


def _candidates(
    ab: np.ndarray, pixels: np.ndarray, grid: np.ndarray, min_in_range: float, inlier_px: float
) -> list[_Candidate]:
    shape = np.array(grid.shape[:2])
    out = []
    for T in _TRANSFORMS:
        q = ab @ T.T
        lo, hi = q.min(axis=0), q.max(axis=0)
        for oi, oj in itertools.product(
            range(-hi[0], shape[0] - lo[0]), range(-hi[1], shape[1] - lo[1])
        ):
            ij = q + (oi, oj)
            ok = np.all((ij >= 0) & (ij < shape), axis=1)
            if ok.sum() < max(min_in_range * ab.shape[0], 6):
                continue
            fit = dlt_projection(grid[ij[ok, 0], ij[ok, 1]], pixels[ok])
            if not fit.proper:
                continue
            inliers = int(np.count_nonzero(np.linalg.norm(fit.residuals, axis=1) < inlier_px))
            out.append(_Candidate(T, np.array([oi, oj]), ij, ok, inliers, fit.P))
    return out


def _points_up(c: _Candidate, grid: np.ndarray, up_axis: np.ndarray) -> bool:
    """Does the world direction ``up_axis`` point up (decreasing v) in the image?"""
    X0 = grid[c.ij[c.in_range, 0], c.ij[c.in_range, 1]].mean(axis=0)
    scale = np.ptp(grid.reshape(-1, 3), axis=0).max() * 1e-3
    uv = project_matrix(c.P, np.stack([X0, X0 + scale * up_axis]))
    return bool(uv[1, 1] < uv[0, 1])


def label_grid(
    centers: np.ndarray,
    lattice: np.ndarray,
    valid: np.ndarray,
    grid: np.ndarray,
    image_size: tuple[int, int],
    up_axis: Sequence[float] | None = (0.0, 0.0, 1.0),
    anchors: Sequence[tuple[int, int | None, int | None]] = (),
    min_in_range: float = 0.9,
    inlier_px: float = 8.0,
    reject_px: float = 3.0,
) -> Labelling:
    """Assign object indices ``(i, j)`` to lattice-labelled dots.

    Parameters
    ----------
    centers : numpy.ndarray
        Dot centres, (n, 2) [px].
    lattice, valid : numpy.ndarray
        Output of :func:`experiments.stereo.lattice.grid_lattice`.
    grid : numpy.ndarray
        Known object points, shape (ni, nj, 3) [mm] (MultiDIC's ``P3d``).
    image_size : tuple of int
        ``(width, height)`` [px].
    up_axis : sequence of float, optional
        World direction that appears upwards in the image (camera upright);
        ``None`` disables this tie-break.
    anchors : sequence of (int, int or None, int or None)
        ``(dot, i, j)``: detected dot ``dot`` has object row ``i`` and/or
        column ``j`` (``None`` = unknown).
    min_in_range : float
        Smallest fraction of lattice dots a labelling must map inside the grid.
    inlier_px : float
        DLT residual [px] under which a dot counts as fitted (generous: the
        DLT ignores lens distortion).
    reject_px : float
        Largest reprojection error [px] kept after the distortion calibration.

    Raises
    ------
    ValueError
        If no labelling fits, or several fit equally well and the up prior and
        anchors do not decide between them.
    """
    centers = np.asarray(centers, dtype=float)
    idx = np.flatnonzero(valid)
    if idx.size < 6:
        raise ValueError(f"only {idx.size} lattice dots; at least 6 are needed to label a grid")
    ab, pix = lattice[idx], centers[idx]
    cands = _candidates(ab, pix, grid, min_in_range, inlier_px)
    if not cands:
        raise ValueError("no labelling of the lattice onto the object fits a real camera")
    best = max(c.inliers for c in cands)
    if best < 0.5 * idx.size:
        raise ValueError(f"the best labelling explains only {best} of {idx.size} dots")
    tied = [c for c in cands if c.inliers >= best - 2]
    n_equivalent = len(tied)
    if up_axis is not None and len(tied) > 1:
        up = np.asarray(up_axis, dtype=float)
        upright = [c for c in tied if _points_up(c, grid, up / np.linalg.norm(up))]
        tied = upright or tied
    pos = {int(k): r for r, k in enumerate(idx)}
    for dot, ai, aj in anchors:
        if int(dot) not in pos:
            raise ValueError(f"anchor dot {dot} is not on the lattice")
        r = pos[int(dot)]
        tied = [
            c for c in tied if (ai is None or c.ij[r, 0] == ai) and (aj is None or c.ij[r, 1] == aj)
        ]
        if not tied:
            raise ValueError(f"no well-fitting labelling agrees with anchor {(dot, ai, aj)}")
    if len(tied) > 1:
        shifts = sorted({tuple(c.offset) for c in tied})
        raise ValueError(
            f"{len(tied)} labellings fit equally well (offsets {shifts}): the object is "
            "symmetric for this view; give an anchor (e.g. from the printed column numbers)"
        )
    chosen = tied[0]
    ij = np.full((centers.shape[0], 2), -1, dtype=int)
    ij[idx[chosen.in_range]] = chosen.ij[chosen.in_range]
    return verify_labelling(centers, ij, grid, image_size, reject_px, n_equivalent)


def verify_labelling(
    centers: np.ndarray,
    ij: np.ndarray,
    grid: np.ndarray,
    image_size: tuple[int, int],
    reject_px: float = 3.0,
    n_equivalent: int = 1,
) -> Labelling:
    """Calibrate with distortion and drop the worst dot until all reproject within ``reject_px``.

    Parameters
    ----------
    centers : numpy.ndarray
        Dot centres, (n, 2) [px].
    ij : numpy.ndarray
        (n, 2) object indices, ``-1`` for unlabelled; modified in place.
    grid : numpy.ndarray
        Object points (ni, nj, 3) [mm].
    image_size : tuple of int
        ``(width, height)`` [px].
    reject_px : float
        Largest reprojection error kept [px].
    n_equivalent : int
        Passed through to the result.
    """
    ij = np.asarray(ij)
    rejected = 0
    while True:
        lab = np.flatnonzero(ij[:, 0] >= 0)
        cal = calibrate_from_object(grid[ij[lab, 0], ij[lab, 1]], centers[lab], image_size)
        err = np.linalg.norm(cal.residuals, axis=1)
        bad = err > reject_px
        if not np.any(bad):
            return Labelling(ij, cal, n_equivalent, rejected)
        worst = lab[np.argmax(err)]  # one at a time: a gross outlier can bend the fit
        ij[worst] = -1
        rejected += 1
