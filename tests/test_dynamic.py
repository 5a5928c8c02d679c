"""Dynamic inverse (docs/dynamic.md): scheme, recovery, bias, coverage, contrast."""

import numpy as np
import pytest
from conftest import assert_same_solution

from experiments.dynamics import inverse as dynamic
from experiments.dynamics.trajectories import (
    DEFAULT_FRAMES,
    DYNAMIC_NAMES,
    DYNAMIC_PHANTOM,
    DYNAMIC_TRUTH,
    build_dynamic_problem,
    simulate_dynamic,
    truth_trajectories,
)
from experiments.phantom.forehead import forehead_model, marker_uv, probe_loads
from experiments.phantom.simulate import simulate
from experiments.problem.fitting import FitSettings, build_problem
from solvers.dynamic.identifiability import analyse_dynamic
from solvers.dynamic.nested import DynamicNestedSolver
from solvers.dynamic.problem import DynamicProblem, TimeGrid, trajectory_case
from solvers.dynamic.scheme import TrapezoidalScheme
from solvers.dynamic.simultaneous import DynamicSimultaneousSolver
from solvers.inverse.identifiability import analyse
from solvers.inverse.simultaneous import IpoptSettings, SimultaneousSolver
from solvers.inverse.space import ParameterSpace
from solvers.transient.stepping import StepSettings, TransientSolver

TRUTH = np.array([DYNAMIC_TRUTH[n] for n in DYNAMIC_NAMES])
SHORT = 2e-3 * np.arange(1, 11)
"""10 frames at 500 Hz: small enough for the simultaneous NLP in a few seconds."""


def exact_problem(frames, substeps, noise=0.0, seed=0, k0=0.0) -> DynamicProblem:
    """Markers of the true phantom moved by the scheme itself; the model has the true
    geometry and starts at the paper's values (mu0 = 1e-4, gamma0 = 15, alpha0 = 0.5)."""
    truth = forehead_model(DYNAMIC_PHANTOM, {**DYNAMIC_TRUTH, "k0": k0})
    uv = marker_uv(DYNAMIC_PHANTOM)
    load = probe_loads(truth, DYNAMIC_PHANTOM)[0]
    path = truth_trajectories(truth, truth.generalized_force(load), frames, "scheme", substeps)
    rows = truth.volume.collocation(truth.volume.outer_params(uv))
    observed = (rows @ truth.rest)[None] + np.einsum(
        "mn,tnc->tmc", rows[:, truth.free].toarray(), path
    )
    observed += np.random.default_rng(seed).normal(0.0, noise, observed.shape)
    observed[:, 40] = np.nan  # the marker under the probe is not seen
    model = forehead_model(DYNAMIC_PHANTOM, parameters={"k0": k0})
    case = trajectory_case(model, load, observed, uv, label="0.25 N")
    space = ParameterSpace.create(DYNAMIC_NAMES)
    return DynamicProblem(model, [case], space, frames, substeps, noise or None)


@pytest.fixture(scope="module")
def short_noisy():
    return exact_problem(SHORT, 1, noise=0.02, seed=1)


def test_the_scheme_is_newmark_average_acceleration_with_fixed_steps():
    problem = exact_problem(DEFAULT_FRAMES[:10], 2)
    run = TrapezoidalScheme(problem.model, (), problem.grid).run(
        problem.cases[0].loads(problem.grid.nodes), []
    )
    newmark = TransientSolver(problem.model, (), "newmark").integrate(
        problem.cases[0].force, 0.01, settings=StepSettings(dt=5e-4)
    )
    assert np.allclose(newmark.times, problem.grid.nodes, rtol=0, atol=1e-12)
    stacked = newmark.displacements.transpose(0, 2, 1).reshape(len(newmark.times), -1)
    assert np.abs(stacked - run.displacements).max() < 1e-12 * np.abs(stacked).max()


