"""Which effects a dataset's design can separate from alpha, as measured.

The diagnosis can only find what the experiment lets it see. On the paper's design
(loads at one contact, along the normal) the cases are nearly proportional and a
refit of alpha absorbs four physical effects; on the diagnosis design (five contacts,
a tilted load) only ``base_compliance`` stays hidden (docs/diagnosis.md, "The
experiment design of the diagnosis"; docs/results/diagnosis-phantom.md; ``dvs study
diagnosis --design paper`` and ``dvs study diagnosis``). ``design_note`` reads a
dataset's contacts and force directions and says which of these limits applies.
"""

from __future__ import annotations

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.plausibility import outward_normals
from experiments.data.validation import median_marker_spacing
from symbolic.effects.library import effect_library

HIDDEN_ANYWHERE = ("base_compliance",)
"""Effects not selected on any design tried (absorbed by alpha_w)."""

HIDDEN_ON_ONE_CONTACT = ("heterogeneity", "bending", "pre_tension", *HIDDEN_ANYWHERE)
"""Effects not selected first with loads at one contact along the normal (seed 1)."""

TILT_DEG = 10.0
"""A load more than this far from the inward normal (at the nearest marker) is tilted [deg]."""


def design_summary(dataset: Dataset) -> dict:
    """Loads, distinct contacts (a marker spacing apart) and tilted loads of a dataset."""
    spacing = median_marker_spacing(dataset.outer_rest)
    distinct: list[np.ndarray] = []
    for contact in dataset.contacts:
        if all(np.linalg.norm(contact - c) > spacing for c in distinct):
            distinct.append(contact)
    normals = outward_normals(dataset)
    markers = dataset.outer_rest.reshape(-1, 3)
    tilted = 0
    for force, contact in zip(dataset.forces, dataset.contacts):
        normal = normals[int(np.argmin(np.linalg.norm(markers - contact, axis=1)))]
        cosine = -float(force @ normal) / max(float(np.linalg.norm(force)), 1e-300)
        tilted += bool(cosine < np.cos(np.radians(TILT_DEG)))
    return {"loads": dataset.n_loads, "contacts": len(distinct), "tilted_loads": tilted}


HIDDEN_FROM_THE_CONTINUUM_ON_ONE_CONTACT = ("heterogeneity", "base_compliance", "contact_patch")
"""Effects the continuum base model's E and nu absorb with loads at one contact along the
normal (scikit-fem data, docs/results/continuum-scenarios.md)."""


def design_note(dataset: Dataset, energy: str = "dnurbs") -> dict:
    """The design's summary, the effects it cannot separate from the base model, one line."""
    summary = design_summary(dataset)
    one_contact = summary["contacts"] == 1 and summary["tilted_loads"] == 0
    if energy != "dnurbs":
        hidden = HIDDEN_FROM_THE_CONTINUUM_ON_ONE_CONTACT if one_contact else ()
        offered = effect_library(energy=energy)
        hidden = tuple(name for name in hidden if name in offered)
        line = (
            f"with every load at one contact along the normal, E and nu absorb "
            f"{', '.join(hidden)}; press at several contacts and tilt a load (docs/continuum.md)"
            if one_contact
            else "detection limits of the continuum base model: docs/results/continuum-scenarios.md"
        )
        return {**summary, "cannot_separate": list(hidden), "note": line}
    if one_contact:
        hidden = HIDDEN_ON_ONE_CONTACT
        line = (
            "with every load at one contact along the normal, the design cannot separate "
            f"{', '.join(hidden)} from alpha (a refit absorbs them); press at several "
            "contacts and tilt a load (dvs simulate --design diagnosis; docs/diagnosis.md)"
        )
    else:
        hidden = HIDDEN_ANYWHERE
        line = (
            f"{', '.join(hidden)} is absorbed by alpha_w on every design tried; the others "
            "can be told apart when large enough (docs/results/detection-limits.md)"
        )
    return {**summary, "cannot_separate": list(hidden), "note": line}
