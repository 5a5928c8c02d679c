"""The discretisation error an effect must beat (docs/diagnosis.md, "The selection rule",
eq. D1-D3): Richardson's estimate from step 0's resolution checks, and the bound."""

from __future__ import annotations

import numpy as np
import pytest

from solvers.diagnosis.discretisation import discretisation_reason, remaining_error
from solvers.diagnosis.leftout import PredictionCheck

R = 1.5


def _checks(order: float, spans: list[float], converged_last: bool, scale: float = 40.0):
    """Resolution records of predicted markers whose error is scale h^order along a fixed
    direction, on volumes of the knot spans ``spans`` (each R times the next); the exact
    error of the volume the records adopt."""
    rng = np.random.default_rng(0)
    direction = rng.normal(size=50)
    direction /= np.linalg.norm(direction)
    errors = [scale * h**order * direction for h in spans]
    records = [
        {"verdict": "refined", "prediction_chi2": float(np.sum((a - b) ** 2))}
        for a, b in zip(errors[:-1], errors[1:])
    ]
    if converged_last:
        records[-1]["verdict"] = "converged"
        return records, float(errors[-2] @ errors[-2])
    return records, float(errors[-1] @ errors[-1])


@pytest.mark.parametrize("order", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("converged_last", [False, True])
def test_two_changes_give_the_order_and_the_error_left_exactly(order, converged_last):
    """On an error that falls as h^p, (D2) recovers p and (D1a)/(D1b) the error of the
    adopted volume (the coarser of a converged check, the finer of a refinement)."""
    records, exact = _checks(order, [1.0, 1.0 / R, 1.0 / R**2], converged_last)
    estimate = remaining_error(records, R)
    assert estimate["how"] == "measured"
    assert estimate["order"] == pytest.approx(order)
    assert estimate["chi2"] == pytest.approx(exact)


def test_one_change_assumes_first_order_which_overestimates_a_faster_error():
    """With one change p = 1 is assumed, the slowest order: the error left is then never
    underestimated for a faster convergence, and exact at first order."""
    for order in (1.0, 2.0):
        records, exact = _checks(order, [1.0, 1.0 / R], converged_last=False)
        estimate = remaining_error(records, R)
        assert estimate["how"] == "assumed" and estimate["order"] == 1.0
        assert estimate["chi2"] >= exact * (1 - 1e-12)
        if order == 1.0:
            assert estimate["chi2"] == pytest.approx(exact)
    # the refinement step 0 could not check adds no change: the last measured one counts
    records, exact = _checks(1.0, [1.0, 1.0 / R], converged_last=False)
    estimate = remaining_error(records + [{"verdict": "not checked"}], R)
    assert estimate["chi2"] == pytest.approx(exact)


def test_nothing_checked_gives_no_bound():
    estimate = remaining_error([{"verdict": "not checked", "reason": "budget"}], R)
    assert estimate == {"chi2": 0.0, "order": None, "how": "not estimated"}


def test_an_effect_must_gain_more_than_the_error_left():
    """(D3): the same left-out gain G passes without a bound, stands in for the
    discretisation when D >= G, and passes again when D < G."""
    check = PredictionCheck([[0], [1]], [60.0, 60.0], [40.0, 40.0], 0, 0, rows=1000)
    assert check.improvement == pytest.approx(40.0)
    assert discretisation_reason(check, 0.0) is None
    assert discretisation_reason(check, 39.9) is None
    reason = discretisation_reason(check, 85.4)
    assert reason is not None and "40.0" in reason and "85.4" in reason
    assert discretisation_reason(None, 85.4) is None  # one case: no left-out gain to bound
