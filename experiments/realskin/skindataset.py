"""The skin extensometer as a dataset (docs/formats.md, "Measured experiments";
rule 23 of docs/formats-validation.md).

``skin_dataset(case)`` poses a ``SkinCase`` (``experiments.realskin.data``) in the
format, in the case's DIC frame [mm, N]; ``case_from_dataset`` gives the same case back,
array for array (``dvs import extensometer``, ``experiments.realskin.skinimport``, writes
the file and prints ``skin_summary``; ``dvs diagnose`` reads it):

- one load case per DIC frame, frame 0 (the reference, the pads at rest) included;
- the DIC points as ``markers_rest`` (frame 0, z = 0 on the skin) and ``markers_loaded``
  (every frame), measured in x and y only: ``markers_axes`` = [1, 1, 0], z NaN;
- the moving pad as the plate: ``contacts`` its reference point at rest,
  ``plate_motion`` its displacement per frame, ``forces`` its synchronised x force on the
  skin (F_x, 0, 0) [N], NaN beyond the force record; the fixed pad's reference point as
  ``fixed_plate``;
- the extra keys ``plate_force_curve`` (the sensor's record: pad displacement ux [mm],
  force fx [N]), ``geometry_geo`` (the ``geometry.geo`` text: modelled region, pads and
  keloid outline, model frame), ``specimen_names`` (the case's name, ``specimen`` all 0)
  and ``source``;
- the volume: ``outer_rest`` a grid over the modelled region at z = 0, ``inner_rest``
  ``SKIN_THICKNESS_MM`` below it. **Choice**: the measurement gives no thickness; this is
  the study's slab thickness (``RealSkinSettings.thickness_mm``).
"""

from __future__ import annotations

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.errors import DatasetError, one_line
from experiments.realskin.data import SkinCase, dic_to_model_offset
from experiments.realskin.dicnoise import spurious_points
from experiments.realskin.geometry import geometry_from_geo

SKIN_THICKNESS_MM = 2.0
"""Thickness of the slab between ``outer_rest`` and ``inner_rest`` [mm]."""
GRID = 9
"""Points per side of the grids over the modelled region."""
AXES_XY = np.array([1.0, 1.0, 0.0])
"""``markers_axes`` of a 2-D DIC: x and y measured, z not."""
SOURCE = "skin-extensometer (aflahelouneg/inverse_identification_soft_tissue, MIT)"


def _with_z(points: np.ndarray, z: float) -> np.ndarray:
    """(..., 2) points with a third coordinate ``z`` appended, (..., 3)."""
    points = np.asarray(points, dtype=float)
    return np.concatenate([points, np.full((*points.shape[:-1], 1), z)], axis=-1)


def region_grid(case: SkinCase, z: float, points: int = GRID) -> np.ndarray:
    """A (points, points, 3) grid over the modelled region in the DIC frame at height
    ``z`` [mm]."""
    region, offset = case.geometry.region, case.dic_to_model_mm
    x = np.linspace(region.x0, region.x1, points) - offset[0]
    y = np.linspace(region.y0, region.y1, points) - offset[1]
    gx, gy = np.meshgrid(x, y, indexing="ij")
    return np.stack([gx, gy, np.full_like(gx, z)], axis=-1)


