"""The selection rule under model error (docs/diagnosis.md, "The selection rule"): the
dispersion of left-out residuals (G2), what chance allows (G3), the model error (G4), the
per-capture parameters predicted across marker halves, and the stand-ins."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from experiments.diagnosis.diagnose import BASE_NAMES
from experiments.phantom.designs import DIAGNOSIS_CONTACTS, DIAGNOSIS_TILT_DEG
from experiments.phantom.simulate import simulate_with_effects
from experiments.problem.fitting import FitSettings, build_problem, dataset_loads
from solvers.diagnosis import guard
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from solvers.diagnosis.leftout import LeftOut, PredictionCheck, chance, dispersion
from solvers.diagnosis.loop import diagnose
from solvers.diagnosis.record import DiagnosisSettings
from solvers.diagnosis.standin import implausible, own_bounds, stand_in_reason
from symbolic.effects.library import ALL_EFFECT_NAMES, effect_library

DESIGN = {"contacts": DIAGNOSIS_CONTACTS, "tilt_deg": DIAGNOSIS_TILT_DEG}


def _problem(effects: dict, seed: int = 3):
    dataset = simulate_with_effects(effects, seed=seed, **DESIGN)
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    return base, dataset_loads(dataset, base.model.volume)


@pytest.fixture(scope="module")
def null_phantom():
    """The paper's energy on its own phantom, diagnosis design, no effect."""
    base, loads = _problem({})
    problem = ExtendedProblem(base, loads, [])
    return problem, fit(problem), effect_library(ALL_EFFECT_NAMES)


def test_dispersion_chance_and_model_error_are_the_equations():
    """(G2) phi = max(1, chi^2 / (m - k)); (G3) the chi^2_k quantile; (G4) noise RMS x
    sqrt(phi - 1), 0 at phi = 1."""
    assert dispersion(50.0, 100) == 1.0
    assert dispersion(300.0, 100) == pytest.approx(3.0)
    assert dispersion(300.0, 110, 10) == pytest.approx(3.0)
    assert chance(0.01, 1) == pytest.approx(stats.chi2.isf(0.01, 1))
    assert chance(0.01, 0.3) == chance(0.01, 1)  # at least one degree of freedom
    assert chance(0.01, 3) > chance(0.01, 2) > chance(0.05, 2)
    record = LeftOut(500.0, 100)
    assert record.model_error_mm(0.05) == pytest.approx(0.05 * 2.0)
    assert record.rms_mm(0.05) == pytest.approx(0.05 * np.sqrt(5.0))
    assert LeftOut(80.0, 100).model_error_mm(0.05) == 0.0


def test_an_improvement_counts_in_units_of_the_larger_models_dispersion():
    """G / phi_after against chi^2_k(1 - level): the same G passes at the noise and fails
    where the model with the effect still scatters four times the noise variance."""
    quiet = PredictionCheck([[0], [1]], [60.0, 60.0], [50.0, 50.0], 0, 0, rows=100)
    assert quiet.improvement == pytest.approx(20.0) and quiet.after.dispersion == 1.0
    assert quiet.improves and quiet.distance == pytest.approx(20.0 - chance(0.01, 1))
    noisy = PredictionCheck([[0], [1]], [210.0, 210.0], [200.0, 200.0], 0, 0, rows=100)
    assert noisy.improvement == pytest.approx(20.0) and noisy.after.dispersion == 4.0
    assert not noisy.improves and noisy.scaled_improvement == pytest.approx(5.0)
    assert PredictionCheck([[0]], [60.0], [50.0], 0, 0, rows=100, added_dof=3).threshold == (
        pytest.approx(stats.chi2.isf(0.01, 3))
    )


def test_parameters_fitted_across_halves_predict_only_what_both_halves_share():
    """``across_halves``: a signal in the span of the columns on both halves is predicted
    to rounding; one that lives on a single half is not, and pure noise is predicted with
    chi^2 above its in-sample value (nothing is fitted to the rows it predicts)."""
    rng = np.random.default_rng(0)
    n = 400
    first = np.arange(n) % 2 == 0
    columns = np.column_stack([np.ones(n), np.linspace(-1.0, 1.0, n)])
    shared = columns @ [0.3, -2.0]
    assert np.allclose(guard.across_halves(shared, columns, first), 0.0, atol=1e-12)
    local = np.where(first, 0.0, 1.0) * columns[:, 0]
    assert np.sum(guard.across_halves(local, columns, first) ** 2) > 0.9 * n / 2
    noise = rng.standard_normal((200, n))
    predicted = [np.sum(guard.across_halves(e, columns, first) ** 2) for e in noise]
    in_sample = [np.sum((e - columns @ np.linalg.lstsq(columns, e)[0]) ** 2) for e in noise]
    assert np.mean(predicted) > np.mean(in_sample) + 2.0  # in-sample: n - 2 on average


