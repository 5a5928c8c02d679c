"""The default pipeline (step 0, then the loop) on data from the project's scikit-fem
generator (``experiments.phantom.fe``: P2 tetrahedra, clamped 6 mm beyond the markers,
a Gaussian probe whose radius the dataset does not declare, a 7 x 6 marker grid that is
not the model's): a planted effect is named first and nothing but the set-up follows
it; without one nothing is named; and where the model carries model error only (a
coarse volume of the user's), no effect stands in for it (docs/diagnosis.md, "The loop
and its selection rule")."""

from __future__ import annotations

from dataclasses import replace

import pytest

from experiments.diagnosis.diagnose import base_settings, diagnose_dataset
from experiments.phantom.fe import (
    Departure,
    ReferenceSlab,
    SlabSolution,
    design_cases,
    reference_dataset,
)
from experiments.phantom.simulate import SimulationSettings

SET_UP = frozenset({"surrounding_tissue", "contact_patch"})
"""The physical set-up terms: the tissue beyond the markers and the probe's patch."""

SLAB = ReferenceSlab(
    lengths=(40.0, 36.0, 5.0), marked=(28.0, 24.0), elements=(12, 11, 3), fix_lateral=True
)


@pytest.fixture(scope="module")
def solution():
    return SlabSolution(SLAB)


def _dataset(solution, design: str, radius: float, departure: Departure | None = None):
    forces, contacts = design_cases(design, SLAB)
    measurement = SimulationSettings(noise_mm=0.02, seed=5)
    data = reference_dataset(
        SLAB, forces, contacts, radius, (7, 6), measurement, departure, solver=solution
    )
    return replace(data, probe_radius=None)  # the probe's size is not declared


def test_without_an_effect_the_default_pipeline_names_nothing(solution):
    document = diagnose_dataset(_dataset(solution, "paper", 5.0)).document()
    assert document["base_choice"]["chosen"] == "linear-elastic"
    assert document["selected"] == [] and document["unexplained"] is False
    assert document["model_error_mm"] == 0.0


def test_a_planted_rigid_motion_is_named_first_and_only_set_up_follows(solution):
    data = _dataset(solution, "paper", 5.0, Departure(rigid_mm=0.1))
    document = diagnose_dataset(data).document()
    assert document["selected"][:1] == ["rigid_motion"], document["selected"]
    assert set(document["selected"][1:]) <= SET_UP
    assert document["unexplained"] is False


def test_model_error_alone_is_stated_not_explained_by_an_effect(solution):
    """A 7 x 7 x 2 continuum cannot follow the probes of the ten-load design: the
    residual stays far above the noise. No effect but the set-up is named, the verdict
    states the model error, and what stood in for it is listed as a stand-in; a rigid
    motion planted in the same data is still named first."""
    coarse = base_settings((7, 7, 2), "linear-elastic")
    document = diagnose_dataset(_dataset(solution, "diagnosis", 4.0), base=coarse).document()
    assert set(document["selected"]) <= SET_UP, document["selected"]
    assert document["unexplained"] is True
    assert document["model_error_mm"] > 0.5 * document["noise_rms_mm"]
    assert document["model_error"]["times_noise"] == pytest.approx(
        document["model_error_mm"] / document["noise_rms_mm"]
    )
    assert document["stand_ins"], "the candidates that lowered the residual are listed"
    assert not {s["effect"] for s in document["stand_ins"]} & set(document["selected"])
    planted = _dataset(solution, "diagnosis", 4.0, Departure(rigid_mm=0.1))
    document = diagnose_dataset(planted, base=coarse).document()
    assert document["selected"][:1] == ["rigid_motion"], document["selected"]
    assert set(document["selected"][1:]) <= SET_UP