def skin_dataset(case: SkinCase) -> Dataset:
    """The case as a dataset (its geometry as ``case.geometry_text``).

    Raises
    ------
    DatasetError
        When the moving pad does not start at the DIC frame's origin (0, 0) or the fixed
        pad moves: the format gives one rest point per pad.
    """
    moving, fixed = case.pad_moving_mm, case.pad_fixed_mm
    if np.any(moving[0] != 0.0):
        raise DatasetError("xt_pad_mov.out: the moving pad must start at (0, 0) (the DIC origin)")
    if not case.geometry_text:
        raise DatasetError("the case has no geometry.geo text; read it with read_case")
    if np.any(fixed != fixed[0]):
        raise DatasetError("xt_pad_fix.out: the fixed pad moves; its rows must be equal")
    k_count = case.n_frames
    force = case.force_at_frame_n
    forces = np.zeros((k_count, 3))
    forces[:, 0] = force
    forces[~np.isfinite(force)] = np.nan
    loaded = _with_z(case.dic_positions_mm, np.nan)
    return Dataset(
        outer_rest=region_grid(case, 0.0),
        inner_rest=region_grid(case, -SKIN_THICKNESS_MM),
        forces=forces,
        contacts=np.tile(_with_z(moving[0], 0.0), (k_count, 1)),
        outer_loaded=np.full((k_count, GRID, GRID, 3), np.nan),
        plate_motion=_with_z(moving - moving[0], 0.0),
        markers_rest=_with_z(case.dic_positions_mm[0], 0.0),
        markers_loaded=loaded,
        markers_axes=AXES_XY.copy(),
        fixed_plate=_with_z(fixed[0], 0.0),
        specimen=np.zeros(k_count, dtype=np.int64),
        extra={
            "plate_force_curve": np.column_stack([case.force_ux_mm, case.force_fx_n]),
            "geometry_geo": np.array(case.geometry_text),
            "specimen_names": np.array([case.name]),
            "source": np.array(f"{SOURCE} {case.name}"),
        },
    )


def skin_summary(case: SkinCase) -> str:
    """One line of what ``skin_dataset`` holds: the case's DIC frames and points (x, y),
    the moving pad's travel [mm], the frames with a force and the force record's
    samples."""
    forced = int(np.isfinite(case.force_at_frame_n).sum())
    return (
        f"{case.name}, {case.n_frames} DIC frames x {case.n_points} points (x, y), pad "
        f"travel {-case.pad_displacement_mm[-1, 0]:.3g} mm, force at {forced} frames, "
        f"force record {len(case.force_ux_mm)} samples"
    )


def case_from_dataset(dataset: Dataset) -> SkinCase:
    """The ``SkinCase`` of a dataset written by ``skin_dataset``.

    Raises
    ------
    DatasetError
        One line for any other dataset (not an extensometer, markers not measured in x
        and y alone, an extra key missing) or a geometry that cannot be read.
    """
    extra = dataset.extra
    needed = ("plate_force_curve", "geometry_geo", "specimen_names")
    axes = dataset.markers_axes
    if (
        dataset.kind != "extensometer"
        or dataset.markers_rest is None
        or axes is None
        or not np.array_equal(axes, AXES_XY)
        or any(key not in extra for key in needed)
    ):
        raise DatasetError(
            "not a skin extensometer dataset (needs fixed_plate, markers measured in x, y "
            f"and the extra keys {', '.join(needed)}); write it with dvs import extensometer"
        )
    positions = np.ascontiguousarray(dataset.markers_loaded[..., :2])
    moving = dataset.contacts[:, :2] + dataset.plate_motion[:, :2]
    fixed = np.tile(dataset.fixed_plate[:2], (dataset.n_loads, 1))
    curve = np.asarray(extra["plate_force_curve"], dtype=float)
    geo = np.asarray(extra["geometry_geo"])
    if geo.shape != () or geo.dtype.kind != "U":
        raise DatasetError("must be the 0-d text of geometry.geo", "geometry_geo")
    text = str(geo.item())
    try:
        geometry = geometry_from_geo(text)
    except (ValueError, KeyError, IndexError, TypeError, SyntaxError) as error:
        raise DatasetError(f"cannot be read ({one_line(error)})", "geometry_geo") from None
    names = np.asarray(extra["specimen_names"])
    if names.dtype.kind != "U" or names.size != 1:
        raise DatasetError("must be the case's name, one string", "specimen_names")
    return SkinCase(
        name=str(names.ravel()[0]),
        dic_positions_mm=positions,
        pad_moving_mm=moving,
        pad_fixed_mm=fixed,
        force_ux_mm=curve[:, 0].copy(),
        force_fx_n=curve[:, 1].copy(),
        force_at_frame_n=dataset.forces[:, 0].copy(),
        geometry=geometry,
        dic_to_model_mm=dic_to_model_offset(moving[0], fixed[0], geometry),
        spurious=spurious_points(positions[0], positions - positions[0]),
        geometry_text=text,
    )
