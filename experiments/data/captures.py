"""A session's captures as one dataset: the presses of several datasets, one rest capture.

In the lab the cameras film the skin once at rest and then once per press. A press
reconstructed on its own (``dvs reconstruct`` on the new images) is a dataset with its
own rest capture and one load case; ``merge_captures`` appends its load cases to the
session's dataset, keeping the session's rest capture (the first dataset's), which
every later press shares (docs/formats.md, "Appending a press").

The rule for the rest captures: a later dataset's rest markers must agree with the
first's to ``REST_TOLERANCE`` noise levels RMS (0.1 mm when no noise level is declared).
A larger difference means the skin moved between the captures (the subject shifted, or
the markers are another grid), and the loads would be measured from the wrong rest
shape: the merge refuses it instead of mixing the two frames.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.validation import DatasetError, validate

REST_TOLERANCE = 5.0
"""Largest RMS difference of two rest captures, in noise levels (chi^2 per marker
coordinate of two independent draws has mean 2 sigma^2: 5 sigma RMS is far beyond
noise)."""
REST_TOLERANCE_MM = 0.1
"""The same when the first dataset declares no noise level [mm]."""


def merge_captures(datasets: list[Dataset], names: list[str] | None = None) -> Dataset:
    """The load cases of ``datasets`` in order, on the first dataset's rest capture.

    Parameters
    ----------
    datasets : list of Dataset
        The session's dataset first, then the presses to append.
    names : list of str, optional
        How errors name each dataset (default ``dataset 1``, ``dataset 2``, ...).

    Returns
    -------
    Dataset
        Rest geometry, noise level, probe shape and extras of the first; forces,
        contacts, loaded markers and probe radii of all, in order; ``marker_std_mm``
        when every dataset has it (the first's rest row, then every load's row).

    Raises
    ------
    DatasetError
        One line: another marker grid, rest markers that moved, a transient (its time
        series cannot be appended), probe radii given for some but not all.
    """
    names = names or [f"dataset {k + 1}" for k in range(len(datasets))]
    first = datasets[0]
    if len(datasets) == 1:
        return first
    tolerance = REST_TOLERANCE * first.noise_mm if first.noise_mm is not None else REST_TOLERANCE_MM
    for dataset, name in zip(datasets, names):
        if dataset.outer_series is not None:
            raise DatasetError(
                f"{name} holds a transient (outer_series); only static captures can be "
                "appended: drop its times and outer_series"
            )
    for dataset, name in zip(datasets[1:], names[1:]):
        if dataset.marker_shape != first.marker_shape:
            raise DatasetError(
                f"{name} has a {dataset.marker_shape[0]}x{dataset.marker_shape[1]} marker grid, "
                f"{names[0]} {first.marker_shape[0]}x{first.marker_shape[1]}: append captures "
                "of the same markers"
            )
        moved = float(np.sqrt(np.mean((dataset.outer_rest - first.outer_rest) ** 2)))
        if moved > tolerance:
            raise DatasetError(
                f"{name}'s rest markers differ from {names[0]}'s by {moved:.3g} mm RMS "
                f"(at most {tolerance:.3g} mm): the skin moved between the captures; "
                "register the new capture to the session's rest frame first"
            )
    radii = [d.probe_radius for d in datasets]
    if any(r is None for r in radii) and not all(r is None for r in radii):
        missing = names[[r is None for r in radii].index(True)]
        raise DatasetError(
            f"{missing} declares no probe_radius while others do: give every press its "
            "probe radius (0 for a point force)"
        )
    merged = replace(
        first,
        forces=np.concatenate([d.forces for d in datasets]),
        contacts=np.concatenate([d.contacts for d in datasets]),
        outer_loaded=np.concatenate([d.outer_loaded for d in datasets]),
        probe_radius=None if radii[0] is None else np.concatenate(radii),
        extra=_merged_extra(datasets),
    )
    validate(merged)
    return merged


def _merged_extra(datasets: list[Dataset]) -> dict:
    """The first dataset's extras; ``marker_std_mm`` (K+1, U, V) rebuilt over every load
    when all have it, dropped otherwise."""
    extra = dict(datasets[0].extra)
    stds = [d.extra.get("marker_std_mm") for d in datasets]
    extra.pop("marker_std_mm", None)
    if all(s is not None for s in stds):
        rows = [np.asarray(stds[0])[:1]] + [np.asarray(s)[1:] for s in stds]
        extra["marker_std_mm"] = np.concatenate(rows)
    return extra
