"""The blind spots of a verdict (solvers/diagnosis/blind.py).

The score test's profiled information gives the power against an effect of any size
without a new solve. Checked here: it is the linearisation of eq. (D2)'s solved signal
(``effect_power``), converging as the size shrinks; the detectable size inverts the
power; and on the phantom the measured blind spots are the ones the detection studies
found (docs/results/loop-rules.md: base_compliance hides on every design; heterogeneity and
pre_tension also hide when every load presses one contact along the normal).
"""

import numpy as np
import pytest

from experiments.design.predictions import NOISE_MM, base_fit, phantom_dataset
from solvers.design.information import effect_power
from solvers.diagnosis.blind import blind_spots, detectable_magnitude, noncentrality
from solvers.diagnosis.report import verdict
from solvers.diagnosis.stats import power, score_test
from symbolic.effects.library import EFFECT_NAMES, effect_library, make_effect

LEVEL = 0.01


def _scores(design: str):
    fit = base_fit(phantom_dataset({}, 0, design, 0.0))
    names = [n for n in EFFECT_NAMES if n in effect_library(EFFECT_NAMES, "dnurbs")]
    return fit, [score_test(fit, make_effect(n), NOISE_MM) for n in names]


@pytest.fixture(scope="module")
def diagnosis_design():
    return _scores("diagnosis")


@pytest.fixture(scope="module")
def paper_design():
    return _scores("paper")


@pytest.mark.parametrize(
    ("name", "magnitude"),
    [
        ("heterogeneity", 0.02),
        ("contact_offset", 0.2),
        ("force_direction", 0.03),
        ("bending", 4e-5),
    ],
)
def test_linearised_noncentrality_converges_to_the_solved_one(diagnosis_design, name, magnitude):
    """theta^T I theta against |P_A s(theta)|^2 / sigma^2 with the signal solved: the
    relative gap falls at least linearly with the size (bending, the most nonlinear,
    is 14 % off at 4e-5 N/mm)."""
    fit, tests = diagnosis_design
    effect = make_effect(name)
    test = next(t for t in tests if t.effect == name)
    gaps = []
    for size in (magnitude, magnitude / 4):
        theta = effect.true_parameters(size, len(fit.problem.cases))
        solved = effect_power(fit, effect, size, NOISE_MM).noncentrality
        gaps.append(abs(noncentrality(test, theta) / solved - 1.0))
    assert gaps[1] <= max(gaps[0] / 3.0, 1e-3), gaps
    assert gaps[0] < 0.2


def test_the_detectable_size_reaches_the_goal_power(diagnosis_design):
    fit, tests = diagnosis_design
    n_cases = len(fit.problem.cases)
    for name in ("heterogeneity", "base_compliance"):
        effect, test = make_effect(name), next(t for t in tests if t.effect == name)
        size = detectable_magnitude(test, effect, n_cases, LEVEL, goal=0.8)
        theta = effect.true_parameters(size, n_cases)
        one_sided = theta.size == 1 and effect.lower[0] == 0.0
        assert power(noncentrality(test, theta), test.dof, LEVEL, one_sided) == pytest.approx(
            0.8, abs=1e-4
        )


def test_blind_spots_are_the_ones_the_detection_studies_found(diagnosis_design, paper_design):
    """Five contacts and a tilted load: only base_compliance hides at a realistic size.
    Two loads at one contact: heterogeneity and pre_tension hide too."""
    fit, tests = diagnosis_design
    spots = blind_spots(tests, len(fit.problem.cases), LEVEL)
    assert [s["effect"] for s in spots] == ["base_compliance"]
    assert spots[0]["detectable"] > spots[0]["realistic"]
    fit, tests = paper_design
    names = {s["effect"] for s in blind_spots(tests, len(fit.problem.cases), LEVEL)}
    assert {"base_compliance", "heterogeneity", "pre_tension"} <= names
    assert not names & {"force_direction", "rigid_motion", "measurement_scale"}


def test_the_verdict_names_the_blind_spots_only_when_it_says_explained():
    spot = {
        "effect": "heterogeneity",
        "realistic": 0.5,
        "power": 0.1,
        "detectable": 0.9,
        "unit": "1",
    }
    document = {"selected": [], "unexplained": False, "rivals": {}, "blind_spots": [spot]}
    assert verdict(document).startswith("consistent with noise")
    assert "not ruled out: heterogeneity" in verdict(document)
    document["unexplained"] = True
    assert "not ruled out" not in verdict(document)
    assert np.isfinite(spot["detectable"])
