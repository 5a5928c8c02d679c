"""The authors' planar fit of the extensometer, reproduced (docs/realskin.md, "Reproducing
the authors"): the energy's derivatives, closed-form stretches, the sensitivities, their
frame rule, and their healthy values on our own mesh.

The energy and mesh tests need no data; the rest read ``../shared/data`` and skip when
it is absent. The reproduction asserts against the authors' published values (issue 41:
E within 10 %, nu within 0.03), not against our own earlier output.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import exit_code_and_stderr
from planarchecks import check_tangent_and_residual, healthy_mesh
from scipy.optimize import brentq
from scipy.spatial import Delaunay

from experiments.realskin import authors, mesh2d
from experiments.realskin.planar import Assumptions, Extensometer, newton
from experiments.realskin.reproduce import Setting, gradient_at, main, problem, run_fit
from symbolic.planar_neohookean import PlanarNeoHookean, lame

QUIET = {"log": lambda *a: None}


@pytest.fixture(scope="module")
def coarse():
    return healthy_mesh()


def _random_state(mesh, plane, seed=0):
    rng = np.random.default_rng(seed)
    model = PlanarNeoHookean(mesh.points, mesh.triangles, plane)
    model.set_parameters(
        rng.uniform(0.02, 0.1, mesh.n_triangles), rng.uniform(0.1, 0.45, mesh.n_triangles)
    )
    return model, 0.05 * rng.normal(size=2 * mesh.n_nodes), rng.normal(size=2 * mesh.n_nodes), rng


# ------------------------------------------------------------------ the energy
@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_tangent_and_residual_match_central_differences(coarse, plane):
    """K v against (R(u + h v) - R(u - h v)) / 2h, and R . v against the energy's."""
    model, u, v, _ = _random_state(coarse, plane)
    check_tangent_and_residual(model, u, v, tangent_rtol=1e-8, symmetry_rtol=1e-14)


@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_parameter_and_edge_force_derivatives_match_central_differences(coarse, plane):
    model, u, v, rng = _random_state(coarse, plane, seed=1)
    weights = (rng.uniform(size=coarse.n_triangles) > 0.5).astype(float)
    derivative = model.residual_derivatives(u, weights)
    young, poisson = model.young.copy(), model.poisson.copy()
    for j, h in enumerate((1e-6, 1e-6)):
        step = weights * h
        model.set_parameters(young + step * (j == 0), poisson + step * (j == 1))
        plus = model.residual(u)
        model.set_parameters(young - step * (j == 0), poisson - step * (j == 1))
        minus = model.residual(u)
        model.set_parameters(young, poisson)
        numeric = (plus - minus) / (2 * h)
        assert np.linalg.norm(numeric - derivative[:, j]) < 1e-7 * np.linalg.norm(numeric)
    normals, owners = coarse.moving_normals(), coarse.moving_owner
    by_u, _ = model.edge_force_derivatives(u, normals, owners, weights)
    h = 1e-6
    numeric = (
        model.edge_force(u + h * v, normals, owners) - model.edge_force(u - h * v, normals, owners)
    ) / (2 * h)
    assert np.abs(numeric - by_u @ v).max() < 1e-7 * np.abs(numeric).max()


def _uniaxial_closed_form(plane, young, poisson, stretch):
    """(lateral stretch, P11) of uniaxial stress along x: P22 = 0 (and P33 = 0 in plane
    stress, where lam2 = lam3 by symmetry)."""
    mu, lam = lame(young, poisson)
    if plane == "strain":
        lateral = brentq(
            lambda s: mu * (s - 1 / s) + lam * np.log(stretch * s) / s, 0.5, 1.5, xtol=1e-15
        )
        volume = stretch * lateral
    else:
        lateral = brentq(
            lambda s: mu * (s * s - 1) + lam * np.log(stretch * s * s), 0.5, 1.5, xtol=1e-15
        )
        volume = stretch * lateral**2
    return lateral, mu * (stretch - 1 / stretch) + lam * np.log(volume) / stretch