def test_forward_sensitivities_are_the_derivatives_of_the_discrete_scheme():
    problem = exact_problem(SHORT, 2)
    scheme = TrapezoidalScheme(problem.model, DYNAMIC_NAMES, problem.grid)
    loads = problem.cases[0].loads(problem.grid.nodes)
    run = scheme.run(loads, TRUTH, sensitivities=True)
    for i in range(TRUTH.size):
        step = TRUTH * 0
        step[i] = 1e-6 * TRUTH[i]
        plus, minus = scheme.run(loads, TRUTH + step), scheme.run(loads, TRUTH - step)
        central = (plus.displacements - minus.displacements) / (2 * step[i])
        error = np.abs(central - run.sensitivities[:, :, i]).max()
        assert error < 1e-6 * np.abs(central).max()


def test_noise_free_trajectories_recover_the_truth_nested():
    problem = exact_problem(DEFAULT_FRAMES, 2)
    result = DynamicNestedSolver(problem).solve()
    assert result.success
    assert np.allclose(result.x, TRUTH, rtol=1e-4, atol=0)


def test_noise_free_trajectories_recover_the_truth_simultaneous():
    result = DynamicSimultaneousSolver(exact_problem(SHORT, 1)).solve()
    assert result.success and result.extra["constraint_violation"] < 1e-8
    assert np.allclose(result.x, TRUTH, rtol=1e-4, atol=0)


def test_simultaneous_and_nested_solve_the_same_discrete_problem(short_noisy):
    simultaneous = DynamicSimultaneousSolver(short_noisy).solve()
    nested = DynamicNestedSolver(short_noisy).solve()
    assert_same_solution(simultaneous, nested, cost_rel=1e-9)
    trajectories = simultaneous.extra["trajectories"][0], nested.extra["trajectories"][0]
    assert np.abs(trajectories[0] - trajectories[1]).max() < 1e-5


def test_ipopt_defaults_and_user_options_reach_the_dynamic_nlp(short_noisy):
    solver = DynamicSimultaneousSolver(
        short_noisy, IpoptSettings(max_iter=2, options={"ipopt.mumps_pivot_order": 5})
    )
    assert solver.options["ipopt.mumps_pivot_order"] == 5
    assert solver.options["ipopt.tol"] == 1e-10
    assert solver.options["ipopt.hessian_approximation"] == "exact"
    result = solver.solve()
    assert result.iterations == 2 and result.status == "Maximum_Iterations_Exceeded"
    default = DynamicSimultaneousSolver(short_noisy)
    assert default.options["ipopt.mumps_pivot_order"] == 2


@pytest.fixture(scope="module")
def cvodes_clean():
    """Noise-free trajectories from CVODES (BDF, rtol 1e-10), not from the fit's scheme."""
    return simulate_dynamic(noise_mm=0.0)


def test_data_from_a_finer_integrator_show_the_second_order_bias_of_the_scheme(cvodes_clean):
    """CVODES data fitted with the trapezoidal scheme: the bias is the scheme's
    discretisation error, and it falls 4x per halving of the step (2nd order).
    Measured: mu -3.3e-2, -9.7e-3, -2.6e-3 with 1, 2, 4 substeps; gamma +1.5e-2,
    +4.1e-3, +1.1e-3. At the default 2 substeps it stays below half a standard error
    of the 0.02 mm data."""
    biases = []
    for substeps in (1, 2, 4):
        problem = build_dynamic_problem(cvodes_clean, substeps=substeps)
        biases.append(DynamicNestedSolver(problem).solve().x / TRUTH - 1)
    biases = np.abs(np.array(biases))
    ratios = biases[:-1] / biases[1:]
    assert np.all((ratios > 2.8) & (ratios < 4.5))
    assert biases[1].max() < 1.2e-2 and biases[2].max() < 3e-3
    noisy = build_dynamic_problem(simulate_dynamic(noise_mm=0.02, seed=0))
    std = np.array([p.std for p in analyse_dynamic(noisy, TRUTH).parameters])
    assert np.all(biases[1] * TRUTH < 0.5 * std)


