"""Dataset format v1 (``dvs-dataset/1``): load, validate and save ``.npz`` files.

A dataset holds the rest geometry of the tissue block (outer marker grid and inner
surface grid, in correspondence), the load cases (force vector and contact point) and
the measured marker positions under each load. Units are mm, N and s throughout.
The format and every validation rule are documented in ``docs/formats.md``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from experiments.data.archive import ArchiveError, read_npz
from experiments.data.validation import (
    KNOWN_KEYS,
    OPTIONAL_KEYS,
    REQUIRED_KEYS,
    DatasetError,
    validate,
)
from experiments.output.atomic import atomic_save_npz

SCHEMA = "dvs-dataset/1"


@dataclass
class Dataset:
    """Measured deformation of a tissue block under K load cases (format v1).

    Marker grids have U x V markers; all lengths are in mm, forces in N, times in s.
    """

    outer_rest: np.ndarray
    """(U, V, 3) marker positions on the skin, unloaded [mm]."""
    inner_rest: np.ndarray
    """(U, V, 3) inner surface grid, in correspondence with ``outer_rest`` [mm]."""
    forces: np.ndarray
    """(K, 3) force vector of each load case [N]."""
    contacts: np.ndarray
    """(K, 3) point of application of each force on the outer surface at rest [mm]."""
    outer_loaded: np.ndarray
    """(K, U, V, 3) measured marker positions under each load [mm]; NaN = not seen."""
    noise_mm: float | None = None
    """Standard deviation of the marker measurement [mm], if known."""
    probe_radius: np.ndarray | None = None
    """(K,) probe radius of each load case [mm]; 0 = point force."""
    probe_shape: str | None = None
    """The probe patch's shape the model assumes (``symbolic.loads.PROBE_SHAPES``); None:
    Gaussian. Not stored in the ``.npz``: step 0 of the loop estimates it."""
    times: np.ndarray | None = None
    """(T,) sample times of the transient, strictly increasing [s]."""
    outer_series: np.ndarray | None = None
    """(K, T, U, V, 3) marker trajectories during the transient [mm]; NaN = not seen."""
    markers_rest: np.ndarray | None = None
    """(N, 3) markers anywhere in the volume, e.g. beads inside it, unloaded [mm]."""
    markers_loaded: np.ndarray | None = None
    """(K, N, 3) measured positions of ``markers_rest`` under each load [mm]; NaN = not seen."""
    plate_motion: np.ndarray | None = None
    """(K, 3) prescribed displacement of a rigid plate on the outer surface [mm]; with it,
    ``forces`` is the plate's measured force on the tissue, NaN where not measured."""
    specimen: np.ndarray | None = None
    """(K,) which specimen (or series) each load case was measured on, integers from 0."""
    force_noise_n: float | None = None
    """Standard deviation of a measured force [N], if known."""
    markers_axes: np.ndarray | None = None
    """(3,) 1 for each coordinate x, y, z that ``markers_loaded`` measures, 0 for one it
    does not (NaN there); None: all three (e.g. [1, 1, 0] for a 2-D DIC)."""
    fixed_plate: np.ndarray | None = None
    """(3,) rest reference point of a second plate glued to the outer surface and held
    fixed [mm]: an extensometer, ``plate_motion`` moving the other along the surface."""
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    """Unknown keys of the file, kept as they are and written back on save."""

    @property
    def n_loads(self) -> int:
        """Number of load cases K."""
        return int(np.shape(self.forces)[0])

    @property
    def marker_shape(self) -> tuple[int, int]:
        """Marker grid size (U, V)."""
        u_count, v_count = np.shape(self.outer_rest)[:2]
        return int(u_count), int(v_count)

    @property
    def kind(self) -> str:
        """ "indentation" (forces at contacts, markers on the skin), "plate" (a
        displacement-controlled plate, ``plate_motion``) or "extensometer" (that plate
        pulled along the skin against a fixed one, ``fixed_plate``)."""
        if self.plate_motion is None:
            return "indentation"
        return "plate" if self.fixed_plate is None else "extensometer"

    @property
    def observed_mask(self) -> np.ndarray:
        """(K, U, V) boolean: True where the marker was seen under load (all coordinates finite)."""
        return np.isfinite(np.asarray(self.outer_loaded)).all(axis=-1)


# ----------------------------------------------------------------------------- file I/O


def load_dataset(path: str | os.PathLike) -> Dataset:
    """Read and validate a ``dvs-dataset/1`` ``.npz`` file (never unpickles).

    Raises
    ------
    DatasetError
        One line naming the file, the offending key and the fix.
    """
    source = Path(path)
    try:
        return from_arrays(_read_npz(source))
    except DatasetError as error:
        raise error.in_file(source) from None


