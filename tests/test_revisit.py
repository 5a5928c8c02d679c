"""Step 0 revisited (``experiments.basemodel.revisit``): once an effect is in, the
surroundings step 0 chose on data that hold it are searched again.

FE data from the generator the model was not tuned on (``experiments.phantom.tissue``):
a small flat patch, the tissue 3 mm beyond the markers and clamped there, the paper's
two loads from a 2.5 mm disc probe whose contact lies 2 mm off the declared point.
Without the offset in the model the probe's radius absorbs part of it (step 0 took
3.6 mm for 2.5 on row A's patch).
"""

from __future__ import annotations

import pytest

from experiments.basemodel.choice import BaseChoice
from experiments.basemodel.family import SEARCH_SPAN_OF_SPACING, Family, starting_resolution
from experiments.basemodel.revisit import Revisit
from solvers.diagnosis.loop import _refit
from solvers.diagnosis.stats import score_test
from solvers.linalg.blas import one_thread
from symbolic.effects.library import make_effect

TRUE_RADIUS_MM = 2.5
WRONG_RADIUS_MM = 3.85


@pytest.fixture(scope="module")
def offset_data():
    from experiments.phantom.fe import Departure
    from experiments.phantom.simulate import SimulationSettings
    from experiments.phantom.tissue import TissuePatch, tissue_cases, tissue_dataset

    patch = TissuePatch(
        marked=(24.0, 18.0), extent_mm=3.0, thickness=4.0, poisson=0.45, support="clamped"
    )
    forces, contacts = tissue_cases("paper", patch)
    return tissue_dataset(
        patch,
        forces,
        contacts,
        TRUE_RADIUS_MM,
        (7, 6),
        "disc",
        measurement=SimulationSettings(noise_mm=0.02, seed=3),
        departure=Departure(contact_offset_mm=(1.2, 1.6)),
    )


def test_with_the_offset_in_the_search_finds_the_true_radius_and_the_fit_improves(offset_data):
    """From a wrong radius, with contact_offset in every member, the revisit's search
    moves to the true radius (within 0.3 mm) and the refit's chi^2 drops; a second
    revisit from there keeps it."""
    with one_thread():
        sigma = offset_data.noise_mm
        span, layers = starting_resolution(offset_data, SEARCH_SPAN_OF_SPACING)
        family = Family(offset_data, span, layers, sigma, lambda *_: None)
        wrong = family.trial(3.0, "clamped", WRONG_RADIUS_MM)
        choice = BaseChoice(wrong, wrong, wrong, [wrong], [], sigma=sigma)
        current = wrong.fit
        current.problem.sigma = sigma
        effect = make_effect("contact_offset")
        with_offset = _refit(current, effect, score_test(current, effect, sigma))
        revisit = Revisit(choice, lambda *_: None)
        moved = revisit(with_offset)
        assert moved is not None
        fitted, record = moved
        assert abs(record["after"]["radius_mm"] - TRUE_RADIUS_MM) < 0.3, record
        assert record["chi2_after"] < record["chi2_before"]
        assert fitted.cost < with_offset.cost
        assert [e.name for e in fitted.problem.effects] == ["contact_offset"]
        assert revisit(fitted) is None  # the search from the new surroundings keeps them
        assert revisit.records[-1]["changed"] is False
