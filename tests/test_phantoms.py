"""The silicone phantoms (docs/experiments.md): the cylinder against scikit-fem, E
recovered from a synthetic twin, one recipe on real data, the full table (slow)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments.command.options import UsageError
from experiments.data.compression import compression_dataset, read_recipe
from experiments.phantoms import diagnosis
from experiments.phantoms.cylinder import uniform_force
from experiments.phantoms.cylindercheck import reference_ratio, spline_ratio
from experiments.phantoms.study import (
    PUBLISHED_E_KPA,
    LinearFit,
    energy_entry,
    model_entry,
    named_contact,
    recipe_row,
    run,
    unit_curves,
)


def test_the_spline_cylinder_matches_scikit_fem_where_nothing_locks():
    """At nu = 0.3 the bonded cylinder's apparent modulus (E A delta / H = 1 under
    uniform stress) is the P2 reference's within 1 %, and both exceed 1 (barrelling)."""
    spline = spline_ratio(0.3, (7, 7, 5), 2)
    reference = reference_ratio(0.3, 6)
    assert reference > 1.05
    assert spline == pytest.approx(reference, rel=0.01)


def test_near_incompressibility_the_bonded_cylinder_stiffens_and_degree_2_locks_a_little():
    """At nu = 0.49 the barrelling factor grows (about 1.39); degree 2 on the coarse
    grid is measurably too stiff, and refining it moves it towards the reference."""
    reference = reference_ratio(0.49, 6)
    coarse, finer = spline_ratio(0.49, (7, 7, 5), 2), spline_ratio(0.49, (9, 9, 6), 2)
    assert 1.3 < reference < 1.5
    assert coarse > finer > reference * 0.995


def test_uniform_stress_is_linear_elastic_at_small_strain():
    """The sliding model's force at 0.1 % strain is E A strain (kPa = 1e-3 N/mm^2)."""
    force = uniform_force(np.array([0.03]), 30.0, 25.0, 40.0)[0]
    assert force == pytest.approx(1e-3 * 40.0 * np.pi * 25.0**2 * 0.001, rel=2e-3)


def test_a_twin_with_known_e_and_noise_is_recovered_within_its_standard_error():
    """Five specimens from the sliding model with E = 27 kPa, 3 % specimen scatter and
    force noise: E within 3 standard errors, and bonded and sliding are told apart
    only when the data's curve shape says so (here it cannot: both are linear in E)."""
    rng = np.random.default_rng(4)
    travel = np.linspace(0.06, 3.0, 8)
    unit = uniform_force(travel, 30.0, 25.0, 1.0)
    specimens = 27.0 * (1 + 0.03 * rng.standard_normal((5, 1))) * unit
    specimens += 0.05 * rng.standard_normal(specimens.shape)
    fitted = LinearFit.of(np.tile(unit, 5), specimens.ravel())
    assert abs(fitted.young_kpa - 27.0) < 3 * fitted.std_kpa + 0.02 * 27.0
    # a "bonded" curve that is the sliding one times a constant predicts equally well
    sliding_sse = np.sum((specimens - fitted.young_kpa * unit) ** 2, axis=1)
    bonded_sse = np.sum((specimens - (fitted.young_kpa / 1.4) * (1.4 * unit)) ** 2, axis=1)
    assert named_contact(bonded_sse, sliding_sse) == "neither"


def test_one_recipe_on_real_data_predicts_its_b_series_within_the_scatter(shared_data):
    """EF10_100T at small strain on a coarse grid: E of the A series near the published E
    under uniform stress, the bonded E lower by the barrelling factor, and the B series
    predicted about as well as the A series' own mean curve predicts it."""
    travel = np.linspace(0.02, 1.0, 5) * 0.1 * 30.0
    curves = {"small strain": unit_curves(travel, 25.0, 30.0, (7, 7, 5), 2)}
    folder = shared_data / "phantom-compression" / "data" / "EF10_100T"
    row = recipe_row(folder, curves, {"small strain": (0.1, 5)})
    small = row["small strain"]
    published = PUBLISHED_E_KPA["EF10_100T"][0]
    assert small["sliding"]["E_kPa"] == pytest.approx(published, rel=0.15)
    ratio = small["sliding"]["E_kPa"] / small["bonded"]["E_kPa"]
    assert 1.3 < ratio < 1.6
    for contact in ("sliding", "bonded"):
        assert small[contact]["b_prediction_rms_n"] < 1.5 * small["b_scatter_n"]


