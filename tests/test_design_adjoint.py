"""The design pool's fast path (issue 39): per-contact patches (eq. D8), the states from
the independent loads and the sensitivities from the shared marker rows (eq. D9) equal
the diagnosis's linear path; ``dvs design``'s model options refuse bad values."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.command.cli import main as dvs
from experiments.design.plan import dataset_presses
from experiments.design.predictions import NOISE_MM, base_fit, phantom_dataset
from experiments.diagnosis.diagnose import base_settings
from solvers.design import adjoint
from solvers.design.candidates import candidate_presses, contact_grid
from solvers.design.pressloads import press_loads
from solvers.diagnosis.extended import ExtendedProblem
from solvers.forward import linearpath
from solvers.inverse.problem import InverseProblem, observation_case
from symbolic.effects.library import make_effect


@pytest.fixture(scope="module")
def presses():
    """A linear-elastic base fit on 6x6x3 and 30 presses at 3 contacts, as the pool
    poses them (the markers a press hides are dropped), and the markers' (u, v)."""
    dataset = phantom_dataset({}, 1, "diagnosis", NOISE_MM)
    fit = base_fit(dataset, base=base_settings((6, 6, 3), "linear-elastic", (3, 3, 2), 5.0))
    model = fit.problem.model
    uv, _ = model.volume.project_to_outer(dataset.outer_rest.reshape(-1, 3))
    own, _ = dataset_presses(dataset, model)
    chosen = candidate_presses(model, contact_grid(uv, 2)[:3], (0.17, 0.25), 20.0, 4, 4.0)
    rest = model.volume.collocation(model.volume.outer_params(uv)) @ model.rest
    loads = press_loads(chosen, model.volume)
    cases = []
    for k, load in enumerate(loads):
        observed = rest.copy()
        observed[k % 7 :: 11] = np.nan  # a different loss per press
        cases.append(observation_case(model, load, observed, uv))
    base = fit.problem.base
    problem = ExtendedProblem(
        InverseProblem(model, cases, base.space, base.noise_mm, base.rest_noise), loads, []
    )
    return fit, chosen, problem, own, uv


def test_known_loads_are_the_presses_loads(presses):
    fit, chosen, problem, own, _ = presses
    volume = fit.problem.model.volume
    for press, load in zip(chosen + own, press_loads(chosen + own, volume)):
        expected = press.load().generalized(volume)
        assert np.allclose(load.generalized(volume), expected, rtol=0, atol=1e-15)


def test_the_fast_evaluation_is_the_linear_path(presses):
    fit, _, problem, _, _ = presses
    x = fit.p
    assert problem.linear_state
    r, jacobian, states, _ = problem.evaluate_full(x)
    for by_adjoint in (True, False):
        factor = problem.stiffness_factor(x)
        fast_states = adjoint.equilibria(problem, x, factor)
        assert np.allclose(fast_states, np.column_stack(states), rtol=1e-10, atol=1e-14)
        fast_r, fast_jacobian = adjoint.linearise(
            problem, x, fast_states, factor, adjoint=by_adjoint
        )
        assert np.allclose(fast_r, r, rtol=1e-10, atol=1e-14)
        scale = np.abs(jacobian).max()
        assert np.allclose(fast_jacobian, jacobian, rtol=1e-9, atol=1e-12 * scale)


@pytest.mark.parametrize("name", ["heterogeneity", "base_compliance", "force_direction"])
def test_the_effect_columns_and_signal_are_the_linear_path(presses, name):
    """A candidate's columns at theta = 0 (only its own, on the linear path) and the
    residual at its magnitude, with extra state (base_compliance: K is not symmetric,
    the forward path serves) and without."""
    fit, _, problem, _, _ = presses
    effect = make_effect(name)
    extended = problem.with_effects([effect])
    p = np.concatenate([fit.p, np.zeros(len(extended.labels) - fit.p.size)])
    n_state = extended.extended.n_state
    _, _, states, _ = problem.evaluate_full(fit.p)
    padded = np.column_stack([np.concatenate([s, np.zeros(n_state - s.size)]) for s in states])
    block = extended.slice_of(name)
    columns = np.arange(block.start, block.stop)
    factor = extended.stiffness_factor(p)
    reference = np.vstack(linearpath.linearise(extended, p, padded, factor, columns)[1])
    _, fast = adjoint.linearise(extended, p, padded, factor, columns, adjoint=True)
    scale = np.abs(reference[:, block]).max()
    assert np.allclose(fast[:, block], reference[:, block], rtol=1e-9, atol=1e-12 * scale)
    p[block] = effect.true_parameters(effect.default_magnitude, 1)
    expected = extended.residual(p)
    assert np.allclose(adjoint.residual(extended, p), expected, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize(
    "options, message",
    [
        (["--degrees", "3x3"], "--degrees must look like 3x3x1"),
        (["--margin", "-2"], "--margin must be a width in [0, 100] mm"),
        (["--grid", "3x3x2", "--degrees", "3x3x2"], "need at least 4x4x3 control points"),
        (["--energy", "elastic"], "invalid choice"),
    ],
)
def test_bad_model_options_exit_2_with_one_line(tmp_path, capsys, options, message):
    dataset = tmp_path / "d.npz"
    dataset.write_bytes(b"")
    try:
        code = dvs(["design", str(dataset), "--out", str(tmp_path / "out"), *options])
    except SystemExit as stop:  # argparse's own checks (--energy's choices)
        code = stop.code
    error = capsys.readouterr().err.strip()
    assert code == 2
    assert "\n" not in error and message in error


def test_the_sequential_loop_takes_no_other_energy(tmp_path, capsys):
    code = dvs(["design", "--sequential", "none", "--energy", "dnurbs", "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in error and "step 0 chooses (auto)" in error


@pytest.mark.parametrize(
    "names, expected",
    [(("force_direction",), 0), (("heterogeneity", "force_direction", "contact_offset"), 1)],
)
def test_the_pool_factorises_only_where_an_effect_changes_k(presses, monkeypatch, names, expected):
    """The pool solves every press on the fit's factorisation of K(x); an effect's signal
    at its magnitude needs one more only where it changes K (heterogeneity), not where
    it moves the load (force_direction, contact_offset), whatever effect came before."""
    from solvers.design.pool import InformationPool
    from tests.test_linear_path import _count_factorisations

    fit, chosen, _, _, uv = presses
    effects = [(make_effect(n), make_effect(n).default_magnitude) for n in names]
    seen = [np.ones(len(uv), dtype=bool)] * len(chosen)
    reference = InformationPool(fit, uv, effects)
    reference.add(chosen, seen)  # warms the fit's factorisation and the functions
    calls = _count_factorisations(monkeypatch)
    pool = InformationPool(fit, uv, effects)
    pool.add(chosen, seen)
    assert len(calls) == expected
    total, again = pool.totals(range(len(chosen))), reference.totals(range(len(chosen)))
    assert np.allclose(total.matrix(), again.matrix(), rtol=1e-12, atol=0.0)