@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_homogeneous_stretch_of_a_strip_matches_the_closed_form(plane):
    """A 10 x 5 mm strip pulled 20 % by its ends, free at its sides: Newton's equilibrium
    has the closed-form lateral stretch and end force, and the small-strain limit gives
    E and nu (plane stress) or E / (1 - nu^2), nu / (1 - nu) (plane strain)."""
    young, poisson, stretch = 0.05, 0.3, 1.2
    x, y = np.meshgrid(np.linspace(0, 10, 11), np.linspace(0, 5, 6))
    points = np.c_[x.ravel(), y.ravel()]
    triangles = mesh2d.oriented(points, Delaunay(points).simplices)
    model = PlanarNeoHookean(points, triangles, plane)
    model.set_parameters(young, poisson)
    ends = np.flatnonzero((points[:, 0] == 0) | (points[:, 0] == 10))
    prescribed = np.r_[2 * ends, 1]  # ends' x, and y of the corner (0, 0)
    target = np.r_[(stretch - 1) * points[ends, 0], 0.0]
    free = np.setdiff1d(np.arange(2 * len(points)), prescribed)
    u, *_ = newton(model, np.zeros(2 * len(points)), prescribed, target, free)
    lateral, p11 = _uniaxial_closed_form(plane, young, poisson, stretch)
    top = np.flatnonzero(points[:, 1] == 5)
    assert np.allclose(u[2 * top + 1], 5 * (lateral - 1), rtol=0, atol=1e-9)
    right = np.flatnonzero(points[:, 0] == 10)
    assert model.residual(u)[2 * right].sum() == pytest.approx(5 * p11, rel=1e-9)
    eps = 1e-7
    lateral, p11 = _uniaxial_closed_form(plane, young, poisson, 1 + eps)
    modulus, ratio = (
        (young, poisson)
        if plane == "stress"
        else (young / (1 - poisson**2), poisson / (1 - poisson))
    )
    assert p11 / eps == pytest.approx(modulus, rel=1e-5)
    assert (1 - lateral) / eps == pytest.approx(ratio, rel=1e-5)


def test_the_mesh_closes_the_pads_and_refine_and_warp_keep_it_valid(coarse):
    area = mesh2d.triangle_areas(coarse).sum()
    assert area == pytest.approx(100 * 50 - 2 * 64, rel=1e-12)
    for mesh in (mesh2d.refine(coarse), mesh2d.warp_gap(coarse, 36.5)):
        assert mesh2d.triangle_areas(mesh).sum() == pytest.approx(area, rel=1e-12)
        assert np.linalg.norm(mesh.moving_normals(), axis=1).sum() == pytest.approx(32.0)
    warped = mesh2d.warp_gap(coarse, 36.5)
    assert warped.pad_fixed.x0 - warped.pad_moving.x1 == pytest.approx(36.5)
    assert np.abs(coarse.moving_normals().sum(axis=0)).max() < 1e-12  # a closed contour


# ------------------------------------------------------------- on the data
def test_the_frame_rule_picks_their_frames(shared_data):
    expected = {
        ("healthy", 3.0): list(range(2, 39, 4)),
        ("healthy", 2.0): list(range(7, 26, 2)),
        ("keloid", 3.0): list(range(7, 62, 6)),
        ("keloid", 2.0): list(range(5, 42, 4)),
    }
    for (case, travel), frames in expected.items():
        picked = authors.load_frames(case, travel)
        assert picked.indices == frames, (case, travel)
        assert np.all(np.abs(picked.pad_ux_mm) <= travel) and np.all(picked.force_n < 0)
    assert authors.frame_rule(1, 10, 4) == [1, 4, 7, 10]


