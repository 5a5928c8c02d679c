"""Held-out checks of a calibration on the MultiDIC calibration object: views and regions
left out of the calibration, their reprojection and 3D errors (docs/stereo.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.stereo.multidic import LabelledView, calibrate_subset

from .calibration import (
    OBJECT_FLAGS,
    calibrate_from_object,
    spatial_blocks,
    spatial_halves,
)
from .cameras import Camera
from .triangulation import Triangulation, triangulate


@dataclass(frozen=True)
class StereoCheck:
    """Triangulated dots seen by two cameras, compared with ``P3d``.

    Attributes
    ----------
    mask : numpy.ndarray
        (ni, nj) dots triangulated (labelled in both views, inside ``eval_mask``).
    triangulation : Triangulation
        Their triangulation.
    errors : numpy.ndarray
        Triangulated minus true position, (n, 3) [mm].
    rms : float
        RMS 3D error [mm].
    """

    mask: np.ndarray
    triangulation: Triangulation
    errors: np.ndarray
    rms: float


def stereo_check(
    views: tuple[LabelledView, LabelledView],
    cameras: tuple[Camera, Camera],
    grid: np.ndarray,
    eval_mask: np.ndarray | None = None,
) -> StereoCheck:
    """Triangulate the dots both views labelled and compare them with ``P3d``."""
    shape = grid.shape[:2]
    pix = [v.pixel_grid(shape) for v in views]
    both = np.all(np.isfinite(pix[0]), axis=2) & np.all(np.isfinite(pix[1]), axis=2)
    if eval_mask is not None:
        both &= eval_mask
    tri = triangulate(list(cameras), [p[both] for p in pix])
    err = tri.points - grid[both]
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    return StereoCheck(both, tri, err, rms)


def spatial_holdout_check(
    views: tuple[LabelledView, LabelledView], grid: np.ndarray, flags=(OBJECT_FLAGS, OBJECT_FLAGS)
) -> dict:
    """3D error of dots whose neighbourhood the calibration did not see [mm].

    ``ends_rms``: calibrate both cameras on one end of the object (``spatial_halves``
    along its longest axis), triangulate the other, and the reverse (extrapolation).
    ``blocks_rms``: leave out one of the 12 ``spatial_blocks`` at a time (interpolation
    within the calibrated volume, as a calibration is used). ``n`` dots each.
    ``flags`` are the two cameras' lens models.
    """
    shape = grid.shape[:2]
    pix = [v.pixel_grid(shape) for v in views]
    both = np.all(np.isfinite(pix[0]), axis=2) & np.all(np.isfinite(pix[1]), axis=2)
    X = grid[both]
    ends = spatial_halves(X)[:2]
    blocks = spatial_blocks(X)
    out = {}
    for name, folds in (("ends", ends), ("blocks", [blocks == b for b in np.unique(blocks)])):
        errors = []
        for test in folds:
            mask = np.zeros(shape, dtype=bool)
            held = np.argwhere(both)[test]
            mask[held[:, 0], held[:, 1]] = True
            train = both & ~mask
            cameras = tuple(
                calibrate_from_object(grid[train], p[train], v.image_size, f).camera
                for p, v, f in zip(pix, views, flags)
            )
            errors.append(stereo_check(views, cameras, grid, eval_mask=mask).errors)
        every = np.concatenate(errors)
        out[f"{name}_rms"] = float(np.sqrt(np.mean(np.sum(every**2, axis=1))))
    out["n"] = int(both.sum())
    return out


def holdout_check(views: tuple[LabelledView, LabelledView], grid: np.ndarray) -> dict:
    """Calibrate on one checkerboard half of the dots, triangulate the other half.

    The halves interleave, so every held-out dot has calibrated neighbours: this is
    nearly an in-sample figure (``spatial_holdout_check`` is the honest one).

    Returns
    -------
    dict
        ``rms`` [mm] over both folds, ``fold_rms`` [mm] per fold, ``n`` dots
        evaluated, and ``reproj_rms`` [px]: reprojection error of the held-out
        dots under the half-calibrated cameras.
    """
    ii, jj = np.indices(grid.shape[:2])
    even = (ii + jj) % 2 == 0
    sq, n, folds, rep = 0.0, 0, [], []
    for train in (even, ~even):
        cams = tuple(calibrate_subset(v, grid, train).camera for v in views)
        check = stereo_check(views, cams, grid, eval_mask=~train)
        sq += float(np.sum(check.errors**2))
        n += check.errors.shape[0]
        folds.append(check.rms)
        for v, cam in zip(views, cams):
            pix = v.pixel_grid(grid.shape[:2])
            test = ~train & np.all(np.isfinite(pix), axis=2)
            rep.append(pix[test] - cam.project(grid[test]))
    r = np.concatenate(rep)
    return {
        "rms": float(np.sqrt(sq / n)),
        "fold_rms": folds,
        "n": n,
        "reproj_rms": float(np.sqrt(np.mean(np.sum(r**2, axis=1)))),
    }
