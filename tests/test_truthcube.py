"""The Truth Cube's model, fit and study (experiments/truthcube/, docs/truthcube.md).

Fast: the frame puts the base at w = 0; the forward solution on a 3 x 3 x 3 subsample
of inner beads behaves as a bonded compressed block must; a synthetic twin (the model's
own beads at a known nu and plate, with noise) gives nu back within its standard error;
the scikit-fem twins (``cubetwin``: bonded and frictionless plate) name their planted
contact out of sample and give nu back.
Slow: the twins on the study's grid; the whole study on the data.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from experiments.truthcube.cubefit import CubeSolver, fit_cube, layer_bulge
from experiments.truthcube.cubemodel import (
    CubeData,
    CubeSettings,
    cube_model,
    lattice_scatter,
    load_truth_cube,
    plate_displacement,
    plate_points,
)

SMALL = CubeSettings((5, 5, 5), 2, 8)
"""A grid small enough for tests of a second or two."""


@pytest.fixture(scope="module")
def data() -> CubeData:
    return CubeData.of(load_truth_cube())


@pytest.fixture(scope="module")
def inner(data) -> CubeData:
    """Beads 2, 4, 6 along each index: a 3 x 3 x 3 subsample away from the faces."""
    index = load_truth_cube().index
    keep = np.all(np.isin(index, (2, 4, 6)), axis=1)
    assert keep.sum() == 27
    return data.subset(keep)


def test_the_frame_puts_the_base_at_w_0_and_the_beads_inside(data):
    cube = load_truth_cube()
    w = data.params[:, 2]
    assert np.all((data.params > 0) & (data.params < 1))
    # the file's largest z (k = 1 beads) is the base: smallest w
    assert w[cube.index[:, 2] == 1].mean() < 0.2 < 0.8 < w[cube.index[:, 2] == 7].mean()
    # compression moves the beads towards the base: w falls, z' falls
    assert np.all(np.nanmean(data.displacement[..., 2], axis=1) < 0)


def _bead_displacement(settings, nu, data, translation, energy="linear"):
    solver = CubeSolver(cube_model(settings, energy, nu), data)
    solution = solver.equilibrium(nu, np.asarray(translation, dtype=float))
    return solver.positions(solution) - solver.rest_points, solver, solution


def test_forward_solution_on_inner_beads_is_a_compressed_bonded_block(inner):
    travel = 8.0
    u, solver, solution = _bead_displacement(SMALL, 0.45, inner, (0.0, 0.0, -travel))
    w = inner.params[:, 2]
    layers = np.unique(np.round(w, 1))
    mean_uz = np.array([u[np.round(w, 1) == layer, 2].mean() for layer in layers])
    # the beads move towards the base, less than the plate, more the nearer the plate
    assert np.all(mean_uz < 0) and np.all(-mean_uz < travel)
    assert np.all(np.diff(-mean_uz) > 0)
    # the block bulges: beads off the centre move outwards in x and y
    centre = np.array([0.0, 0.0])
    outward = np.sum(u[:, :2] * (inner.rest[:, :2] - centre), axis=1)
    middle = np.abs(w - 0.5) < 0.2
    assert np.all(outward[middle & (np.linalg.norm(inner.rest[:, :2], axis=1) > 10)] > 0)
    # the plate face moves with the plate
    top = np.column_stack([np.full(5, 0.3), np.linspace(0.1, 0.9, 5), np.ones(5)])
    moved = solver.model.volume.collocation(top) @ (solution.positions - solver.model.rest)
    assert np.allclose(moved, [0.0, 0.0, -travel], atol=1e-8)
    # linear energy: twice the travel, twice the displacement
    double, _, _ = _bead_displacement(SMALL, 0.45, inner, (0.0, 0.0, -2 * travel))
    assert np.allclose(double, 2 * u, atol=1e-9)
    # a more nearly incompressible block bulges more
    stiffer, _, _ = _bead_displacement(SMALL, 0.49, inner, (0.0, 0.0, -travel))
    assert np.mean(np.abs(stiffer[middle, :2])) > np.mean(np.abs(u[middle, :2]))


def test_neo_hookean_matches_linear_at_small_travel_and_departs_at_large(inner):
    small = (0.0, 0.0, -0.2)
    linear, _, _ = _bead_displacement(SMALL, 0.45, inner, small)
    hyper, _, _ = _bead_displacement(SMALL, 0.45, inner, small, "neo-hookean")
    assert np.max(np.abs(hyper - linear)) < 0.005 * np.max(np.abs(linear))
    large = (0.0, 0.0, -14.6)
    linear, _, _ = _bead_displacement(SMALL, 0.45, inner, large)
    hyper, _, _ = _bead_displacement(SMALL, 0.45, inner, large, "neo-hookean")
    assert np.max(np.abs(hyper - linear)) > 0.02 * np.max(np.abs(linear))


@pytest.mark.parametrize("energy, slip", [("linear", True), ("neo-hookean", False)])
def test_a_synthetic_twin_gives_nu_back_within_its_standard_error(data, energy, slip):
    """Beads of the model itself at nu = 0.46 and known plates (translations, and a
    lateral stretch of the face when it slips), with 0.1 mm noise."""
    rng = np.random.default_rng(7)
    nu_true, noise = 0.46, 0.1
    plates = np.array([[0.1, -1.5, -4.5], [0.5, -2.0, -10.8], [0.6, -2.1, -16.2]])
    if slip:
        plates = np.column_stack([plates, [0.02, 0.04, 0.06]])
    solver = CubeSolver(cube_model(SMALL, energy, nu_true), data, slip=slip)
    loaded = []
    for plate in plates:
        solution = solver.equilibrium(nu_true, plate)
        loaded.append(solver.positions(solution) + rng.normal(0.0, noise, data.rest.shape))
    twin = CubeData(
        data.frame,
        solver.rest_points,
        np.array(loaded),
        data.params,
        data.labels,
        data.nominal_travel,
    )
    fitted = fit_cube(CubeSolver(cube_model(SMALL, energy), twin, slip=slip), nu0=0.4)
    assert abs(fitted.nu - nu_true) < 3 * fitted.nu_se
    assert fitted.nu_se < 0.01
    assert fitted.translations.shape == plates.shape
    assert np.all(np.abs(fitted.translations - plates) < 3 * fitted.translation_se + 1e-9)
    # the residual is the noise: RMS distance about sqrt(3) x 0.1 mm
    assert np.allclose(fitted.rms_mm, np.sqrt(3) * noise, rtol=0.15)


def test_a_slipping_plate_face_stretches_and_b_0_is_the_bonded_plate(inner):
    model = cube_model(SMALL, "linear")
    bonded = plate_displacement(model, [0.0, 0.0, -5.0])
    assert np.allclose(plate_displacement(model, [0.0, 0.0, -5.0, 0.0]), bonded)
    stretched = plate_displacement(model, [0.0, 0.0, -5.0, 0.1])
    points = plate_points(model)
    assert np.allclose(stretched[:, :2], 0.1 * points[:, :2]) and np.allclose(stretched[:, 2], -5)
    # the layer under a slipping plate expands more than under a bonded one
    solver = CubeSolver(model, inner, slip=True)
    layer = np.round(inner.params[:, 2] * 8).astype(int)
    expansion = []
    for b in (0.0, 0.05):
        moved = solver.positions(solver.equilibrium(0.45, [0.0, 0.0, -8.0, b]))
        expansion.append(layer_bulge(inner.rest, moved, layer))
    # (inner layers 2, 4, 6: the top one 20 mm below the plate); the volume it gains
    # there the lower layers give up
    assert expansion[1][-1] > expansion[0][-1] + 0.005
    assert expansion[1][0] < expansion[0][0]


def test_the_fe_plate_is_bonded_or_slides_without_friction():
    """scikit-fem's cube (``cubechecks.FemCube``): the bonded plate carries the top face
    with it; the frictionless one prescribes its height alone, and the face expands."""
    from experiments.truthcube.cubechecks import FemCube

    top = np.array([[30.0, 20.0, 80.0], [-30.0, -30.0, 80.0], [20.0, -35.0, 80.0]])
    moved = {}
    for contact in ("bonded", "frictionless"):
        fem = FemCube(3, 0.47, contact=contact)
        moved[contact] = fem.at(fem.displacement(np.array([0.0, 0.0, -8.0])), top)
        assert np.allclose(moved[contact][:, 2], -8.0)
    assert np.allclose(moved["bonded"][:, :2], 0.0)
    outward = np.sum(moved["frictionless"][:, :2] * top[:, :2], axis=1)
    assert np.all(outward > 0)


def _check_twins(twins, nu_bias):
    for twin in twins:
        decision, nu = twin["decision"], twin["fits"][twin["decision"]["named"]]
        assert decision["named"] == twin["expected"], (twin["planted"], decision)
        # nu within 3 standard errors of the noise-free twin's value, which is the
        # planted nu up to the spline's own (locking) bias
        assert abs(nu["nu"] - twin["nu_noise_free"]) < 3 * nu["nu_se"]
        assert abs(twin["nu_noise_free"] - twin["nu_planted"]) < nu_bias
        assert 0 < nu["nu_se"] < 0.005
    bonded, frictionless = twins
    # the frictionless plate is told from the bonded one beyond chance
    assert frictionless["decision"]["distinguished"]
    rms = frictionless["decision"]["left_out_rms"]
    assert rms["slip"]["all_mm"] < rms["bonded"]["all_mm"]


def test_the_scikit_fem_twins_name_their_planted_contact_and_give_nu_back():
    """Both twins (``cubetwin``: a bonded and a frictionless plate, nu 0.47, the real
    beads' lattice noise) on a 6^3-cell FE mesh and the small spline grid: the contact
    decided out of sample is the planted one, and nu comes back within 3 standard
    errors of the noise-free twin's, which this coarse quadratic grid biases low by its
    locking (measured: 0.009 and 0.011; 0.0000 and 0.0009 on the study's grid)."""
    from experiments.truthcube.cubetwin import twin_study

    twins = twin_study(load_truth_cube(), SMALL, cells=6, log=lambda line: None)
    assert [t["planted"] for t in twins] == ["bonded", "frictionless"]
    _check_twins(twins, nu_bias=0.015)


@pytest.mark.slow
def test_the_twins_on_the_study_grid_give_the_planted_nu_within_3_se():
    from experiments.truthcube.cubetwin import twin_study

    settings = CubeSettings((7, 7, 7), 3, 12)
    twins = twin_study(load_truth_cube(), settings, log=lambda line: None)
    _check_twins(twins, nu_bias=0.002)
    for twin in twins:
        nu = twin["fits"][twin["decision"]["named"]]
        assert abs(nu["nu"] - twin["nu_planted"]) < 3 * nu["nu_se"]


def test_lattice_scatter_recovers_a_known_placement_noise():
    rng = np.random.default_rng(1)
    index = np.stack(np.meshgrid(*[np.arange(1, 8)] * 3, indexing="ij"), -1).reshape(-1, 3)
    smooth = 10.0 * index + 0.05 * index**2
    scatter = lattice_scatter(index, smooth + rng.normal(0.0, 0.4, smooth.shape), order=2)
    assert np.allclose(scatter, 0.4, rtol=0.12)


@pytest.mark.slow
def test_dvs_diagnose_on_the_imported_cube_runs_the_study_and_keeps_its_promises(tmp_path):
    """``dvs import truth-cube`` then ``dvs diagnose``: the study's files, the shared
    loop's diagnosis.json, and the properties below (its time is printed, not asserted:
    the machines are shared)."""
    import json

    from experiments.command.cli import main
    from experiments.truthcube.cubemodel import truth_cube_path

    data, out = tmp_path / "cube.npz", tmp_path / "d"
    assert main(["import", "truth-cube", str(truth_cube_path()), "--out", str(data)]) == 0
    begin = time.perf_counter()
    assert main(["diagnose", str(data), "--out", str(out)]) == 0
    print(f"dvs diagnose on the Truth Cube: {time.perf_counter() - begin:.0f} s")
    for name in ("cubestudy.json", "diagnosis.json", "report.md"):
        assert (out / name).is_file()
    result = json.loads((out / "cubestudy.json").read_text())
    assert json.loads((out / "diagnosis.json").read_text())["schema"] == "dvs-diagnosis/1"
    fits = {(f["energy"], f["contact"]): f for f in result["fits"]}
    for fit in fits.values():
        assert 0.4 < fit["nu"] < 0.5 and 0 < fit["nu_se"] < 0.01
        # larger compression, larger misfit
        assert fit["rms_mm"][0] < fit["rms_mm"][-1]
        # predicting a state is never better than fitting it
        for fold, fitted in zip(fit["leave_one_out"] or [], fit["rms_mm"]):
            assert fold["rms_plate_fitted_mm"] >= fitted - 1e-6
    # the slipping plate has more freedom: it fits no worse than the bonded one
    for energy in ("linear", "neo-hookean"):
        slip, bonded = fits[(energy, "slip")], fits[(energy, "bonded")]
        assert all(s <= b + 1e-6 for s, b in zip(slip["rms_mm"], bonded["rms_mm"]))
    # the contact is decided out of sample, and the loop's base is the one named
    contact = result["contact"]
    assert contact["named"] in ("bonded", "slip") and result["loop"]["contact"] == contact["named"]
    steps = result["loop"]["steps"]
    assert steps[-1]["rms_all_mm"] <= steps[0]["rms_all_mm"] + 1e-9