def test_standard_errors_cover_the_truth(cvodes_clean):
    """Over 8 seeds at 0.02 mm (noisy rest markers and frames, CVODES truth), every
    estimate lies within 3 reported standard errors and the RMS z-score is near 1
    (20 seeds: RMS z 1.37, 1.01, 1.02, 1.09, 0.79; all within 3)."""
    z = []
    for seed in range(8):
        problem = build_dynamic_problem(simulate_dynamic(noise_mm=0.02, seed=seed))
        result = DynamicNestedSolver(problem).solve()
        report = analyse_dynamic(problem, result.x)
        z.append((result.x - TRUTH) / np.array([p.std for p in report.parameters]))
    z = np.abs(np.array(z))
    assert np.all(z < 3)
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((rms > 0.4) & (rms < 1.8))


def test_trajectories_identify_mu_and_gamma_where_static_data_cannot(cvodes_clean):
    dataset = simulate_dynamic(noise_mm=0.02, seed=0)
    static_problem = build_problem(dataset, FitSettings(names=DYNAMIC_NAMES))
    static_result = SimultaneousSolver(static_problem).solve()
    static = analyse(static_problem, static_result.x, static=True).by_name()
    problem = build_dynamic_problem(dataset)
    report = analyse_dynamic(problem, DynamicNestedSolver(problem).solve().x)
    by_name = report.by_name()
    for name in ("mu", "gamma"):
        assert not static[name].identifiable and static[name].std is None
        assert static[name].note == "not identifiable from static data"
        assert by_name[name].identifiable and by_name[name].note == ""
        assert 0 < by_name[name].std < 0.1 * by_name[name].value
    assert report.rank == 5 and analyse(static_problem, static_result.x).rank == 3


def test_the_script_writes_json_and_figure(tmp_path, cvodes_clean):
    summary = dynamic.run(tmp_path, log=lambda *_: None, simultaneous=False)
    assert (tmp_path / "dynamic.json").exists() and (tmp_path / "dynamic.png").exists()
    mu = summary["dynamic"]["parameters"]["mu"]
    assert mu["identifiable"] and abs(mu["z_score"]) < 3
    assert summary["static"]["parameters"]["mu"]["note"] == "not identifiable from static data"


@pytest.mark.slow
def test_full_problem_simultaneous_agrees_with_nested(tmp_path):
    """The default experiment (40 frames at 1 kHz, 2 substeps, 0.02 mm) from the paper's
    start: both methods, 1e-6 relative."""
    summary = dynamic.run(tmp_path, log=lambda *_: None)
    assert summary["dynamic"]["simultaneous"]["success"]
    assert summary["dynamic"]["max_relative_difference"] < 1e-6


@pytest.mark.slow
def test_nonlinear_model_is_recovered_by_both_methods():
    """k0 = 50 (eq. 1): Newton in every step of the scheme, AD Jacobians, one 3 n_free
    block in the NLP. Measured: nested 7 s, simultaneous 49 s (+ 11 s build)."""
    problem = exact_problem(SHORT, 1, k0=50.0)
    assert not problem.linear
    for solver in (DynamicNestedSolver, DynamicSimultaneousSolver):
        result = solver(problem).solve(1.2 * TRUTH)
        assert result.success and np.allclose(result.x, TRUTH, rtol=1e-6, atol=0)


@pytest.mark.slow
def test_coverage_over_many_seeds():
    result = dynamic.coverage_study(range(30), log=lambda *_: None)
    assert result["within_3_std"] >= 0.97
    assert all(0.6 < v < 1.5 for v in result["rms_z"].values())


def test_bad_grids_and_datasets_are_rejected():
    with pytest.raises(ValueError, match="strictly increasing"):
        TimeGrid(np.array([0.001, 0.001]))
    with pytest.raises(ValueError, match="substeps"):
        TimeGrid(np.array([0.001]), 0)
    with pytest.raises(ValueError, match="no trajectories"):
        build_dynamic_problem(simulate())
    grid = TimeGrid(np.array([0.0, 0.001, 0.003]), 2)
    assert np.allclose(grid.nodes, [0, 5e-4, 1e-3, 2e-3, 3e-3])
    assert grid.frame_nodes.tolist() == [0, 2, 4]