def test_diagnose_on_a_recipe_fits_the_a_series_and_predicts_the_b_series(
    shared_data, tmp_path, monkeypatch
):
    """``dvs diagnose`` on imported curves (coarse 3D grids here): the base E under
    uniform stress near the published E, bonded plates added only if they predict the
    B series better, the files written; a dataset without a B series is refused."""

    def coarse(travel, radius, height, shape=None, degree=None):
        return unit_curves(travel, radius, height, (7, 7, 5) if shape is None else (6, 6, 4), 2)

    monkeypatch.setattr(diagnosis, "unit_curves", coarse)
    recipe, tests = read_recipe(shared_data / "phantom-compression" / "data" / "EF10_100T")
    dataset = compression_dataset(recipe, tests, 8, 0.3)
    document = diagnosis.diagnose_compression(dataset, tmp_path / "d", log=print)
    assert document["schema"] == "dvs-diagnosis/1" and document["recipe"] == "EF10_100T"
    assert set(document["selected"]) <= {"bonded_plates"}
    named = document["windows"]["curve"]["named"]
    contact = document["final_model"].split(" + ")[0]
    assert contact == ("bonded" if named == "bonded" else "sliding")
    if contact == "sliding":
        published = PUBLISHED_E_KPA["EF10_100T"][0]
        assert document["young_kpa"] == pytest.approx(published, rel=0.15)
    assert document["b_prediction_rms_n"] <= 2.0 * document["b_scatter_n"]
    assert {"diagnosis.json", "phantom.json", "report.md"} <= {
        p.name for p in (tmp_path / "d").iterdir()
    }
    only_a = compression_dataset(recipe, [t for t in tests if t.name.startswith("A")], 8, 0.3)
    with pytest.raises(UsageError, match="A and non-A"):
        diagnosis.diagnose_compression(only_a, tmp_path / "e")
    assert not (tmp_path / "e").exists()


@pytest.mark.slow
def test_every_recipe(tmp_path):
    """The table of docs/experiments.md: every recipe's sliding E within 15 % of the
    published E at small strain; the B series within 1.5 x its scatter at small strain,
    and to 30 % within 1.2 x once a named softening is in."""
    document = run(tmp_path)
    assert len(document["recipes"]) == 14
    for row in document["recipes"]:
        small = row["small strain"]
        assert small["sliding"]["E_kPa"] == pytest.approx(row["published_E_kPa"][0], rel=0.15)
        assert small["sliding"]["b_prediction_rms_n"] < 1.5 * small["b_scatter_n"]
        # to 30 %: stiffening is never asked for; where Yeoh's softening is named, the
        # B series comes within 1.2 x its scatter
        energy, curve = row["curve"]["energy"], row["curve"]
        assert not energy["nonlinear_stiffening"]["named"]
        if energy["yeoh_term"]["named"]:
            assert energy["yeoh_term"]["ratio"] < 0
            assert energy["yeoh_term"]["b_prediction_rms_n"] < 1.2 * curve["b_scatter_n"]


def test_a_scikit_fem_twin_with_bonded_plates_gives_back_e_and_the_sliding_bias():
    """Data from scikit-fem (P2, bonded plates, E = 20 kPa, nu = 0.49, small strain, 1 %
    noise): the bonded spline model (degree 3) recovers E within 1.5 %; the uniform-stress
    model, the published fits' assumption, reads the barrelling as stiffness and
    returns E x 1.39."""
    rng = np.random.default_rng(7)
    planted = 20.0
    reference = reference_ratio(0.49, 6)  # F H / (E A delta) of the P2 solution
    unit = 1e-3 * np.pi * 25.0**2 * 0.3 / 30.0  # E A delta / H at E = 1 kPa [N]
    measured = planted * reference * unit * (1 + 0.01 * rng.standard_normal(5))
    bonded = LinearFit.of(np.full(5, spline_ratio(0.49, (9, 9, 7), 3) * unit), measured)
    sliding = LinearFit.of(np.full(5, unit), measured)
    assert bonded.young_kpa == pytest.approx(planted, rel=0.015)
    assert sliding.young_kpa / planted == pytest.approx(1.39, rel=0.02)


@pytest.mark.slow
def test_dvs_import_then_diagnose_on_one_recipe(shared_data, tmp_path):
    """The user's path on one recipe (the model's own grids; the time is printed, not
    asserted): E under uniform stress within 15 % of the published E, or the bonded
    model named; the B series predicted within 2 x its scatter."""
    import time

    from experiments.command.cli import main

    folder = shared_data / "phantom-compression" / "data" / "EF30_25T"
    data = tmp_path / "ef30.npz"
    assert main(["import", "compression", str(folder), "--out", str(data)]) == 0
    begin = time.perf_counter()
    assert main(["diagnose", str(data), "--out", str(tmp_path / "d")]) == 0
    print(f"dvs diagnose on EF30_25T: {time.perf_counter() - begin:.0f} s")
    document = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    if document["final_model"].startswith("sliding"):
        published = PUBLISHED_E_KPA["EF30_25T"][0]
        assert document["young_kpa"] == pytest.approx(published, rel=0.15)
    assert document["b_prediction_rms_n"] <= 2.0 * document["b_scatter_n"]


