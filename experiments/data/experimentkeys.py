"""The dataset keys of measured experiments other than indentation (docs/formats.md).

Three extensions of format v1, each optional, so that v1 files keep loading:

- markers anywhere in the volume (``markers_rest``, ``markers_loaded``): the Truth
  Cube's beads;
- a rigid plate with prescribed motion as the load (``plate_motion``); ``forces`` is
  then the plate's measured force on the tissue, a row of NaN where none was measured;
- a force-displacement curve as an observation: the load cases of one specimen at
  increasing plate motion, their forces measured (``specimen`` tells the specimens
  apart, ``force_noise_n`` is the force's noise);
- an extensometer: a second plate glued to the outer surface and held fixed
  (``fixed_plate``), the first moved along the surface, markers measured in some
  coordinates only (``markers_axes``: a 2-D DIC sees x and y), the sensor's own record
  of the moving plate's force (the extra key ``plate_force_curve``).

``check_experiment_keys`` applies the rules that only these keys have; the rules they
share with v1 (ranges, NaN markers) are ``experiments.data.validation``'s.
"""

from __future__ import annotations

import numpy as np

from experiments.data.errors import DatasetError

EXPERIMENT_KEYS = (
    "markers_rest",
    "markers_loaded",
    "plate_motion",
    "specimen",
    "force_noise_n",
    "markers_axes",
    "fixed_plate",
)
MAX_PLATE_FORCE_N = 1e4
"""Largest measured plate force [N] (a compression test's load cell; a probe's limit
is ``validation.MAX_FORCE_N``)."""
MAX_FORCE_NOISE_N = 100.0
"""Largest ``force_noise_n`` [N]."""
MAX_INTERIOR_MARKERS = 40_000
"""Most markers N in ``markers_rest``."""
MARKER_MARGIN_FACTOR = 3.0
"""A marker may lie at most this many median outer spacings outside the box of the
volume's two surfaces."""
MAX_CURVE_SAMPLES = 100_000
"""Most samples of ``plate_force_curve``."""


