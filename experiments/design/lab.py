"""The lab the sequential loop presses on: FE continuum data, one capture per press.

A ``ContinuumLab`` stands in for a subject in the chair. Its tissue is a scikit-fem
slab of ``experiments.diagnosis.continuumstudy`` (quadratic tetrahedra, tissue beyond the
marked area, 9 x 9 markers) with one scenario's hidden departure (``SCENARIOS``).
Each press is filmed once: the markers under the true load, their own noise draw
(seed ``1000 seed + k`` for the k-th press) and the probe's occlusion. The rest capture
is drawn once, with the first press, and shared by every press after it, as in a
session where the cameras film the skin before the first press
(``experiments.data.captures.merge_captures``, as ``dvs next`` appends a lab's presses).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from experiments.data.captures import merge_captures
from experiments.data.dataset import Dataset
from experiments.diagnosis.continuumstudy import SCENARIOS, ContinuumStudy


class ContinuumLab:
    """FE continuum data of one scenario, made one press at a time.

    Parameters
    ----------
    scenario : str
        A name of ``experiments.diagnosis.continuumstudy.SCENARIOS``.
    study : ContinuumStudy
        The slab, the probe radius [mm], the noise [mm] and the seed.
    """

    def __init__(self, scenario: str, study: ContinuumStudy | None = None):
        from experiments.phantom.fe import Departure, SlabSolution

        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}")
        self.scenario = scenario
        self.study = study or ContinuumStudy()
        slab_changes, departure, self.hidden = SCENARIOS[scenario]
        self.slab = replace(self.study.slab, **slab_changes)
        self.departure = Departure(**departure)
        self.solver = SlabSolution(self.slab)
        self.captures: list[Dataset] = []

    def press(self, contact_mm, force_n) -> Dataset:
        """Press at ``contact_mm`` (x, y[, z]) on the skin with ``force_n`` (3,) [N]; film it.

        Returns the dataset of every press so far.
        """
        from experiments.phantom.fe import reference_dataset
        from experiments.phantom.simulate import SimulationSettings

        study = self.study
        seed = 1000 * study.seed + len(self.captures)
        measurement = SimulationSettings(noise_mm=study.noise_mm, seed=seed)
        contact = np.asarray(contact_mm, dtype=float)[:2]
        force = np.asarray(force_n, dtype=float)
        self.captures.append(
            reference_dataset(
                self.slab,
                force[None],
                contact[None],
                study.radius,
                (9, 9),
                measurement,
                self.departure,
                self.solver,
            )
        )
        return self.dataset

    def start(self, design: str = "paper") -> Dataset:
        """Press a named design of ``experiments.phantom.fe.design_cases`` (the paper's:
        0.17 and 0.25 N at the centre, along the normal)."""
        from experiments.phantom.fe import design_cases

        forces, contacts = design_cases(design, self.slab)
        for force, contact in zip(forces, contacts):
            self.press(contact, force)
        return self.dataset

    @property
    def dataset(self) -> Dataset:
        """Every press so far, with the first press's rest capture."""
        if not self.captures:
            raise ValueError("no press made yet")
        return merge_captures(self.captures)
