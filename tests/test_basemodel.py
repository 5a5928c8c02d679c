"""Step 0 of the loop (``experiments.basemodel``): the base model, its surroundings and
its resolution, chosen from the data.

The FE data come from ``experiments.phantom.tissue`` (Q2 hexahedra, another mesh and
element than the model's), a small patch so that a step 0 takes seconds: 24 x 18 mm
marked by 7 x 6 markers, 4 mm thick, clamped 4 mm beyond the markers, 8 loads at four
contacts, a 2 mm disc probe whose radius the dataset does not declare. The phantom is
the paper's own model (``experiments.phantom.simulate``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fepatch import patch_dataset
from scipy import stats

from experiments.basemodel import MARGINS_MM, SUPPORTS, choose_base
from experiments.basemodel.family import MIN_RADIUS_MM, span_settings, with_radius
from experiments.basemodel.resolution import MAX_CHECK_POINTS, MAX_REFINEMENTS, linearised_refit


def _patch_dataset(radius: float, probe: str, seed: int):
    """The module's FE patch (docstring) pressed by a probe of ``radius`` [mm] and shape."""
    return patch_dataset((24.0, 18.0), (7, 6), radius, probe, seed)


@pytest.fixture(scope="module")
def patch_data():
    return _patch_dataset(2.0, "disc", seed=3)


@pytest.fixture(scope="module")
def patch_choice(patch_data):
    return choose_base(patch_data)


def test_on_fe_tissue_step_0_keeps_the_continuum_with_its_surroundings(patch_choice):
    """The continuum wins by the information criterion (not nested: BIC, each chosen
    setting counted as a parameter), and the finding says what the paper's model lacks."""
    choice = patch_choice
    assert choice.chosen is choice.continuum
    assert choice.continuum.bic < choice.paper.bic - 100
    assert "linear elasticity" in choice.finding()
    # every surroundings of the family was fitted, and the chosen one fits best
    searched = {(t.surroundings.margin_mm, t.surroundings.support) for t in choice.trials}
    assert searched == {(m, s) for m in MARGINS_MM for s in SUPPORTS}
    best = min(choice.trials, key=lambda t: t.chi2).surroundings
    chosen = choice.chosen.surroundings
    assert (chosen.margin_mm, chosen.support) == (best.margin_mm, best.support)
    # the undeclared radius is estimated inside the profile's range, at neither end: not
    # its smallest (a point force a continuum cannot carry), not the cap of a quarter of
    # the shorter marked side (a load over the marked area, not a 2 mm probe)
    assert MIN_RADIUS_MM < chosen.radius_mm < choice.chosen.family.max_radius()


def test_the_resolution_is_refined_until_the_markers_do_not_move(patch_choice):
    """Each check that the data can see is followed by one on a finer volume; the last
    is within the 1-dof chi^2 quantile at the loop's level. The patch is small: every
    check's volume is within the budget (``MAX_CHECK_POINTS``), so each check runs and
    the refinements end converged, not "not checked" or out of refinements."""
    checks = patch_choice.resolution
    assert 1 <= len(checks) <= MAX_REFINEMENTS
    assert all(math.prod(c["refined_grid"]) <= MAX_CHECK_POINTS for c in checks)
    limit = stats.chi2.isf(0.01, 1)  # choose_base's default level
    for check in checks[:-1]:
        assert check["verdict"] == "refined" and check["prediction_chi2"] > check["limit"]
    last = checks[-1]
    assert last["verdict"] == "converged"
    assert last["limit"] == pytest.approx(limit) and last["prediction_chi2"] <= limit
    assert list(patch_choice.settings.grid) == last["grid"]


def test_the_linearised_refit_agrees_with_the_full_refit(patch_data, patch_choice):
    """The check's refit is one Gauss-Newton step from the coarse estimate; the distance
    it gives (how far the finer volume moves the predicted markers) is the full refit's
    to a tenth, where the rule compares it with the 1-dof quantile."""
    from experiments.problem.fitting import build_model, dataset_loads, problem_on
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit

    key, sigma = patch_choice.chosen.surroundings, patch_choice.sigma
    data = with_radius(patch_data, key.radius_mm)
    coarse = min(patch_choice.trials, key=lambda t: t.chi2)
    settings = span_settings(data, key.margin_mm, key.support, 2.0, 5)
    model, uv = build_model(data, settings)
    base = problem_on(model, uv, data, settings)
    problem = ExtendedProblem(base, dataset_loads(data, model.volume), [])
    predicted, _ = linearised_refit(problem, coarse.fit.p)
    full = fit(problem, coarse.fit.p)
    linearised = np.sum((coarse.fit.whitened - predicted) ** 2) / sigma**2
    refitted = np.sum((coarse.fit.whitened - full.whitened) ** 2) / sigma**2
    assert refitted > 1.0  # the two volumes differ visibly: the comparison means something
    assert abs(linearised - refitted) <= 0.1 * refitted