def test_halves_split_markers_not_rows(null_phantom):
    """Every marker's rows fall in one half, in every case, and both halves hold about
    half the markers (two opposite quadrants)."""
    problem, _, _ = null_phantom
    mask = guard.halves(problem)
    assert mask.size == sum(3 * case.n_observations for case in problem.cases)
    start = 0
    for case in problem.cases:
        n = case.n_observations
        x, y, z = (mask[start + k * n : start + (k + 1) * n] for k in range(3))
        assert np.array_equal(x, y) and np.array_equal(x, z)
        assert 0.3 < x.mean() < 0.7
        start += 3 * n


def test_a_per_capture_effect_must_predict_the_other_half_of_its_markers(null_phantom):
    """On data without a measurement effect, a per-capture scale lowers every fold's
    in-sample chi^2 but predicts the held markers no better than chance; on data with a
    rigid motion, rigid_motion predicts them far better."""
    problem, base_fit, library = null_phantom
    scaled = fit(problem.with_effects([library["measurement_scale"]]))
    check = guard.prediction_check(base_fit, scaled, 0.02)
    assert scaled.cost < base_fit.cost and not check.improves
    base, loads = _problem({"rigid_motion": 0.1})
    moved = ExtendedProblem(base, loads, [])
    moved_fit = fit(moved)
    rigid = fit(moved.with_effects([library["rigid_motion"]]))
    check = guard.prediction_check(moved_fit, rigid, 0.02)
    assert check.improves and check.scaled_improvement > 10 * check.threshold


def test_an_effect_past_its_plausible_size_is_a_stand_in(null_phantom):
    """A refit whose parameter ends on its own bound, or outside the range plausible for
    tissue, is a stand-in, with the reason; the free refit on data without the effect is
    not (it ends at 0, its null value, which is no bound of a stand-in)."""
    problem, base_fit, library = null_phantom
    effect = library["pre_tension"]
    extended = problem.with_effects([effect])
    base_free = np.append(np.ones(base_fit.p.size, dtype=bool), False)
    forced = fit(extended, np.append(base_fit.p, 2.0), base_free)
    assert implausible(forced, effect) == ["sigma0 = 2"]
    assert own_bounds(forced, "pre_tension") == []
    assert stand_in_reason(base_fit, forced, effect) is not None
    upper = fit(extended, np.append(base_fit.p, effect.upper[0]), base_free)
    assert own_bounds(upper, "pre_tension") == ["sigma0"]
    assert stand_in_reason(base_fit, upper, effect) is not None
    refit = fit(extended, np.append(base_fit.p, 0.0))
    assert own_bounds(refit, "pre_tension") == [] and implausible(refit, effect) == []
    assert stand_in_reason(base_fit, refit, effect) is None


def test_the_loop_records_model_error_and_left_out_errors_of_each_step():
    """diagnosis.json: ``model_error_mm`` 0 when explained; every step's ``left_out`` and
    each added step's ``prediction`` with the left-out RMS before and after [mm]."""
    base, loads = _problem({"force_direction": 0.3}, seed=4)
    diagnosis = diagnose(base, loads, DiagnosisSettings(max_effects=1))
    document = diagnosis.document()
    assert document["selected"] == ["force_direction"]
    assert document["model_error_mm"] == 0.0 and not document["unexplained"]
    first, second = document["steps"]
    assert first["left_out"]["source"] == "left-out"
    assert first["left_out"]["dispersion"] > second["left_out"]["dispersion"] >= 1.0
    prediction = second["prediction"]
    assert prediction["rms_before_mm"] > prediction["rms_after_mm"] > 0.0
    assert document["stand_ins"] == [] or all(
        s["effect"] not in document["selected"] for s in document["stand_ins"]
    )