def save_dataset(path: str | os.PathLike, dataset: Dataset) -> Path:
    """Validate ``dataset`` and write it atomically to ``path`` (exactly that name).

    Raises
    ------
    DatasetError
        If the dataset is invalid; nothing is written then.
    """
    validate(dataset)
    return atomic_save_npz(path, **to_arrays(dataset))


def _read_npz(source: Path) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` archive, read safely (``experiments.data.archive``)."""
    try:
        return read_npz(source)
    except ArchiveError as error:
        raise DatasetError(str(error), error.member) from None


# ----------------------------------------------------------------- arrays <-> Dataset


def to_arrays(dataset: Dataset) -> dict[str, np.ndarray]:
    """The named arrays of the ``.npz`` file, ``schema`` first (no validation)."""
    arrays = {"schema": np.array(SCHEMA)}
    for key in REQUIRED_KEYS + OPTIONAL_KEYS:
        value = getattr(dataset, key)
        if value is not None:
            kind = np.int64 if key == "specimen" else np.float64
            arrays[key] = np.asarray(value, dtype=kind)
    arrays.update({key: np.asarray(value) for key, value in dataset.extra.items()})
    return arrays


def from_arrays(arrays: dict[str, np.ndarray]) -> Dataset:
    """Build and validate a Dataset from the named arrays of a ``.npz`` file.

    Arrays are converted to float64 after validation; keys that are not part of the
    format are kept in ``Dataset.extra``.
    """
    _check_schema(arrays)
    missing = [key for key in REQUIRED_KEYS if key not in arrays]
    if missing:
        others = f" (so are {', '.join(missing[1:])})" if len(missing) > 1 else ""
        raise DatasetError(
            f"required key missing{others}; a dataset needs {', '.join(REQUIRED_KEYS)}",
            missing[0],
        )
    known = {key: arrays[key] for key in REQUIRED_KEYS + OPTIONAL_KEYS if key in arrays}
    extra = {key: value for key, value in arrays.items() if key not in KNOWN_KEYS}
    dataset = Dataset(**known, extra=extra)
    validate(dataset)
    return _as_float(dataset)


def require_indentation(dataset: Dataset, command: str) -> Dataset:
    """``dataset`` when it is an indentation experiment; else a one-line DatasetError.

    The commands that model a probe (fit, diagnose, image, design, next) read neither
    a plate nor markers inside the volume: on such data they would fit the wrong
    experiment without a word.
    """
    if dataset.plate_motion is not None or dataset.markers_rest is not None:
        what = {
            "plate": "a plate load (plate_motion)",
            "extensometer": "two pads pulling along the skin (plate_motion, fixed_plate)",
        }.get(dataset.kind, "markers inside the volume (markers_rest)")
        raise DatasetError(
            f"the dataset has {what}, which {command} does not model (it models probe "
            "indentation); run that experiment's study (docs/experiments.md)"
        )
    return dataset


def _check_schema(arrays: dict[str, np.ndarray]) -> None:
    """``schema`` must be the 0-d string ``"dvs-dataset/1"``."""
    if "schema" not in arrays:
        raise DatasetError(f"key missing; add schema = numpy.array({SCHEMA!r})", "schema")
    schema = arrays["schema"]
    if schema.shape != () or schema.dtype.kind not in "US":
        raise DatasetError(
            f"must be a 0-d string array, got dtype {schema.dtype} shape {schema.shape}; "
            f"use numpy.array({SCHEMA!r})",
            "schema",
        )
    text = schema.item().decode() if schema.dtype.kind == "S" else str(schema.item())
    if text != SCHEMA:
        raise DatasetError(f"is {text!r}, but this reader understands only {SCHEMA!r}", "schema")


def _as_float(dataset: Dataset) -> Dataset:
    """The dataset with float64 arrays and a float ``noise_mm`` (after validation)."""
    values: dict[str, Any] = {}
    for key in REQUIRED_KEYS + OPTIONAL_KEYS:
        value = getattr(dataset, key)
        if value is not None:
            values[key] = np.asarray(value, dtype=np.float64)
    for key in ("noise_mm", "force_noise_n"):
        if getattr(dataset, key) is not None:
            values[key] = float(np.asarray(getattr(dataset, key)))
    if dataset.specimen is not None:
        values["specimen"] = np.asarray(dataset.specimen).astype(np.int64)
    return replace(dataset, **values)
