"""The MultiDIC calibration cylinder: label a view, calibrate, triangulate, hold out.

The object is a white cylinder (radius 57 mm) with a 20 x 14 grid of black
square dots whose 3D positions ``P3d[i, j]`` [mm] are known: ``i`` runs
along the axis (z = 10 ... 238 mm) and ``j`` around it (12.06 degrees per
column). Printed column number ``n`` is taken to be ``P3d[:, n - 1]``; with
the world z axis upwards in the images this puts increasing ``j`` left to
right, as the printed numbers run.

Data: ``../shared/data/multidic-calibration-object`` (MultiDIC toolbox
sample data, Apache-2.0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import scipy.io

from .calibration import (
    DISTORTION_MODELS,
    OBJECT_FLAGS,
    PRINCIPAL_POINT_STD_BOUND_PX,
    ObjectCalibration,
    calibrate_from_object,
    principal_point_spread,
    select_distortion_model,
    spatial_halves,
)
from .cameras import Camera
from .colnumbers import ColumnReading, read_column_numbers
from .dots import Dots, detect_dots, detect_near
from .gridlabel import Labelling, label_grid, verify_labelling
from .lattice import grid_lattice


def load_grid(data_dir: Path) -> np.ndarray:
    """``P3d`` from ``calibrationObjectCoordinates.mat``: shape (20, 14, 3) [mm]."""
    mat = scipy.io.loadmat(Path(data_dir) / "calibrationObjectCoordinates.mat")
    grid = np.asarray(mat["P3d"], dtype=float)
    if grid.ndim != 3 or grid.shape[2] != 3:
        raise ValueError(f"P3d must have shape (ni, nj, 3), got {grid.shape}")
    return grid


def grid_normals(grid: np.ndarray) -> np.ndarray:
    """Unit surface normals at the grid points, (ni, nj, 3), pointing outwards.

    From the grid's own tangents (central differences along i and j,
    second-order one-sided ones on the edges, so the edge normals are not
    tilted by half a grid step); the sign is chosen so the normals point
    away from the centroid of the grid, which lies inside the (convex) object.
    """
    d_i = np.gradient(grid, axis=0, edge_order=2)
    d_j = np.gradient(grid, axis=1, edge_order=2)
    n = np.cross(d_i, d_j)
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    outward = np.einsum("ijk,ijk->ij", n, grid - grid.reshape(-1, 3).mean(axis=0))
    return n if np.mean(outward > 0) >= 0.5 else -n


def visible_mask(camera: Camera, grid: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Dots that face the camera and project inside its image, (ni, nj) bool.

    A dot faces the camera when its outward normal points towards the
    camera centre: ``n . (C - X) > 0``.
    """
    pts = grid.reshape(-1, 3)
    facing = np.einsum("nk,nk->n", normals.reshape(-1, 3), camera.center() - pts) > 0
    in_front = camera.depth(pts) > 0
    inside = camera.in_image(camera.project(pts))
    return (facing & in_front & inside).reshape(grid.shape[:2])


def fully_visible_mask(
    camera: Camera, grid: np.ndarray, normals: np.ndarray, dot_fraction: float
) -> np.ndarray:
    """Dots facing the camera across their whole extent, (ni, nj) bool.

    A stricter reading of :func:`visible_mask`: the facing test must hold at
    the four edge midpoints of the dot, ``dot_fraction / 2`` grid steps from
    its centre along i and j (positions and normals extrapolated with the
    grid's derivatives). A dot whose centre faces the camera but whose far
    half lies past the silhouette fails.
    """
    h = 0.5 * float(dot_fraction)
    ok = visible_mask(camera, grid, normals)
    C = camera.center()
    for axis in (0, 1):
        dX = np.gradient(grid, axis=axis, edge_order=2)
        dn = np.gradient(normals, axis=axis, edge_order=2)
        for sign in (-1.0, 1.0):
            X = grid + sign * h * dX
            n = normals + sign * h * dn
            ok &= np.einsum("ijk,ijk->ij", n, C - X) > 0
    return ok