def measured_axes(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """(3,) True for the coordinates of ``markers_loaded`` that are measured
    (``markers_axes``; all three without it)."""
    if "markers_axes" not in arrays:
        return np.ones(3, dtype=bool)
    return np.asarray(arrays["markers_axes"]) == 1


def has_other_observations(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """(K,) True where a load case is observed by something other than the outer
    markers: a seen ``markers_loaded`` marker, or a measured plate force."""
    k_count = arrays["forces"].shape[0]
    seen = np.zeros(k_count, dtype=bool)
    if "markers_loaded" in arrays:
        measured = arrays["markers_loaded"][..., measured_axes(arrays)]
        seen |= np.isfinite(measured).all(axis=-1).any(axis=1)
    if "plate_motion" in arrays:
        seen |= np.isfinite(arrays["forces"]).all(axis=1)
    return seen


def check_experiment_keys(arrays: dict[str, np.ndarray], spacing: float) -> None:
    """The rules of the experiment keys (docs/formats.md, rules 18-23).

    Parameters
    ----------
    arrays : dict
        The dataset's format arrays (shapes of the v1 keys already checked).
    spacing : float
        Median neighbouring spacing of ``outer_rest`` [mm].
    """
    k_count = arrays["forces"].shape[0]
    _check_markers_inside(arrays, k_count, spacing)
    _check_extensometer(arrays, spacing)
    if "plate_motion" in arrays:
        _check_plate(arrays, k_count)
    elif not np.isfinite(arrays["forces"]).all():
        raise DatasetError(
            "has NaN or infinite values; only a plate load (plate_motion) may leave a "
            "force unmeasured",
            "forces",
        )
    if "specimen" in arrays:
        specimen = arrays["specimen"]
        if specimen.shape != (k_count,):
            raise DatasetError(f"shape {specimen.shape} is not (K,) = ({k_count},)", "specimen")
        if not np.isfinite(specimen).all() or (specimen % 1).any() or (specimen < 0).any():
            raise DatasetError("must be whole numbers >= 0, one per load case", "specimen")
    if "force_noise_n" in arrays:
        noise = arrays["force_noise_n"]
        if noise.shape != () or not 0.0 < float(noise) <= MAX_FORCE_NOISE_N:
            raise DatasetError(
                f"must be one number in (0, {MAX_FORCE_NOISE_N:g}] N, the measured force's "
                "standard deviation",
                "force_noise_n",
            )


def _check_markers_inside(arrays: dict[str, np.ndarray], k_count: int, spacing: float) -> None:
    """``markers_rest`` (N, 3) finite and inside the volume's box; ``markers_loaded``
    (K, N, 3) with NaN for not seen, and only together with it."""
    has_rest, has_loaded = "markers_rest" in arrays, "markers_loaded" in arrays
    if has_rest != has_loaded:
        absent = "markers_loaded" if has_rest else "markers_rest"
        raise DatasetError("missing; markers_rest and markers_loaded come together", absent)
    if not has_rest:
        return
    rest, loaded = arrays["markers_rest"], arrays["markers_loaded"]
    if rest.ndim != 2 or rest.shape[1] != 3 or not 1 <= rest.shape[0] <= MAX_INTERIOR_MARKERS:
        raise DatasetError(
            f"shape {rest.shape} is not (N, 3) with 1 <= N <= {MAX_INTERIOR_MARKERS}",
            "markers_rest",
        )
    if loaded.shape != (k_count, *rest.shape):
        raise DatasetError(
            f"shape {loaded.shape} does not match (K, N, 3) = {(k_count, *rest.shape)}",
            "markers_loaded",
        )
    if not np.isfinite(rest).all():
        raise DatasetError("must be finite: every marker has a rest position", "markers_rest")
    surfaces = np.concatenate([arrays["outer_rest"], arrays["inner_rest"]]).reshape(-1, 3)
    margin = MARKER_MARGIN_FACTOR * spacing
    outside = (rest < surfaces.min(axis=0) - margin) | (rest > surfaces.max(axis=0) + margin)
    if outside.any():
        n = int(np.argmax(outside.any(axis=1)))
        raise DatasetError(
            f"marker {n} lies more than {margin:.3g} mm outside the box of outer_rest and "
            "inner_rest; give the markers in the frame and unit (mm) of the surfaces",
            "markers_rest",
        )


def _check_plate(arrays: dict[str, np.ndarray], k_count: int) -> None:
    """``plate_motion`` (K, 3), finite, less than the tissue's thickness; the forces
    either measured (finite) or a row of NaN."""
    motion = arrays["plate_motion"]
    if motion.shape != (k_count, 3):
        raise DatasetError(f"shape {motion.shape} is not (K, 3) = ({k_count}, 3)", "plate_motion")
    if not np.isfinite(motion).all():
        raise DatasetError("must be finite: the plate's motion is prescribed", "plate_motion")
    thickness = float(
        np.median(np.linalg.norm(arrays["outer_rest"] - arrays["inner_rest"], axis=-1))
    )
    limit, what = thickness, "the tissue's thickness"
    if "fixed_plate" in arrays:  # an extensometer pulls along the surface (rule 23)
        gap = np.linalg.norm(arrays["contacts"] - arrays["fixed_plate"], axis=1)
        limit, what = float(gap.min()), "the plates' distance at rest"
    travel = np.linalg.norm(motion, axis=1)
    if travel.max() >= limit:
        k = int(np.argmax(travel))
        raise DatasetError(
            f"load {k} moves the plate {travel[k]:.3g} mm, not less than {what} "
            f"({limit:.3g} mm); give the plate's displacement from rest in mm",
            "plate_motion",
        )
    forces = arrays["forces"]
    partial = np.isnan(forces).any(axis=1) & ~np.isnan(forces).all(axis=1)
    if partial.any() or np.isinf(forces).any():
        raise DatasetError(
            "a plate force is measured (three finite components) or not (three NaN)", "forces"
        )
    if np.abs(forces[np.isfinite(forces)]).max(initial=0.0) > MAX_PLATE_FORCE_N:
        raise DatasetError(
            f"a plate force beyond {MAX_PLATE_FORCE_N:g} N; check the unit (N)", "forces"
        )


def _check_extensometer(arrays: dict[str, np.ndarray], spacing: float) -> None:
    """Rule 23: ``markers_axes`` (3,) of 0 and 1 with ``markers_loaded``, its unmeasured
    coordinates NaN; ``fixed_plate`` (3,) on the outer surface, with ``plate_motion``."""
    if "markers_axes" in arrays:
        axes = arrays["markers_axes"]
        if axes.shape != (3,) or not np.isin(axes, (0, 1)).all() or not axes.any():
            raise DatasetError(
                "must be three 0 or 1, one per coordinate x, y, z, at least one 1 "
                "(e.g. [1, 1, 0]: markers measured in x and y)",
                "markers_axes",
            )
        if "markers_loaded" not in arrays:
            raise DatasetError("needs markers_rest and markers_loaded", "markers_axes")
        unmeasured = arrays["markers_loaded"][..., ~measured_axes(arrays)]
        if not np.isnan(unmeasured).all():
            raise DatasetError(
                "a coordinate that markers_axes marks unmeasured (0) holds a value; set it to NaN",
                "markers_loaded",
            )
    if "fixed_plate" in arrays:
        fixed = arrays["fixed_plate"]
        if fixed.shape != (3,) or not np.isfinite(fixed).all():
            raise DatasetError(f"shape {fixed.shape} is not (3,), or not finite", "fixed_plate")
        if "plate_motion" not in arrays:
            raise DatasetError("needs plate_motion: the plate pulled against it", "fixed_plate")
        markers = arrays["outer_rest"].reshape(-1, 3)
        distance = float(np.linalg.norm(markers - fixed, axis=1).min())
        if distance > MARKER_MARGIN_FACTOR * spacing:
            raise DatasetError(
                f"lies {distance:.3g} mm from the nearest outer_rest point (limit "
                f"{MARKER_MARGIN_FACTOR * spacing:.3g} mm); give it on the outer surface at "
                "rest, in mm",
                "fixed_plate",
            )


def check_force_curve(extra: dict, arrays: dict[str, np.ndarray]) -> None:
    """Rule 23: the extra key ``plate_force_curve`` (M, 2), the plate's displacement along
    x [mm] and its force on the tissue along x [N] at the sensor's own sampling;
    finite, within the coordinate and plate-force limits, with ``plate_motion``."""
    if "plate_force_curve" not in extra:
        return
    curve = np.asarray(extra["plate_force_curve"])
    if curve.dtype.kind not in "iuf" or curve.ndim != 2 or curve.shape[1] != 2:
        raise DatasetError(
            f"must be numbers of shape (M, 2) (displacement mm, force N), got {curve.shape}",
            "plate_force_curve",
        )
    if not 1 <= curve.shape[0] <= MAX_CURVE_SAMPLES or not np.isfinite(curve).all():
        raise DatasetError(
            f"must hold 1 to {MAX_CURVE_SAMPLES} finite samples", "plate_force_curve"
        )
    if "plate_motion" not in arrays:
        raise DatasetError("needs plate_motion: it is that plate's record", "plate_force_curve")
    if np.abs(curve[:, 1]).max() > MAX_PLATE_FORCE_N or np.abs(curve[:, 0]).max() > 1e4:
        raise DatasetError(
            f"a force beyond {MAX_PLATE_FORCE_N:g} N or a displacement beyond 1e4 mm; "
            "check the units (mm, N)",
            "plate_force_curve",
        )
