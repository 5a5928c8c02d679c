"""Dataset format v1 (``dvs-dataset/1``): load, validate and save ``.npz`` files.

A dataset holds the rest geometry of the tissue block (outer marker grid and inner
surface grid, in correspondence), the load cases (force vector and contact point) and
the measured marker positions under each load. Units are mm, N and s throughout.
The format and every validation rule are documented in ``docs/formats.md``.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from experiments.atomic import atomic_save_npz

SCHEMA = "dvs-dataset/1"
REQUIRED_KEYS = ("outer_rest", "inner_rest", "forces", "contacts", "outer_loaded")
OPTIONAL_KEYS = ("noise_mm", "probe_radius", "times", "outer_series")
KNOWN_KEYS = ("schema", *REQUIRED_KEYS, *OPTIONAL_KEYS)

MIN_FORCE_N = 1e-9
"""Smallest accepted force magnitude of a load case [N]."""
CONTACT_SPACING_FACTOR = 3.0
"""A contact may lie at most this many median marker spacings from the nearest marker."""
MIN_THICKNESS_FACTOR = 1e-3
"""Inner and outer points closer than this many median marker spacings coincide."""

_NUMERIC_KINDS = "iuf"


class DatasetError(ValueError):
    """A dataset file or object breaks format v1; the message is one line with the fix.

    Attributes
    ----------
    key : str or None
        The offending key (``None`` for problems with the file itself).
    """

    def __init__(self, message: str, key: str | None = None) -> None:
        text = " ".join(str(message).split())
        super().__init__(f"{key}: {text}" if key is not None else text)
        self.key = key

    def in_file(self, path: str | os.PathLike) -> DatasetError:
        """The same error with the file name in front of the message."""
        error = DatasetError(f"{os.fspath(path)}: {self}")
        error.key = self.key
        return error


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
    times: np.ndarray | None = None
    """(T,) sample times of the transient, strictly increasing [s]."""
    outer_series: np.ndarray | None = None
    """(K, T, U, V, 3) marker trajectories during the transient [mm]; NaN = not seen."""
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
    """All arrays of an ``.npz`` archive, read with ``allow_pickle=False``."""
    if not source.exists():
        raise DatasetError("file not found; check the path to the dataset (.npz)")
    if source.is_dir():
        raise DatasetError("is a directory, not a dataset file (.npz)")
    try:
        archive = np.load(source, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise DatasetError(
            f"not a readable .npz archive ({_one_line(error)}); "
            "write datasets with experiments.dataset.save_dataset"
        ) from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise DatasetError("holds a single .npy array, not an .npz archive of named arrays")
    with archive:
        return {key: _read_member(archive, key) for key in archive.files}


def _read_member(archive: Any, key: str) -> np.ndarray:
    """One array of an open archive; pickled or damaged members raise DatasetError."""
    try:
        return archive[key]
    except ValueError as error:
        raise DatasetError(
            f"cannot be read without pickle ({_one_line(error)}); store it as a numeric array",
            key,
        ) from None
    except (OSError, EOFError, zipfile.BadZipFile) as error:
        raise DatasetError(
            f"damaged in the archive ({_one_line(error)}); write the file again", key
        ) from None


def _one_line(error: BaseException) -> str:
    """Exception text squeezed onto one line."""
    return " ".join(str(error).split()) or type(error).__name__


# ----------------------------------------------------------------- arrays <-> Dataset


def to_arrays(dataset: Dataset) -> dict[str, np.ndarray]:
    """The named arrays of the ``.npz`` file, ``schema`` first (no validation)."""
    arrays = {"schema": np.array(SCHEMA)}
    for key in REQUIRED_KEYS + OPTIONAL_KEYS:
        value = getattr(dataset, key)
        if value is not None:
            arrays[key] = np.asarray(value, dtype=np.float64)
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
    if dataset.noise_mm is not None:
        values["noise_mm"] = float(np.asarray(dataset.noise_mm))
    return replace(dataset, **values)


# --------------------------------------------------------------------------- validation


def validate(dataset: Dataset) -> None:
    """Check ``dataset`` against format v1; raise DatasetError at the first problem.

    The rules and thresholds are listed in ``docs/formats.md``. NaN markers in
    ``outer_loaded`` and ``outer_series`` are allowed (marker not seen).
    """
    arrays = _numeric_arrays(dataset)
    _check_extra(dataset.extra)
    _check_shapes(arrays)
    _check_finite(arrays)
    spacing = _check_rest_geometry(arrays["outer_rest"], arrays["inner_rest"])
    _check_contacts(arrays["contacts"], arrays["outer_rest"], spacing)
    _check_forces(arrays["forces"])
    _check_markers("outer_loaded", arrays["outer_loaded"], per_load=True)
    _check_optional_values(arrays)


def median_marker_spacing(grid: np.ndarray) -> float:
    """Median distance between neighbouring markers of a (U, V, 3) grid [mm]."""
    along_u = np.linalg.norm(np.diff(grid, axis=0), axis=-1)
    along_v = np.linalg.norm(np.diff(grid, axis=1), axis=-1)
    return float(np.median(np.concatenate([along_u.ravel(), along_v.ravel()])))


def _numeric_arrays(dataset: Dataset) -> dict[str, np.ndarray]:
    """The present format fields as arrays; each must have an integer or float dtype."""
    arrays = {}
    for key in REQUIRED_KEYS + OPTIONAL_KEYS:
        value = getattr(dataset, key)
        if value is None:
            continue
        try:
            array = np.asarray(value)
        except (TypeError, ValueError) as error:
            raise DatasetError(f"not an array ({_one_line(error)})", key) from None
        if array.dtype.kind not in _NUMERIC_KINDS:
            raise DatasetError(
                f"dtype {array.dtype} is not numeric; store {key} as floating-point numbers", key
            )
        arrays[key] = array
    return arrays


def _check_extra(extra: dict[str, Any]) -> None:
    """Unknown keys are kept but must be storable without pickle and not shadow known keys."""
    for key, value in extra.items():
        if not isinstance(key, str) or not key or key in KNOWN_KEYS:
            raise DatasetError(
                f"extra key {key!r} is empty, not a string or a format key; rename it", str(key)
            )
        if np.asarray(value).dtype.kind == "O":
            raise DatasetError("object dtype needs pickle; store a numeric or string array", key)


def _check_shapes(arrays: dict[str, np.ndarray]) -> None:
    """Shapes of every field, with U, V, K (and T) consistent between them."""
    outer = arrays["outer_rest"]
    if outer.ndim != 3 or outer.shape[2] != 3 or min(outer.shape[:2]) < 2:
        raise DatasetError(
            f"shape {outer.shape} is not (U, V, 3) with U, V >= 2; "
            "store the marker grid as a U x V x 3 array",
            "outer_rest",
        )
    forces = arrays["forces"]
    if forces.ndim != 2 or forces.shape[1] != 3 or forces.shape[0] < 1:
        raise DatasetError(f"shape {forces.shape} is not (K, 3) with K >= 1", "forces")
    (u_count, v_count), k_count = outer.shape[:2], forces.shape[0]
    _expect_shape(arrays, "inner_rest", outer.shape, "(U, V, 3) as outer_rest")
    _expect_shape(arrays, "contacts", (k_count, 3), "(K, 3) with K from forces")
    grid = (u_count, v_count, 3)
    _expect_shape(arrays, "outer_loaded", (k_count, *grid), "(K, U, V, 3)")
    _expect_shape(arrays, "noise_mm", (), "a scalar (0-d)")
    _expect_shape(arrays, "probe_radius", (k_count,), "(K,) with K from forces")
    _check_series_shapes(arrays, k_count, grid)


def _check_series_shapes(arrays: dict[str, np.ndarray], k_count: int, grid: tuple) -> None:
    """``times`` and ``outer_series`` come together with matching T."""
    has_times, has_series = "times" in arrays, "outer_series" in arrays
    if has_times != has_series:
        present, absent = ("times", "outer_series") if has_times else ("outer_series", "times")
        raise DatasetError(f"missing although {present} is given; store both or neither", absent)
    if not has_times:
        return
    times = arrays["times"]
    if times.ndim != 1 or times.size < 1:
        raise DatasetError(f"shape {times.shape} is not (T,) with T >= 1", "times")
    _expect_shape(arrays, "outer_series", (k_count, times.size, *grid), "(K, T, U, V, 3)")


def _expect_shape(arrays: dict[str, np.ndarray], key: str, shape: tuple, meaning: str) -> None:
    """Raise unless ``arrays[key]`` (when present) has exactly ``shape``."""
    if key in arrays and arrays[key].shape != tuple(shape):
        raise DatasetError(
            f"shape {arrays[key].shape} does not match {tuple(shape)} = {meaning}", key
        )


def _check_finite(arrays: dict[str, np.ndarray]) -> None:
    """Everything except the measured markers must be finite."""
    complete = ("outer_rest", "inner_rest", "forces", "contacts", "noise_mm", "probe_radius")
    for key in (*complete, "times"):
        if key not in arrays:
            continue
        bad = int(np.size(arrays[key]) - np.count_nonzero(np.isfinite(arrays[key])))
        if bad:
            raise DatasetError(
                f"{bad} of {np.size(arrays[key])} values are NaN or infinite; "
                f"{key} must be complete (fill or drop the missing entries)",
                key,
            )


def _check_rest_geometry(outer: np.ndarray, inner: np.ndarray) -> float:
    """Non-degenerate outer grid; inner surface neither touching nor crossing it.

    Returns
    -------
    float
        Median neighbouring marker spacing of ``outer_rest`` [mm].
    """
    spacing = median_marker_spacing(outer)
    if not spacing > 0.0:
        raise DatasetError("markers coincide (median spacing 0 mm); check the grid", "outer_rest")
    offset = outer - inner
    thickness = np.linalg.norm(offset, axis=-1)
    minimum = MIN_THICKNESS_FACTOR * spacing
    if thickness.min() < minimum:
        u, v = np.unravel_index(np.argmin(thickness), thickness.shape)
        raise DatasetError(
            f"coincides with outer_rest at marker ({u}, {v}): thickness "
            f"{thickness.min():.3g} mm < {minimum:.3g} mm; the tissue needs a thickness",
            "inner_rest",
        )
    normal = np.cross(np.gradient(outer, axis=0), np.gradient(outer, axis=1))
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), np.finfo(float).tiny)
    side = np.einsum("uvi,uvi->uv", offset, normal)
    if side.min() < -minimum and side.max() > minimum:
        crossing = int(min(np.count_nonzero(side < 0), np.count_nonzero(side > 0)))
        raise DatasetError(
            f"crosses outer_rest: {crossing} of {side.size} markers lie on the other side "
            "of the outer surface; inner_rest must lie entirely beneath the skin",
            "inner_rest",
        )
    return spacing


def _check_contacts(contacts: np.ndarray, outer: np.ndarray, spacing: float) -> None:
    """Each contact lies within CONTACT_SPACING_FACTOR spacings of an outer marker."""
    markers = outer.reshape(-1, 3)
    distance = np.linalg.norm(contacts[:, None, :] - markers[None, :, :], axis=-1).min(axis=1)
    limit = CONTACT_SPACING_FACTOR * spacing
    if distance.max() > limit:
        k = int(np.argmax(distance))
        raise DatasetError(
            f"contact of load {k} is {distance[k]:.3g} mm from the nearest outer_rest marker "
            f"(limit {limit:.3g} mm = {CONTACT_SPACING_FACTOR:g} x median spacing); "
            "give the contact point on the outer surface at rest",
            "contacts",
        )


def _check_forces(forces: np.ndarray) -> None:
    """Every load case has a force of at least MIN_FORCE_N."""
    magnitude = np.linalg.norm(forces, axis=1)
    if magnitude.min() < MIN_FORCE_N:
        k = int(np.argmin(magnitude))
        raise DatasetError(
            f"load {k} has force magnitude {magnitude[k]:.3g} N < {MIN_FORCE_N:g} N; "
            "drop that load case or give its force in N",
            "forces",
        )


def _check_markers(key: str, markers: np.ndarray, per_load: bool) -> None:
    """Measured markers: NaN for 'not seen' on all three coordinates, never infinite."""
    if np.isinf(markers).any():
        raise DatasetError("contains infinite values; use NaN for markers not seen", key)
    missing = np.isnan(markers)
    partial = missing.any(axis=-1) & ~missing.all(axis=-1)
    if partial.any():
        index = tuple(int(i) for i in np.argwhere(partial)[0])
        raise DatasetError(
            f"marker {index} is NaN in some coordinates only; set all three to NaN if not seen",
            key,
        )
    if per_load:
        unseen = missing.all(axis=(1, 2, 3))
        if unseen.any():
            k = int(np.argmax(unseen))
            raise DatasetError(
                f"no marker observed in load {k} (all NaN); drop that load case", key
            )


def _check_optional_values(arrays: dict[str, np.ndarray]) -> None:
    """Non-negative noise and probe radii, strictly increasing times, valid series."""
    for key in ("noise_mm", "probe_radius"):
        if key in arrays and (arrays[key] < 0).any():
            raise DatasetError(f"negative value {arrays[key].min():.3g} mm; must be >= 0", key)
    if "times" in arrays:
        steps = np.diff(arrays["times"])
        if (steps <= 0).any():
            i = int(np.argmax(steps <= 0))
            raise DatasetError(
                f"not strictly increasing at index {i + 1} (step {steps[i]:.3g} s); "
                "sort the samples and remove duplicates",
                "times",
            )
        _check_markers("outer_series", arrays["outer_series"], per_load=False)
