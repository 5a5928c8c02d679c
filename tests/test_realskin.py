"""The real-skin extensometer study (experiments/realskin*.py): mathematics and key numbers.

Without data: the closed-form Jacobians equal CasADi's AD, the DIC observation uses x
and y only, and the slab/pad geometry is right. With data (``shared_data``): healthy
skin's stiffening k0 cuts the force error, the keloid is found stiffer than its
surroundings. The full study (both cases, every stage and variant) is marked slow.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

from experiments.realskin_model import (
    REGION_RATIO,
    Pads,
    SkinSlabModel,
    polygon_distance,
    region_indicator,
    slab_volume,
    surface_uv,
)
from experiments.realskin_solve import PlanarProblem
from experiments.realskin_stages import standard_errors
from experiments.skindata import Rect
from solvers.problem import LoadCase, ParameterSpace
from symbolic.model import BoundaryConditions
from symbolic.stiffening import exponential_stiffening

REGION = Rect(0.0, -5.0, 100.0, 45.0)
MOVING, FIXED = Rect(26.0, 16.0, 34.0, 24.0), Rect(66.0, 16.0, 74.0, 24.0)
STRIP = np.array([[30.0, 16.0], [70.0, 16.0], [70.0, 24.0], [30.0, 24.0]])


def small_model(boundary: BoundaryConditions, **options) -> tuple[SkinSlabModel, Pads]:
    """A 9 x 5 x 2 slab over the 100 x 50 mm region, pads of the healthy .geo."""
    pads = Pads.build(REGION, MOVING, FIXED, per_side=3)
    model = SkinSlabModel(
        slab_volume(REGION, 2.0, (9, 5)),
        {"alpha_u": 0.01, "alpha_w": 0.05, "k0": 0.3},
        boundary,
        prescribed=pads.prescribed,
        isotropic=True,
        region=region_indicator(REGION, STRIP),
        **options,
    )
    return model, pads


@pytest.mark.parametrize(
    "boundary", [BoundaryConditions(True, False), BoundaryConditions(False, True)]
)
@pytest.mark.parametrize("names", [("alpha_u",), ("alpha_u", "k0", REGION_RATIO)])
def test_closed_form_jacobian_equals_automatic_differentiation(boundary, names):
    model, pads = small_model(boundary, stiffening=exponential_stiffening)
    residual = model._residual(names)
    s, x, force, d = residual.mx_in()
    automatic = ca.Function("ad", [s, x, force, d], [ca.jacobian(residual(s, x, force, d), s)])
    rng = np.random.default_rng(1)
    state = rng.normal(scale=0.5, size=residual.size1_in(0))
    values = np.array([0.012, 0.4, 3.0])[: len(names)]
    args = (state, values, np.zeros((model.n_free, 3)), pads.displacement([-2.0, 0.1]))
    closed, d_x = model.jacobian_function(names)(*args)
    assert np.allclose(closed.full(), automatic(*args).full(), atol=1e-12)
    g_x = ca.Function("gx", [s, x, force, d], [ca.jacobian(residual(s, x, force, d), x)])
    assert np.allclose(d_x.full(), g_x(*args).full(), atol=1e-12)


def test_isotropic_tension_and_region_terms():
    model, _ = small_model(BoundaryConditions(True, False))
    values = model.values({"alpha_u": 0.01, REGION_RATIO: 4.0})
    tension_x, tension_y = model.membrane_tension(values)
    assert tension_x == pytest.approx(0.02) and tension_y == pytest.approx(
        0.02
    )  # T = alpha L_x/L_y
    # with ratio 1 the region terms vanish: K equals the homogeneous K
    one = model.stiffness_matrix({REGION_RATIO: 1.0})
    plain = sum(
        model.coefficient(t, model.values()) * m for t, m in model.terms.items() if "@" not in t
    )
    assert abs(one - plain).max() < 1e-14
    # the strip's signed distance is positive inside, negative outside
    assert polygon_distance(np.array([[50.0, 20.0], [50.0, 30.0]]), STRIP) == pytest.approx([4, -6])


def test_planar_problem_sees_x_and_y_but_not_z():
    model, pads = small_model(BoundaryConditions(True, False))
    points = np.array([[45.0, 18.0], [55.0, 22.0]])
    rows = model.volume.collocation(model.volume.outer_params(surface_uv(REGION, points)))
    case = LoadCase(
        force=np.zeros((model.n_free, 3)),
        rows=rows[:, model.free].tocsr(),
        offset=np.array([[0.1, -0.2, 5.0], [0.3, 0.0, -7.0]]),
        weights=np.ones(2),
        prescribed=pads.displacement([-1.0, 0.0]),
        rest_points=rows @ model.rest,
        force_rows=sp.csr_matrix(model.point_force_rows(pads.moving_index)[:1]),
        force_target=np.array([-0.05]),
        force_weight=10.0,
    )
    problem = PlanarProblem(model, [case], ParameterSpace.create(("alpha_u",)))
    jacobian = problem.case_residual_jacobian(case)
    assert jacobian.shape == (2 * 2 + 1, problem.n_state)
    n = model.n_free
    assert abs(jacobian[:, 2 * n : 3 * n]).sum() == 0  # z of the control points is not seen
    assert np.allclose(problem.case_offset(case), [0.1, 0.3, -0.2, 0.0, 0.5])
    assert problem.n_residuals == 5


# ----------------------------------------------------------------------------- real data
@pytest.fixture(scope="module")
def healthy_fits(shared_data):
    """Healthy skin fitted with the linear model, then with k0 added."""
    from experiments.realskin import RealSkinSettings, _space, build
    from experiments.realskin_stages import fit_stage

    settings = RealSkinSettings()
    setup = build("healthy", settings)
    linear = fit_stage(
        setup.model,
        setup.cases,
        _space(setup.base_names, setup.start, settings),
        "linear",
        log=lambda *_: None,
    )
    start = {**linear.as_dict(), "k0": 0.0}
    space = _space(linear.names + ("k0",), start, settings)
    stiff = fit_stage(setup.model, setup.cases, space, "+ k0", log=lambda *_: None)
    return setup, linear, stiff


def test_healthy_stiffening_cuts_the_force_error(healthy_fits):
    """Healthy skin: adding k0 cuts the RMS force error >= 2x; the final displacement
    error is reported next to the DIC noise."""
    setup, linear, stiff = healthy_fits
    assert linear.rms_force_n / stiff.rms_force_n >= 2.0
    print(
        f"healthy RMS displacement {linear.rms_displacement_mm:.4f} -> "
        f"{stiff.rms_displacement_mm:.4f} mm, DIC noise {setup.noise_mm:.4f} mm; RMS force "
        f"{linear.rms_force_n:.4f} -> {stiff.rms_force_n:.4f} N"
    )
    assert 0.005 < setup.noise_mm < 0.03
    assert stiff.rms_displacement_mm > setup.noise_mm  # model error, not noise, dominates
    assert stiff.x[-1] > 10 * stiff.std[-1]  # k0 > 0 by far more than its standard error


@pytest.mark.xfail(
    strict=True,
    reason="measured: the displacement RMS gets 1.3 % worse (0.1099 -> 0.1113 mm) when k0 "
    "is added; the residual is dominated by the missing lateral (Poisson) contraction",
)
def test_healthy_stiffening_does_not_worsen_the_displacement_error(healthy_fits):
    _, linear, stiff = healthy_fits
    assert stiff.rms_displacement_mm <= linear.rms_displacement_mm


def test_keloid_is_stiffer_than_its_surroundings(shared_data):
    """Keloid, membrane model (lateral ring fixed): the second material inside the
    outline is stiffer (ratio > 1), and adding it is significant (likelihood ratio)."""
    from experiments.realskin import RealSkinSettings, _space, build, likelihood_ratio
    from experiments.realskin_stages import fit_stage

    settings = RealSkinSettings(boundary="lateral")
    setup = build("keloid", settings)
    linear = fit_stage(
        setup.model,
        setup.cases,
        _space(setup.base_names, setup.start, settings),
        "linear",
        log=lambda *_: None,
    )
    start = {**linear.as_dict(), REGION_RATIO: 1.0}
    space = _space(linear.names + (REGION_RATIO,), start, settings)
    region = fit_stage(setup.model, setup.cases, space, "+ region", log=lambda *_: None)
    ratio = region.as_dict()[REGION_RATIO]
    assert ratio > 10.0
    assert likelihood_ratio(linear, region) > 100.0  # chi^2_1: p < 1e-20
    assert region.rms_displacement_mm < 0.6 * linear.rms_displacement_mm


def test_standard_errors_scale_with_the_residual(shared_data):
    from experiments.realskin import RealSkinSettings, _space, build
    from experiments.realskin_solve import PlanarNestedSolver

    settings = RealSkinSettings()
    setup = build("healthy", settings)
    problem = PlanarProblem(
        setup.model, setup.cases, _space(setup.base_names, setup.start, settings)
    )
    solver = PlanarNestedSolver(problem)
    fit = solver.solve()
    std, sigma = standard_errors(solver, fit.x)
    assert sigma == pytest.approx(np.sqrt(2 * fit.cost / (problem.n_residuals - len(fit.x))))
    assert np.all(std > 0) and np.all(std < 0.1 * fit.x)


@pytest.mark.slow
def test_full_study_closes_the_loop_on_both_cases(shared_data, tmp_path):
    from experiments import realskin

    summary = realskin.run(tmp_path, log=lambda *_: None)
    healthy, keloid = summary["healthy"], summary["keloid"]
    first, last = healthy["stages"][0], healthy["stages"][-1]
    assert "k0" in last["estimates"]
    assert first["rms_force_N"] / last["rms_force_N"] >= 2.0
    assert keloid["rounds"][0]["chosen"] is not None
    final = keloid["stages"][-1]
    assert final["estimates"][REGION_RATIO]["value"] > 10.0
    assert keloid["likelihood_ratio"][-1] > 100.0
    assert keloid["stages"][0]["rms_force_N"] / final["rms_force_N"] > 5.0
    assert (tmp_path / "force_healthy.png").exists() and (tmp_path / "parameters.md").exists()
    assert summary["seconds"] < 600