def test_on_the_phantom_step_0_keeps_the_papers_energy():
    """Data made by the paper's own model: its energy is kept. Clean, it fits at the
    noise and the continuum is not tried; with make demo's undeclared rigid motion it
    does not, and the continuum loses by the information criterion."""
    from experiments.phantom.simulate import simulate_with_effects
    from symbolic.effects.library import make_effect

    clean = choose_base(simulate_with_effects({}, seed=0))
    assert clean.chosen is clean.paper and clean.continuum is None
    assert "not tried" in clean.finding()
    magnitude = make_effect("rigid_motion").default_magnitude
    moved = choose_base(simulate_with_effects({"rigid_motion": magnitude}, seed=0))
    assert moved.chosen is moved.paper and moved.settings.energy == "dnurbs"
    assert moved.paper.bic < moved.continuum.bic and moved.resolution == []


def test_the_record_holds_the_choice_and_a_line_names_it(patch_choice):
    record = patch_choice.record()
    assert record["chosen"] == "linear-elastic"
    assert record["surroundings"]["probe_radius_estimated"] is True
    assert record["paper"]["chi2"] > record["continuum"]["chi2"]
    assert "base model: linear-elastic" in patch_choice.line()


@pytest.mark.parametrize("command", ["fit", "diagnose"])
@pytest.mark.parametrize("option", [["--grid", "9x9x2"], ["--margin", "5"], ["--degrees", "3x3x2"]])
def test_volume_options_without_an_energy_exit_2(tmp_path, capsys, command, option):
    """--grid, --margin and --degrees set the volume of a chosen --energy; with the
    default (auto) step 0 chooses it: exit 2, one line naming the option."""
    from experiments.command.cli import main
    from experiments.data.dataset import save_dataset
    from experiments.phantom.simulate import simulate_with_effects

    path = tmp_path / "d.npz"
    save_dataset(path, simulate_with_effects({}, seed=0))
    assert main([command, str(path), *option, "--out", str(tmp_path / "o")]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and option[0] in error[0] and "--energy" in error[0]
    assert not (tmp_path / "o").exists()


def test_the_radius_profile_stops_at_the_largest_probe(patch_data, monkeypatch):
    """Data that fit better the wider the patch (a load spread over the whole marked area)
    take the radius to the cap, a quarter of the shorter marked side, and never past it."""
    from types import SimpleNamespace

    from experiments.basemodel.family import Family

    family = Family(patch_data, span=3.0, layers=3, sigma=0.02, log=lambda *_: None)
    assert not family.declared
    tried = []

    def trial(margin, support, radius, start=None, shape="gauss"):  # chi^2 falls with r
        tried.append(radius)
        key = family.key(margin, support, radius, shape)
        return family.trials.setdefault(key, SimpleNamespace(chi2=1e4 / radius))

    monkeypatch.setattr(family, "trial", trial)
    best = family.radius_profile(5.0, "clamped")
    largest = family.max_radius()
    assert 4.0 < largest < 4.6  # 0.25 x the 18 mm side, measured along the skin
    assert max(tried) == pytest.approx(round(largest, 2))  # radii are tried to 0.01 mm
    assert all(r <= largest + 0.005 for r in tried)
    assert best.chi2 == pytest.approx(1e4 / round(largest, 2))


def test_the_probe_shape_is_compared_on_the_checked_volume(patch_choice):
    """Both shapes are fitted on the volume the resolution check kept, each with its
    radius profiled; no other shape beats the kept one by more than the 1-dof quantile
    (6.6), and the preference says by how much it was kept."""
    from symbolic.loads import PROBE_SHAPES

    choice = patch_choice
    shapes = choice.shapes
    assert sorted(r["shape"] for r in shapes) == sorted(PROBE_SHAPES)
    assert all(r["grid"] == list(choice.chosen.settings.grid) for r in shapes)
    kept = next(r for r in shapes if r["shape"] == choice.chosen.surroundings.shape)
    assert kept["chi2"] == pytest.approx(choice.chosen.chi2)
    assert all(r["chi2"] > kept["chi2"] - 6.7 for r in shapes)
    assert "probe shape: next best" in choice.preference()


@pytest.mark.parametrize("probe", ["gauss", "disc"])
def test_the_probe_shape_of_the_data_is_recovered(probe):
    """FE data pressed through a Gaussian patch or a uniform disc (4 mm radius, 3 mm
    marker spacing, undeclared): step 0 keeps the shape the data were made with. The
    Gaussian is the incumbent: on Gaussian data the disc fitted within the quantile
    (chi^2 881 against 883), on disc data it won by 58 (914 against 972)."""
    choice = choose_base(_patch_dataset(4.0, probe, seed=5))
    print(choice.shapes)
    assert choice.chosen.surroundings.shape == probe