def estimate_dot_fraction(view: LabelledView, grid: np.ndarray, max_angle: float = 30.0) -> float:
    """Dot side over grid pitch, from the areas of dots seen within ``max_angle`` [deg] of face-on.

    ``side = sqrt(area / cos(angle)) * depth / f`` [mm] per dot (median), over
    the median spacing of neighbouring grid points along j [mm].
    """
    cam = view.camera
    lab = view.labelling.labelled & np.isfinite(view.dots.areas)
    ij = view.labelling.ij[lab]
    X = grid[ij[:, 0], ij[:, 1]]
    n = grid_normals(grid)[ij[:, 0], ij[:, 1]]
    ray = cam.center() - X
    cos = np.einsum("nk,nk->n", n, ray) / np.linalg.norm(ray, axis=1)
    use = cos > np.cos(np.radians(max_angle))
    if not np.any(use):
        raise ValueError("no dot is seen face-on enough to measure its size")
    f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
    side = np.sqrt(view.dots.areas[lab][use] / cos[use]) * cam.depth(X[use]) / f
    pitch = np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2))
    return float(np.median(side) / pitch)


@dataclass(frozen=True)
class LabelledView:
    """One image of the cylinder, its dots and their object indices.

    Attributes
    ----------
    dots : Dots
        All detected dots.
    lattice, valid : numpy.ndarray
        Lattice coordinates from :func:`~experiments.stereo.lattice.grid_lattice`.
    reading : ColumnReading
        The printed-number reading that anchors the columns.
    labelling : Labelling
        Object indices and the camera calibrated from them.
    image_size : tuple of int
        ``(width, height)`` [px].
    """

    dots: Dots
    lattice: np.ndarray
    valid: np.ndarray
    reading: ColumnReading
    labelling: Labelling
    image_size: tuple[int, int]

    def pixel_grid(self, shape: tuple[int, int]) -> np.ndarray:
        """Dot centres arranged as the object grid, (ni, nj, 2) [px]; NaN if unlabelled."""
        out = np.full((*shape, 2), np.nan)
        lab = self.labelling.labelled
        ij = self.labelling.ij[lab]
        out[ij[:, 0], ij[:, 1]] = self.dots.centers[lab]
        return out

    @property
    def camera(self) -> Camera:
        """Camera calibrated on all labelled dots."""
        return self.labelling.calibration.camera


