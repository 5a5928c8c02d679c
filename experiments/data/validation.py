"""The rules of dataset format v1 (docs/formats-validation.md).

``validate`` checks a ``Dataset`` (or anything with its attributes) and raises
``DatasetError`` at the first problem, with one line naming the key, what is wrong and
how to fix it. Beyond shapes and finiteness it bounds every number to a documented
range, so that no later computation overflows, allocates without limit or runs on
values no tissue has (``LIMITS``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.data.errors import DatasetError, one_line
from experiments.data.experimentkeys import (
    EXPERIMENT_KEYS,
    MAX_PLATE_FORCE_N,
    check_experiment_keys,
    check_force_curve,
    has_other_observations,
    measured_axes,
)

REQUIRED_KEYS = ("outer_rest", "inner_rest", "forces", "contacts", "outer_loaded")
OPTIONAL_KEYS = ("noise_mm", "probe_radius", "times", "outer_series", *EXPERIMENT_KEYS)
KNOWN_KEYS = ("schema", *REQUIRED_KEYS, *OPTIONAL_KEYS)

MIN_FORCE_N = 1e-9
"""Smallest accepted force magnitude of a load case [N]."""
CONTACT_SPACING_FACTOR = 3.0
"""A contact may lie at most this many median marker spacings from the nearest marker."""
MIN_THICKNESS_FACTOR = 1e-3
"""Inner and outer points closer than this many median marker spacings coincide."""

MAX_MARKERS = 40_000
"""Most markers U x V (a 200 x 200 grid)."""
MAX_LOADS = 200
"""Most load cases K."""
MAX_TIMES = 10_000
"""Most time samples T."""
MAX_COORDINATE_MM = 1e4
"""Largest absolute coordinate of any point [mm] (10 m: no tissue is larger)."""
MAX_FORCE_N = 100.0
"""Largest force magnitude of a load case [N] (a probe on soft tissue; 5 N is a lot)."""
MIN_NOISE_MM = 1e-9
"""Smallest non-zero noise_mm [mm]: below it sigma^2 underflows towards zero and every
chi^2 divides by it (0 means the noise is not given)."""
MAX_NOISE_MM = 10.0
"""Largest noise_mm [mm]; plausible values are 1e-4 to 1 mm (a warning outside)."""
MAX_PROBE_RADIUS_MM = 100.0
"""Largest probe radius [mm]."""
MAX_THICKNESS_MM = 300.0
"""Largest median tissue thickness |outer_rest - inner_rest| [mm]."""
MAX_TIME_S = 1e6
"""Largest absolute sample time [s]."""
MAX_RAMP_S = 1e4
"""Longest load rise time ``load_ramp_s`` [s]."""

_NUMERIC_KINDS = "iuf"


def validate(dataset) -> None:
    """Check ``dataset`` against format v1; raise DatasetError at the first problem.

    The rules and thresholds are listed in ``docs/formats.md``. NaN markers in
    ``outer_loaded`` and ``outer_series`` are allowed (marker not seen).
    """
    arrays = _numeric_arrays(dataset)
    _check_extra(dataset.extra)
    _check_shapes(arrays)
    _check_finite(arrays)
    _check_ranges(arrays)
    _check_known_extras(dataset.extra, arrays)
    spacing = _check_rest_geometry(arrays["outer_rest"], arrays["inner_rest"])
    _check_contacts(arrays["contacts"], arrays["outer_rest"], spacing)
    check_experiment_keys(arrays, spacing)
    if "plate_motion" not in arrays:
        _check_forces(arrays["forces"])
    if "markers_loaded" in arrays:  # the measured coordinates (rule 23)
        axes = measured_axes(arrays)
        loaded, rest = arrays["markers_loaded"][..., axes], arrays["markers_rest"][..., axes]
        _check_markers("markers_loaded", loaded, per_load=False)
        _check_displacements(loaded, rest, "markers_loaded")
    _check_markers("outer_loaded", arrays["outer_loaded"], per_load=True, others=arrays)
    _check_displacements(arrays["outer_loaded"], arrays["outer_rest"])
    _check_optional_values(arrays)


def median_marker_spacing(grid: np.ndarray) -> float:
    """Median distance between neighbouring markers of a (U, V, 3) grid [mm]."""
    along_u = np.linalg.norm(np.diff(grid, axis=0), axis=-1)
    along_v = np.linalg.norm(np.diff(grid, axis=1), axis=-1)
    return float(np.median(np.concatenate([along_u.ravel(), along_v.ravel()])))


def _numeric_arrays(dataset) -> dict[str, np.ndarray]:
    """The present format fields as arrays; each must have an integer or float dtype."""
    arrays = {}
    for key in REQUIRED_KEYS + OPTIONAL_KEYS:
        value = getattr(dataset, key)
        if value is None:
            continue
        try:
            array = np.asarray(value)
        except (TypeError, ValueError) as error:
            raise DatasetError(f"not an array ({one_line(error)})", key) from None
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
    if u_count * v_count > MAX_MARKERS or k_count > MAX_LOADS:
        key = "forces" if k_count > MAX_LOADS else "outer_rest"
        raise DatasetError(
            f"{u_count} x {v_count} markers and {k_count} load cases exceed the limits "
            f"({MAX_MARKERS} markers, {MAX_LOADS} load cases); split the dataset",
            key,
        )
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
    if times.ndim != 1 or not 1 <= times.size <= MAX_TIMES:
        raise DatasetError(f"shape {times.shape} is not (T,) with 1 <= T <= {MAX_TIMES}", "times")
    _expect_shape(arrays, "outer_series", (k_count, times.size, *grid), "(K, T, U, V, 3)")


def _expect_shape(arrays: dict[str, np.ndarray], key: str, shape: tuple, meaning: str) -> None:
    """Raise unless ``arrays[key]`` (when present) has exactly ``shape``."""
    if key in arrays and arrays[key].shape != tuple(shape):
        raise DatasetError(
            f"shape {arrays[key].shape} does not match {tuple(shape)} = {meaning}", key
        )


def _check_finite(arrays: dict[str, np.ndarray]) -> None:
    """Everything except the measured markers must be finite."""
    complete = ("outer_rest", "inner_rest", "contacts", "noise_mm", "probe_radius", "times")
    if "plate_motion" not in arrays:  # a plate's force may be unmeasured (NaN)
        complete = (*complete, "forces")
    for key in complete:
        if key not in arrays:
            continue
        bad = int(np.size(arrays[key]) - np.count_nonzero(np.isfinite(arrays[key])))
        if bad:
            raise DatasetError(
                f"{bad} of {np.size(arrays[key])} values are NaN or infinite; "
                f"{key} must be complete (fill or drop the missing entries)",
                key,
            )


def _largest(values: np.ndarray) -> float:
    """The largest absolute finite value (0 for none), without overflow warnings."""
    finite = np.abs(values[np.isfinite(values)])
    return float(finite.max()) if finite.size else 0.0


def _check_ranges(arrays: dict[str, np.ndarray]) -> None:
    """Every number within its documented range (``MAX_*``), before any arithmetic on it."""
    limits = {
        "outer_rest": (MAX_COORDINATE_MM, "mm"),
        "inner_rest": (MAX_COORDINATE_MM, "mm"),
        "contacts": (MAX_COORDINATE_MM, "mm"),
        "outer_loaded": (MAX_COORDINATE_MM, "mm"),
        "outer_series": (MAX_COORDINATE_MM, "mm"),
        "markers_rest": (MAX_COORDINATE_MM, "mm"),
        "markers_loaded": (MAX_COORDINATE_MM, "mm"),
        "plate_motion": (MAX_COORDINATE_MM, "mm"),
        "fixed_plate": (MAX_COORDINATE_MM, "mm"),
        "forces": (MAX_PLATE_FORCE_N if "plate_motion" in arrays else MAX_FORCE_N, "N"),
        "noise_mm": (MAX_NOISE_MM, "mm"),
        "probe_radius": (MAX_PROBE_RADIUS_MM, "mm"),
        "times": (MAX_TIME_S, "s"),
    }
    for key, (limit, unit) in limits.items():
        if key in arrays and _largest(arrays[key].astype(float)) > limit:
            raise DatasetError(
                f"a value of {_largest(arrays[key].astype(float)):.3g} {unit} is beyond the "
                f"limit of {limit:g} {unit}; check the unit ({unit})",
                key,
            )


def _check_known_extras(extra: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """The documented extra keys: ``load_ramp_s``, ``marker_std_mm`` and
    ``plate_force_curve`` (``experimentkeys.check_force_curve``)."""
    check_force_curve(extra, arrays)
    if "load_ramp_s" in extra:
        ramp = np.asarray(extra["load_ramp_s"])
        if ramp.shape != () or ramp.dtype.kind not in _NUMERIC_KINDS:
            raise DatasetError("must be a number (0-d) [s]", "load_ramp_s")
        if not 0.0 <= float(ramp) <= MAX_RAMP_S:
            raise DatasetError(
                f"must lie in [0, {MAX_RAMP_S:g}] s, got {float(ramp)}", "load_ramp_s"
            )
    if "marker_std_mm" in extra:
        std = np.asarray(extra["marker_std_mm"])
        k_count = arrays["forces"].shape[0]
        shape = (k_count + 1, *arrays["outer_rest"].shape[:2])
        if std.shape != shape or std.dtype.kind not in _NUMERIC_KINDS:
            raise DatasetError(f"must be numbers of shape {shape} (K+1, U, V)", "marker_std_mm")
        values = std[np.isfinite(std)]
        if np.isinf(std).any() or (values < 0).any() or _largest(std) > MAX_COORDINATE_MM:
            raise DatasetError("must be >= 0 mm and finite (NaN for not seen)", "marker_std_mm")


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
    if np.median(thickness) > MAX_THICKNESS_MM:
        raise DatasetError(
            f"lies {np.median(thickness):.3g} mm below outer_rest (median); tissue thicker "
            f"than {MAX_THICKNESS_MM:g} mm is refused; check the unit (mm)",
            "inner_rest",
        )
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


def _check_markers(key: str, markers: np.ndarray, per_load: bool, others=None) -> None:
    """Measured markers: NaN for 'not seen' on all three coordinates, never infinite;
    with ``per_load``, each load case observed (by a marker, or by what ``others``,
    the dataset's arrays, observes: ``experimentkeys.has_other_observations``)."""
    if np.isinf(markers).any():
        raise DatasetError("contains infinite values; use NaN for markers not seen", key)
    missing = np.isnan(markers)
    partial = missing.any(axis=-1) & ~missing.all(axis=-1)
    if partial.any():
        index = tuple(int(i) for i in np.argwhere(partial)[0])
        raise DatasetError(
            f"marker {index} is NaN in some coordinates only; set every coordinate to NaN "
            "if not seen",
            key,
        )
    if per_load:
        unseen = missing.all(axis=(1, 2, 3))
        if others is not None:
            unseen &= ~has_other_observations(others)
        if unseen.any():
            k = int(np.argmax(unseen))
            raise DatasetError(
                f"nothing observed in load {k} (all markers NaN, no measured force); "
                "drop that load case",
                key,
            )


def _check_displacements(loaded: np.ndarray, rest: np.ndarray, key="outer_loaded") -> None:
    """No load case moves its seen markers by a median distance larger than the marked
    area across (the diagonal of ``outer_rest``'s bounding box): such markers are not
    the rest markers under a probe (another frame, other units, another grid)."""
    points = rest.reshape(-1, 3)
    across = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    for k, frame in enumerate(loaded):
        moved = np.linalg.norm(frame - rest, axis=-1)
        if not np.isfinite(moved).any():
            continue  # observed otherwise (rule 14)
        median = float(np.nanmedian(moved))
        if median > across:
            raise DatasetError(
                f"load {k} moves its markers by a median {median:.3g} mm, more than the "
                f"marked area's {across:.3g} mm across; give the same markers under the load "
                "in the rest frame, in mm",
                key,
            )


def _check_optional_values(arrays: dict[str, np.ndarray]) -> None:
    """Non-negative noise and probe radii, strictly increasing times, valid series."""
    for key in ("noise_mm", "probe_radius"):
        if key in arrays and (arrays[key] < 0).any():
            raise DatasetError(f"negative value {arrays[key].min():.3g} mm; must be >= 0", key)
    if "noise_mm" in arrays and 0.0 < float(arrays["noise_mm"]) < MIN_NOISE_MM:
        raise DatasetError(
            f"{float(arrays['noise_mm']):.3g} mm is below {MIN_NOISE_MM:g} mm; give the "
            "marker noise in mm (plausible: 1e-4 to 1), or 0 when it is not known",
            "noise_mm",
        )
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
