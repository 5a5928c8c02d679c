"""Transient of eq. (22): steady state, modal solution, order, SUNDIALS, optimal damping."""

import json

import numpy as np
import pytest

from experiments.phantom.forehead import TRUE_PARAMETERS, forehead_model, probe_loads
from solvers.transient.modal import StepResponse, modal_basis, optimal_damping, probe_observation
from solvers.transient.profiles import ramp_load
from solvers.transient.steadystate import compare_with_equilibrium, run_to_steady_state
from solvers.transient.stepping import StepSettings, transient_solver
from solvers.transient.sundials import integrate_casadi

PAPER_RATIO_MIN = 100.0
"""gamma = 15 is heavily overdamped: it settles more than 100 times slower than gamma*."""


@pytest.fixture(scope="module")
def linear():
    model = forehead_model()
    return model, model.generalized_force(probe_loads(model)[1])


@pytest.fixture(scope="module")
def response(linear):
    model, force = linear
    return StepResponse.build(modal_basis(model), force, probe_observation(model))


def test_nonlinear_transient_ends_at_the_static_equilibrium():
    model = forehead_model(parameters={**TRUE_PARAMETERS, "k0": 50.0})
    force = model.generalized_force(probe_loads(model)[1])
    comparison = compare_with_equilibrium(model, force)
    assert comparison["steady"]
    assert comparison["relative_distance_to_equilibrium"] < 1e-8
    assert comparison["result"].jacobian_evaluations < 20  # modified Newton reuses tangents


@pytest.mark.parametrize(("gamma", "t_end"), [(15.0, 20.0), (0.101, 0.1)])
def test_newmark_matches_the_modal_step_response(linear, response, gamma, t_end):
    # Local errors are held below 1e-6 RMS(u) per step; they add up over the tens of
    # steps per decay time, so 1e-4 of the final displacement bounds the global error
    # (measured 4.4e-6 for gamma = 15 and 2.5e-5 at critical damping, gamma = 0.101).
    model, force = linear
    solver = transient_solver(model, (), "newmark")
    settings = StepSettings(rtol=1e-6)
    result = solver.integrate(force, t_end, overrides={"gamma": gamma}, settings=settings)
    exact = response.displacement(result.times, gamma)[:, 0]
    error = np.linalg.norm(result.probe - exact, axis=1).max()
    assert error < 1e-4 * np.linalg.norm(response.final)


@pytest.mark.parametrize(
    ("method", "order"), [("newmark", 2), ("generalized_alpha", 2), ("backward_euler", 1)]
)
def test_halving_dt_shows_the_theoretical_order(linear, response, method, order):
    model, force = linear
    t_end = 0.01
    exact = response.displacement(np.array([t_end]), TRUE_PARAMETERS["gamma"])[0, 0]
    steps = t_end / np.array([32, 64, 128, 256, 512])
    solver = transient_solver(model, (), method)
    errors = [
        np.linalg.norm(
            solver.integrate(force, t_end, settings=StepSettings(dt=dt)).probe[-1] - exact
        )
        for dt in steps
    ]
    slope = np.polyfit(np.log(steps), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.2


@pytest.mark.parametrize("plugin", ["cvodes", "idas"])
def test_sundials_agrees_with_newmark_at_a_fixed_time(linear, plugin):
    # SUNDIALS runs at rtol 1e-10; Newmark at rtol 1e-7 has a global error of about
    # 1e-6 (its kink at the end of the ramp costs an order), so 1e-5 is the bound.
    model, force = linear
    load = ramp_load(force, 0.5)
    path = integrate_casadi(model, load, np.linspace(0.0, 2.0, 3), plugin=plugin)
    settings = StepSettings(rtol=1e-7)
    result = transient_solver(model, (), "newmark").integrate(load, 2.0, settings=settings)
    gap = np.linalg.norm(result.displacements[-1] - path[-1]) / np.linalg.norm(path[-1])
    assert gap < 1e-5


def test_optimal_damping_settles_faster_than_half_and_double(linear, response):
    model, force = linear
    study = optimal_damping(model, force, samples=31)
    assert study.critical_gamma == pytest.approx(2 * 5e-4 * modal_basis(model).omega[0])
    for factor in (0.5, 2.0):
        assert study.settling_time < response.settling_time(factor * study.gamma)
    transient = {
        factor: run_to_steady_state(model, force, overrides={"gamma": factor * study.gamma})
        for factor in (0.5, 1.0, 2.0)
    }
    assert transient[1.0].probe_settling_time < transient[0.5].probe_settling_time
    assert transient[1.0].probe_settling_time < transient[2.0].probe_settling_time
    assert PAPER_RATIO_MIN < response.settling_time(15.0) / study.settling_time


def test_steady_state_detection_and_settling_time(linear, response):
    model, force = linear
    result = run_to_steady_state(model, force, tol=1e-10)
    assert result.steady and result.static_residual <= 1e-10 and result.kinetic_ratio <= 1e-10
    assert result.steady_time >= result.settling_time > 0
    # the 1 % settling time of the probe agrees with the modal one (local rtol 1e-4)
    assert result.probe_settling_time == pytest.approx(response.settling_time(15.0), rel=1e-2)
    short = run_to_steady_state(model, force, t_max=5.0)
    assert not short.steady and short.steady_time is None and short.times[-1] == pytest.approx(5)


def test_overrides_reject_stiffness_parameters(linear):
    model, force = linear
    with pytest.raises(ValueError, match="mu and gamma only"):
        run_to_steady_state(model, force, overrides={"alpha_u": 1.0})


def test_experiment_writes_summary_on_the_linear_phantom(tmp_path):
    from experiments.dynamics import transient

    summary = transient.run(tmp_path, model=forehead_model(), log=lambda line: None)
    written = json.loads((tmp_path / "transient.json").read_text())
    assert written["relative_distance_to_equilibrium"] < 1e-8
    assert written["optimal_gamma"] == pytest.approx(summary["optimal_gamma"])
    assert (tmp_path / "transient.png").stat().st_size > 0