def projected_spacing(
    camera: Camera, grid: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Smallest image distance from each dot to its 4 grid neighbours, (ni, nj) [px].

    With ``mask``, only neighbours where ``mask`` is True count (e.g. the
    visible ones: a hidden neighbour behind the silhouette can project almost
    on top of a visible dot). ``inf`` where no neighbour counts.
    """
    uv = camera.project(grid.reshape(-1, 3)).reshape(*grid.shape[:2], 2)
    ok = np.ones(grid.shape[:2], dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    out = np.full(grid.shape[:2], np.inf)
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(uv, axis=axis), axis=2)
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        d_next = np.where(ok[tuple(hi)], d, np.inf)  # distance to the next dot, if it counts
        d_prev = np.where(ok[tuple(lo)], d, np.inf)  # distance to the previous dot
        pad_lo = [(0, 0)] * 2
        pad_hi = [(0, 0)] * 2
        pad_lo[axis], pad_hi[axis] = (1, 0), (0, 1)
        out = np.fmin(out, np.pad(d_next, pad_hi, constant_values=np.inf))
        out = np.fmin(out, np.pad(d_prev, pad_lo, constant_values=np.inf))
    return out


def label_view(
    image: np.ndarray, grid: np.ndarray, recover: bool = True, select_model: bool = True
) -> LabelledView:
    """Detect, lattice, read the column numbers and label one view of the cylinder.

    With ``recover``, dots that the calibrated camera predicts to face it but
    that were not labelled are looked for near their predicted positions
    (:func:`~experiments.stereo.dots.detect_near`), then the whole labelling
    is re-verified by :func:`~experiments.stereo.gridlabel.verify_labelling`.
    With ``select_model``, the view's camera is recalibrated with the lens model
    that the spatial hold-out chooses (``select_distortion_model``) if it is not the
    default ``OBJECT_FLAGS``.
    """
    h, w = image.shape[:2]
    dots = detect_dots(image)
    lattice, valid = grid_lattice(dots.centers)
    reading = read_column_numbers(image, dots.centers, lattice, valid)
    labelling = label_grid(dots.centers, lattice, valid, grid, (w, h), anchors=[reading.anchor()])
    if recover:
        dots, lattice, valid, labelling = _recover(image, grid, dots, lattice, valid, labelling)
    view = LabelledView(dots, lattice, valid, reading, labelling, (w, h))
    if select_model:
        X, x = view_points(view, grid)
        flags = DISTORTION_MODELS[select_distortion_model(X, x, (w, h))[0]]
        if flags != OBJECT_FLAGS:
            calibration = calibrate_from_object(X, x, (w, h), flags)
            view = replace(view, labelling=replace(labelling, calibration=calibration))
    return view


def view_points(view: LabelledView, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Object points (n, 3) [mm] and pixels (n, 2) [px] of a view's labelled dots."""
    pix = view.pixel_grid(grid.shape[:2])
    have = np.all(np.isfinite(pix), axis=2)
    return grid[have], pix[have]


def calibration_report(view: LabelledView, grid: np.ndarray) -> dict:
    """The lens model chosen by the spatial hold-out, and the principal point's errors.

    ``principal_point_std_px`` is the spatial (block jackknife) standard error
    (``principal_point_spread``), ``principal_point_cov_std_px`` the covariance's, and
    ``principal_point_half_spread_px`` half the difference between the estimates from
    the two ends of the object (``spatial_halves``), which a consistent standard error
    matches. ``warning`` is one line when the spatial error exceeds
    ``PRINCIPAL_POINT_STD_BOUND_PX``, else None.
    """
    X, x = view_points(view, grid)
    size = view.image_size
    name, table = select_distortion_model(X, x, size)
    flags = DISTORTION_MODELS[name]
    cal = calibrate_from_object(X, x, size, flags)
    spread = principal_point_spread(X, x, size, flags)
    ends = spatial_halves(X)[:2]
    centres = [calibrate_from_object(X[~t], x[~t], size, flags).camera.K[:2, 2] for t in ends]
    warning = None
    if spread.max() > PRINCIPAL_POINT_STD_BOUND_PX:
        warning = (
            f"principal point uncertain by ({spread[0]:.0f}, {spread[1]:.0f}) px (bound "
            f"{PRINCIPAL_POINT_STD_BOUND_PX:g} px): give intrinsics from a separate calibration"
        )
    return {
        "model": name,
        "models": table,
        "in_sample_rms_px": cal.rms,
        "principal_point_px": cal.camera.K[:2, 2].tolist(),
        "principal_point_std_px": spread.tolist(),
        "principal_point_cov_std_px": cal.principal_point_std.tolist(),
        "principal_point_half_spread_px": (np.abs(centres[0] - centres[1]) / 2).tolist(),
        "warning": warning,
    }


def _recover(image, grid, dots, lattice, valid, labelling):
    cam = labelling.calibration.camera
    have = np.zeros(grid.shape[:2], dtype=bool)
    lab_ij = labelling.ij[labelling.labelled]
    have[lab_ij[:, 0], lab_ij[:, 1]] = True
    visible = visible_mask(cam, grid, grid_normals(grid))
    want = visible & ~have
    if not np.any(want):
        return dots, lattice, valid, labelling
    spacing = projected_spacing(cam, grid, visible)[want]
    found = detect_near(image, cam.project(grid[want]), np.where(np.isfinite(spacing), spacing, 0))
    ok = np.all(np.isfinite(found), axis=1)
    # Never give one blob two labels: drop finds that sit on an already labelled dot.
    taken = dots.centers[labelling.labelled]
    for m in np.flatnonzero(ok):
        if np.min(np.linalg.norm(taken - found[m], axis=1)) < 0.5 * spacing[m]:
            ok[m] = False
    new_ij = np.argwhere(want)[ok]
    centers = np.vstack([dots.centers, found[ok]])
    areas = np.concatenate([dots.areas, np.full(new_ij.shape[0], np.nan)])
    ij = np.vstack([labelling.ij, new_ij])
    lattice = np.vstack([lattice, np.full((new_ij.shape[0], 2), -1)])
    valid = np.concatenate([valid, np.zeros(new_ij.shape[0], dtype=bool)])
    relabelled = verify_labelling(
        centers, ij, grid, cam.image_size, n_equivalent=labelling.n_equivalent
    )
    rejected = labelling.rejected + relabelled.rejected
    return (
        Dots(centers, areas),
        lattice,
        valid,
        Labelling(relabelled.ij, relabelled.calibration, labelling.n_equivalent, rejected),
    )


def load_view(path: Path, grid: np.ndarray) -> LabelledView:
    """Read an image file and label it (see :func:`label_view`)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"cannot read image {path}")
    return label_view(image, grid)


def calibrate_subset(view: LabelledView, grid: np.ndarray, mask: np.ndarray) -> ObjectCalibration:
    """Calibrate a view's camera from the labelled dots where ``mask[i, j]`` is True."""
    pix = view.pixel_grid(grid.shape[:2])
    use = mask & np.all(np.isfinite(pix), axis=2)
    return calibrate_from_object(grid[use], pix[use], view.image_size)
