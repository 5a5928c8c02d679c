"""The linear model on one scalar factorisation equals the full Newton path.

The componentwise path (``solvers.forward.componentwise``) must give the states and the exact
sensitivities of the CasADi residual and its Newton solve, with and without prescribed
displacements, and must not build the CasADi residual at all.
"""

from __future__ import annotations

import json
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from experiments.phantom.forehead import forehead_model, probe_loads
from experiments.phantom.simulate import simulate
from experiments.problem.fitting import FitSettings, build_problem
from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import EquilibriumSolver
from solvers.forward.evaluator import casadi_to_scipy
from solvers.inverse.nested import NestedSolver
from symbolic.loads import PrescribedDisplacement

NAMES = ("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")


def _newton(model, names):
    """The full Newton path: the same model, told that it is not componentwise."""
    full = replace(model)
    full.componentwise = False
    return EquilibriumSolver(full, names)


@pytest.mark.parametrize("prescribed", [False, True])
def test_states_and_sensitivities_equal_the_newton_path(prescribed):
    model = forehead_model()
    shift = None
    if prescribed:
        uv = np.array([[0.2, 0.2], [0.8, 0.3], [0.5, 0.9]])
        model = replace(model, prescribed=PrescribedDisplacement(uv))
        shift = np.array([[0.0, 0.0, -0.1], [0.05, 0.0, 0.0], [0.0, -0.02, 0.01]])
    x = np.array([2.0, 0.25, 1.4, 1e-4, 15.0])
    force = model.generalized_force(probe_loads(model)[1])
    scalar = ScalarSystem(model, NAMES)
    factor = scalar.factor(x)
    reduce = model._constraint_rows.shape[1]
    d = np.zeros((reduce, 3)) if shift is None else shift
    state = scalar.state(factor, force, d)
    newton = _newton(model, NAMES)
    reference = newton.solve(force, x, d)
    assert np.allclose(state, reference.state, rtol=0, atol=1e-12 * np.abs(state).max())
    symbols = newton.residual.mx_in()
    derivative = ca.jacobian(newton.residual(*symbols), symbols[1])
    g_x = ca.Function("g_x", symbols, [derivative])(reference.state, x, force, d)
    g_x = casadi_to_scipy(g_x).toarray()
    expected = -reference.factor.solve(g_x)
    got = scalar.sensitivity(factor, state)
    assert np.allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    assert list(scalar.influential) == [True, True, True, False, False]


def test_the_nested_fit_builds_no_casadi_residual_and_matches_the_newton_path():
    problem = build_problem(simulate(), FitSettings(names=NAMES[:3]))
    fast = NestedSolver(problem).solve()
    assert problem._g is None  # the componentwise path never needed the CasADi residual
    slow_problem = build_problem(simulate(), FitSettings(names=NAMES[:3]))
    slow_problem.model.componentwise = False
    slow = NestedSolver(slow_problem).solve()
    assert np.allclose(fast.x, slow.x, rtol=1e-9)
    assert fast.iterations == slow.iterations


def test_auto_chooses_and_says_why(tmp_path):
    from experiments.command.cli import main

    path = tmp_path / "data.npz"
    assert main(["simulate", "--out", str(path)]) == 0
    assert main(["fit", str(path), "--out", str(tmp_path / "auto")]) == 0
    document = json.loads((tmp_path / "auto" / "result.json").read_text())
    assert document["method"] == "nested"
    assert document["method_choice"]["requested"] == "auto"
    assert "linear model" in document["method_choice"]["reason"]
    argv = ["fit", str(path), "--method", "simultaneous", "--out", str(tmp_path / "sim")]
    assert main(argv) == 0
    chosen = json.loads((tmp_path / "sim" / "result.json").read_text())
    assert chosen["method"] == "simultaneous" and chosen["method_choice"]["reason"] == "given"
    values = [
        np.array([d["parameters"][n]["value"] for n in NAMES[:3]]) for d in (document, chosen)
    ]
    assert np.allclose(*values, rtol=1e-6)