@pytest.mark.parametrize("keyword, ratio", [("yeoh", -0.02), ("stiffening", 0.3)])
def test_the_uniform_force_is_the_derivative_of_the_energy_at_free_lateral_stretch(keyword, ratio):
    """-F / (pi r^2) = dw / dlambda, w(lambda) = min over a of W(diag(a, a, lambda)) with
    W of eq. (C6) plus eq. (C10)'s or Yeoh's term, by central differences of a numerical
    minimum (not the stress the code writes)."""
    from scipy.optimize import minimize_scalar

    from symbolic.continuum import lame

    young, nu, height, radius = 10.0, 0.49, 30.0, 25.0
    mu, lam = lame(young, nu)
    scale = 2.0 * (1.0 + nu) * mu * ratio  # k1 or c2 [N/mm^2]

    def energy(a, stretch):
        jacobian = a * a * stretch
        invariant = 2.0 * a * a + stretch * stretch
        s = jacobian ** (-2.0 / 3.0) * invariant - 3.0
        neo = mu / 2 * (invariant - 3) - mu * np.log(jacobian) + lam / 2 * np.log(jacobian) ** 2
        extra = scale / 20.0 * (np.exp(10.0 * s * s) - 1.0) if keyword == "stiffening" else 0.0
        return neo + extra + (scale * s * s if keyword == "yeoh" else 0.0)

    def reduced(stretch):
        found = minimize_scalar(
            lambda a: energy(a, stretch),
            bounds=(0.8, 1.5),
            method="bounded",
            options={"xatol": 1e-12},
        )
        return found.fun

    for travel in (3.0, 7.5):
        stretch, step = 1.0 - travel / height, 1e-4
        slope = (reduced(stretch + step) - reduced(stretch - step)) / (2 * step)
        force = uniform_force(np.array([travel]), height, radius, young, nu, **{keyword: ratio})
        assert force[0] == pytest.approx(-slope * np.pi * radius**2, rel=1e-5)


def _incompressible_yeoh_force(travel, height, radius, c10, c20, c30):
    """Uniaxial compression of an incompressible Yeoh solid [N] (another generator than
    the study's compressible model): P = 2 (lambda - lambda^-2) dW/dI1."""
    stretch = 1.0 - travel / height
    i1 = stretch**2 + 2.0 / stretch
    slope = c10 + 2 * c20 * (i1 - 3) + 3 * c30 * (i1 - 3) ** 2
    return -2e-3 * (stretch - stretch**-2) * slope * np.pi * radius**2


@pytest.mark.parametrize("planted", ["softening", "none"])
def test_an_energy_twin_names_the_planted_softening_and_nothing_on_a_neo_hookean_twin(planted):
    """Ten specimens of an incompressible Yeoh solid (c10 = 8 kPa; c20 = -1 kPa, the
    softening the measured curves show, c2 / E about -0.02, or neo-Hookean with c20 = 0),
    3 % specimen-to-specimen stiffness and 0.01 N noise, to 30 % compression: fitted on
    A1-A5 and judged on B1-B5 with the compressible model (nu = 0.49), the Yeoh term is
    named with c2 / E within 50 % of the planted -1 / 48 on the softening twin and
    stiffening is not; on the neo-Hookean twin neither is named."""
    rng = np.random.default_rng(3)
    height, radius = 30.0, 25.0
    travel = np.linspace(0.02, 1.0, 10) * 0.3 * height
    c20, c30 = (-1.0, 0.0) if planted == "softening" else (0.0, 0.0)
    force = np.array(
        [
            _incompressible_yeoh_force(travel, height, radius, 8.0 * f, c20 * f, c30 * f)
            for f in 1.0 + 0.03 * rng.standard_normal(10)
        ]
    )
    force += 0.01 * rng.standard_normal(force.shape)
    series_a = np.arange(10) < 5
    base = model_entry(uniform_force(travel, height, radius, 1.0), force, series_a)
    entries = {
        name: energy_entry(travel, force, series_a, 0.01, (height, radius), name, base)
        for name in ("nonlinear_stiffening", "yeoh_term")
    }
    assert not entries["nonlinear_stiffening"]["named"]
    if planted == "softening":
        assert entries["yeoh_term"]["named"]
        assert entries["yeoh_term"]["ratio"] == pytest.approx(-1.0 / 48.0, rel=0.5)
    else:
        assert not entries["yeoh_term"]["named"], entries["yeoh_term"]


def test_the_bonded_forces_do_not_depend_on_the_order_of_the_travels():
    """``plate_forces`` solves in order of travel, each start scaled from the last state:
    the forces at travels given in any order are the same (coarse cylinder, to 20 %)."""
    from experiments.phantoms.cylinder import cylinder_model, plate_forces

    travel = np.array([6.0, 0.6, 3.0])
    model = cylinder_model(25.0, 30.0, 1.0, (5, 5, 4), 2)
    forward = plate_forces(model, travel)
    again = plate_forces(cylinder_model(25.0, 30.0, 1.0, (5, 5, 4), 2), travel[::-1])
    np.testing.assert_allclose(again[::-1], forward, rtol=1e-8)
    assert np.all(np.diff(forward[np.argsort(travel)]) > 0)