@pytest.mark.parametrize(
    "setting", [Assumptions("strain", False, "traction"), Assumptions("stress", True, "reaction")]
)
def test_sensitivities_match_finite_differences_of_full_solves(shared_data, coarse, setting):
    frames = authors.load_frames("healthy", 3.0, count=3)
    extensometer = Extensometer(coarse, frames, setting)
    p = np.array([0.03, 0.2])
    solution = extensometer.solve(p)
    gradient = extensometer.jacobian(solution).T @ extensometer.residuals(solution)
    for j in range(2):
        h = 1e-5 * p[j]
        plus = extensometer.solve(p + h * np.eye(2)[j], False)
        minus = extensometer.solve(p - h * np.eye(2)[j], False)
        du = (plus.u - minus.u) / (2 * h)
        assert p[j] * np.abs(du - solution.sensitivity[:, :, j]).max() < 1e-7
        df = (plus.force - minus.force) / (2 * h)
        assert np.abs(df - solution.force_derivative[:, j]).max() < 1e-6 * np.abs(df).max()
        slope = (extensometer.cost(plus)["cost"] - extensometer.cost(minus)["cost"]) / (2 * h)
        # du/dE = 0 (only displacements are prescribed): dJ/dE is the force term alone
        assert gradient[j] == pytest.approx(slope, rel=1e-6, abs=1e-6 * np.abs(gradient).max())
    r = extensometer.residuals(solution)
    assert 0.5 * r @ r == pytest.approx(extensometer.cost(solution)["cost"], rel=1e-12)


@pytest.mark.parametrize("travel", [3.0, 2.0])
def test_healthy_skin_reproduces_the_authors_on_our_mesh(shared_data, travel):
    """Measured (h 1.0 mm, 2285 nodes): 3 mm E 0.02938, nu 0.1432; 2 mm E 0.03122,
    nu 0.1899; about 3 s each."""
    row = run_fit(Setting("healthy", travel), "authors", **QUIET)
    target = authors.ACCEPTANCE[("healthy", travel)]
    assert row["success"]
    assert abs(row["E_n_per_mm"] - target["E"]) <= 0.10 * target["E"]
    assert abs(row["nu"] - target["nu"]) <= 0.03
    assert row["mesh"]["nodes"] == 2285


def test_their_keloid_value_is_not_a_stationary_point_of_their_cost(shared_data):
    """Why the keloid is not reproduced: at their value (tag 1, skin held at their
    healthy values) their cost still falls steeply (measured gradient (-33.5, 79.8));
    the minimum lies at E ~ 0.72, nu ~ 0.02 (docs/realskin.md)."""
    setting = Setting("keloid", 3.0)
    check = gradient_at(problem(setting, authors.HELD_SKIN[3.0]), authors.KELOID[3.0][1])
    assert np.linalg.norm(check["gradient"]) > 50
    assert check["gradient"][0] < 0 < check["gradient"][1]


@pytest.mark.slow
def test_fixing_the_edge_ring_lowers_E_more_than_twice(shared_data):
    """The assumption that separates the project's membrane from the authors' model
    (measured 0.02938 -> 0.00895 N/mm on our mesh)."""
    free = run_fit(Setting("healthy", 3.0), "free", **QUIET)
    ring = run_fit(Setting("healthy", 3.0, Assumptions(fix_ring=True)), "ring", **QUIET)
    assert ring["E_n_per_mm"] < 0.5 * free["E_n_per_mm"]


# ------------------------------------------------------------------- command
def test_the_command_writes_the_table(shared_data, tmp_path):
    out = tmp_path / "authors"
    argv = ["--out", str(out), "--mesh-size", "2.5", "--variants", "force"]
    assert main(argv) == 0
    table = (out / "authors.md").read_text()
    assert "authors' assumptions" in table and "reaction force" in table
    assert (out / "authors.json").stat().st_size > 1000


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--variants", "nope"], "--variants"),
        (["--mesh-size", "0.01"], "--mesh-size"),
        (["--gap", "100"], "--gap"),
        (["--travel", "5"], "--travel"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, argv, fragment):
    out = tmp_path / "never"
    code, err = exit_code_and_stderr(main, [*argv, "--out", str(out)], capsys)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
