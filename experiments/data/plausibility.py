"""Warnings for datasets that are valid but physically implausible (one line each).

``experiments.data.dataset.validate`` rejects what cannot be used (shapes, NaN, overlapping
surfaces). What passes may still be wrong in ways only physics tells: a probe that
pulls the skin outward (a sign error, or outer and inner surfaces swapped), forces in
the wrong unit, a tissue hundreds of millimetres thick, a noise level no camera has.
The commands print these lines and record them; they never stop the work.
"""

from __future__ import annotations

import numpy as np

from experiments.data.dataset import Dataset

FORCE_RANGE_N = (1e-3, 5.0)
"""Plausible force of a probe on skin [N] (the paper: 0.17 and 0.25 N)."""

THICKNESS_RANGE_MM = (0.3, 60.0)
"""Plausible thickness of skin and subcutaneous fat [mm] (median over the markers)."""

NOISE_RANGE_MM = (1e-4, 1.0)
"""Plausible standard deviation of a tracked marker coordinate [mm]."""

OUTWARD_COSINE = 0.5
"""A force within 60 degrees of the outer normal pulls the skin outward."""


def outward_normals(dataset: Dataset) -> np.ndarray:
    """Unit vectors from each inner point to its outer marker, (U V, 3) (NaN if coincident)."""
    offset = (dataset.outer_rest - dataset.inner_rest).reshape(-1, 3)
    length = np.linalg.norm(offset, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return offset / length


def force_warnings(dataset: Dataset) -> list[str]:
    """Forces beyond ``FORCE_RANGE_N``, and forces that pull the skin outward."""
    low, high = FORCE_RANGE_N
    normals = outward_normals(dataset)
    markers = dataset.outer_rest.reshape(-1, 3)
    lines = []
    for k, (force, contact) in enumerate(zip(dataset.forces, dataset.contacts)):
        size = float(np.linalg.norm(force))
        if not low <= size <= high:
            lines.append(
                f"load case {k}: |F| = {size:.3g} N lies outside the {low:g}-{high:g} N of a "
                "probe on skin; check the unit (N)"
            )
        nearest = int(np.argmin(np.linalg.norm(markers - contact, axis=1)))
        cosine = float(force @ normals[nearest]) / size if size > 0 else 0.0
        if cosine > OUTWARD_COSINE:
            lines.append(
                f"load case {k}: the force pulls the skin outward (along the outer normal) "
                "while a probe pushes in; check its sign, or whether outer_rest and inner_rest "
                "are swapped"
            )
    return lines


def geometry_warnings(dataset: Dataset) -> list[str]:
    """Tissue thickness and marker noise outside their plausible ranges."""
    lines = []
    thickness = float(np.median(np.linalg.norm(dataset.outer_rest - dataset.inner_rest, axis=-1)))
    low, high = THICKNESS_RANGE_MM
    if not low <= thickness <= high:
        lines.append(
            f"the tissue is {thickness:.3g} mm thick (median of |outer_rest - inner_rest|); "
            f"skin and fat are {low:g}-{high:g} mm; check the unit (mm)"
        )
    low, high = NOISE_RANGE_MM
    if dataset.noise_mm is not None and not low <= dataset.noise_mm <= high:
        lines.append(
            f"noise_mm = {dataset.noise_mm:.3g} mm is outside the {low:g}-{high:g} mm of "
            "tracked markers; the verdict against noise means little"
        )
    return lines


def dataset_warnings(dataset: Dataset) -> list[str]:
    """Every plausibility warning of a dataset, one line each."""
    return force_warnings(dataset) + geometry_warnings(dataset)
