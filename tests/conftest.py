"""Shared pytest fixtures, and the helpers several test modules import."""

from __future__ import annotations

import os

import numpy as np
import pytest

from experiments.data.paths import shared_data_dir

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def shared_data():
    """Path of ../shared/data; skips the test with a clear message when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data not found at {path} (set DVS_SHARED_DATA to its location)")
    return path


@pytest.fixture(scope="session")
def imaging_problem():
    """The imaging tests' linear-elastic problem at 7 x 7 x 2: diagnosis-design FE data of a
    12 x 12 x 2 slab with a stiffness gradient, 0.02 mm noise (built once per session)."""
    from experiments.diagnosis.diagnose import base_settings
    from experiments.phantom.fe import ReferenceSlab, design_cases, reference_dataset
    from experiments.phantom.simulate import SimulationSettings
    from experiments.problem.fitting import build_problem

    slab = ReferenceSlab(elements=(12, 12, 2), gradient=0.5)
    forces, contacts = design_cases("diagnosis", slab)
    data = reference_dataset(
        slab, forces, contacts, 4.0, (7, 7), SimulationSettings(noise_mm=0.02, seed=3)
    )
    return build_problem(data, base_settings((7, 7, 2), "linear-elastic"))


def exit_code_and_stderr(main, argv, capsys) -> tuple[int, str]:
    """Run a command line's ``main(argv)``; its exit code (argparse exits included) and
    what it wrote to stderr."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr().err


def assert_same_solution(first, second, cost_rel: float) -> None:
    """Two methods' results for one problem agree: both converged, to the same estimate
    (1e-6 relative) and the same cost (``cost_rel`` relative)."""
    assert first.success and second.success
    assert np.allclose(first.x, second.x, rtol=1e-6, atol=0)
    assert first.cost == pytest.approx(second.cost, rel=cost_rel)


def nlp_derivatives(solver, spread_state: float, spread_parameters: float):
    """A simultaneous solver's structured d2L/dv2 (full) beside CasADi's AD of the same
    NLP, at a random point (states ~ N(0, ``spread_state``), parameters about the space's
    start) with lam_f 0.7 and random lam_g; also the point and AD's dg/dv (sparse)."""
    import casadi as ca

    nlp, space = solver.nlp, solver.problem.space
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", nlp["g"].numel())
    lagrangian = lam_f * nlp["f"] + ca.dot(lam_g, nlp["g"])
    automatic = ca.Function("h", [nlp["x"], lam_f, lam_g], [ca.hessian(lagrangian, nlp["x"])[0]])
    jacobian = ca.Function("j", [nlp["x"]], [ca.jacobian(nlp["g"], nlp["x"])])
    rng = np.random.default_rng(5)
    v = rng.normal(0.0, spread_state, nlp["x"].numel())
    count = len(space.names)
    v[:count] = space.to_internal(space.start) + rng.normal(0.0, spread_parameters, count)
    multipliers = rng.normal(0.0, 1.0, nlp["g"].numel())
    upper = solver.hessian(v, [], 0.7, multipliers).full()
    structured = upper + np.triu(upper, 1).T
    return v, automatic(v, 0.7, multipliers).full(), structured, jacobian(v).sparse()
