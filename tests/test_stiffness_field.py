"""The ``stiffness_field`` effect: its prior (eq. F2), the regularised fit and its dof.

Off-at-zero and derivative checks run with every effect in tests/test_effects.py and
tests/test_continuum_loop.py; here the parts only this effect has.
"""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

from experiments.diagnosis.diagnose import BASE_NAMES
from experiments.phantom.designs import DIAGNOSIS_CONTACTS, DIAGNOSIS_TILT_DEG
from experiments.phantom.simulate import simulate_with_effects
from experiments.problem.fitting import ENERGY_NAMES, FitSettings, build_problem, dataset_loads
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from solvers.diagnosis.loop import diagnose
from solvers.diagnosis.record import DiagnosisSettings
from symbolic.effects.fieldeffect import MEAN_PIN, PRIOR_RMS, StiffnessFieldEffect
from symbolic.effects.library import EFFECT_NAMES, make_effect

SIGMA = 0.02


@pytest.fixture(scope="module")
def setting():
    """The phantom with a stiffness gradient it does not declare (10-load design: on the
    paper's, alpha absorbs it), and its base fit."""
    dataset = simulate_with_effects(
        {"heterogeneity": 0.5}, seed=4, contacts=DIAGNOSIS_CONTACTS, tilt_deg=DIAGNOSIS_TILT_DEG
    )
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    loads = dataset_loads(dataset, base.model.volume)
    problem = ExtendedProblem(base, loads, [], sigma=SIGMA)
    return problem, fit(problem)


@pytest.fixture(scope="module")
def field_fit(setting):
    problem, base_fit = setting
    effect = make_effect("stiffness_field")
    extended = problem.with_effects([effect])
    return extended, fit(extended, np.concatenate([base_fit.p, np.zeros(effect.dim)]))


def test_the_field_is_opt_in_and_named_as_in_the_design():
    assert "stiffness_field" not in EFFECT_NAMES
    assert DiagnosisSettings(candidates=("stiffness_field",)).candidates == ("stiffness_field",)
    effect = StiffnessFieldEffect((5, 3))
    assert effect.dim == 15 == len(effect.lower) == len(effect.units)


@pytest.mark.parametrize("energy", ["dnurbs", "linear-elastic"])
def test_a_constant_field_scales_the_base_stiffness(energy):
    """The phi_k sum to 1, so c = t everywhere gives K(c) = t K on the free points (eq. F1):
    the weighted blocks, restricted to each node's support, and their one combined
    product add up to the whole stiffness."""
    dataset = simulate_with_effects({}, seed=4)
    names = BASE_NAMES if energy == "dnurbs" else ENERGY_NAMES[energy]
    model = build_problem(dataset, FitSettings(names=names, energy=energy)).model
    effect = StiffnessFieldEffect((3, 4))
    theta = ca.MX.sym("theta", effect.dim)
    values = dict(model.parameters)
    stiffness = ca.Function("K", [theta], [effect.stiffness(model, values, theta)])
    t = 0.3
    scaled = sp.csc_matrix(stiffness(np.full(effect.dim, t)).sparse())
    if energy == "dnurbs":
        base = sp.kron(sp.identity(3), model.free_block(model.stiffness_matrix()))
    else:
        base = model.stiffness_matrix()
    assert abs(scaled - t * base).max() <= 1e-12 * abs(base).max()
    # one node alone is local: no stiffness outside its support
    single = sp.csc_matrix(stiffness(np.eye(effect.dim)[0]).sparse())
    assert 0 < np.count_nonzero(single.data) < base.nnz


def test_the_prior_of_a_constant_field_is_its_pinned_mean(setting):
    """grad s = 0 for a constant s = t: |R c|^2 = N t^2 / tau^2 (eq. F2), mean row t."""
    problem, _ = setting
    effect = make_effect("stiffness_field")
    factor = effect.prior(problem.model)
    t = 0.3
    c = np.full(effect.dim, t)
    smooth = factor[:-1] @ c
    assert smooth @ smooth == pytest.approx(effect.dim * t**2 / PRIOR_RMS**2, rel=1e-9)
    assert factor[-1] @ c == pytest.approx(MEAN_PIN * t / PRIOR_RMS, rel=1e-9)
    # a rough field costs more than a smooth one of the same mean square
    nodes = effect.field.nodes()
    rough = np.where((np.arange(effect.dim) + (nodes[:, 0] * 3).round()) % 2 == 0, 1.0, -1.0)
    smooth_field = np.cos(np.pi * nodes[:, 0])
    rough, smooth_field = (v / np.linalg.norm(v) for v in (rough, smooth_field))
    cost = [np.sum((factor[:-1] @ v) ** 2) for v in (rough, smooth_field)]
    assert cost[0] > cost[1]


def test_the_regularised_fit_is_stationary_for_data_and_prior_together(setting, field_fit):
    """At the estimate, J^T rho + P^T P p = 0 on the free interior entries (the posterior
    mode), so the prior rows were part of the least-squares cost."""
    extended, result = field_fit
    assert result.success, result.status
    prior = extended.prior_matrix()
    interior = result.estimated()
    derivative = extended.natural_derivative(extended.to_internal(result.p))
    data = (result.jacobian.T @ result.whitened * derivative)[interior]
    both = data + (prior.T @ (prior @ result.p) * derivative)[interior]
    # the data alone are far from stationary: the prior's pull balances them
    assert np.abs(both).max() < 1e-3 * np.abs(data).max()


def test_the_field_counts_fewer_dof_than_coefficients(setting, field_fit):
    """tr((J^T J + P^T P)^-1 J^T J) lies between the base model's count and N + base, and
    the prior narrows every standard error."""
    problem, base_fit = setting
    extended, result = field_fit
    n_base = base_fit.effective_dof()
    assert n_base == base_fit.estimated().sum()
    assert n_base < result.effective_dof() < n_base + make_effect("stiffness_field").dim - 1
    assert result.penalty > 0
    flat = replace(result, prior=None)
    assert np.all(result.standard_errors(SIGMA) <= flat.standard_errors(SIGMA) * (1 + 1e-9))


def test_a_prior_without_a_noise_level_is_refused(setting):
    problem, _ = setting
    unscaled = ExtendedProblem(problem.base, problem.loads, [make_effect("stiffness_field")])
    unscaled.sigma = None
    with pytest.raises(ValueError, match="noise level"):
        unscaled.prior_matrix()


def test_the_loop_tests_the_field_by_its_own_rules(setting):
    """A heterogeneity the data hide: the field passes the score test and the loop's rules,
    with its effective dof in the record, and its map is stiffer where h says."""
    problem, _ = setting
    settings = DiagnosisSettings(candidates=("stiffness_field",), max_effects=1)
    diagnosis = diagnose(problem.base, problem.loads, settings)
    document = diagnosis.document()
    assert diagnosis.selected == ["stiffness_field"], document["rejected"]
    step = diagnosis.steps[-1]
    record = step.record()
    assert record["effective_dof"] == pytest.approx(step.fit.effective_dof())
    assert step.residual.dof == round(step.fit.whitened.size - step.fit.effective_dof())
    effect = step.fit.problem.effects[0]
    c = step.fit.p[step.fit.problem.slice_of("stiffness_field")]
    nodes = effect.field.nodes()
    # heterogeneity 0.5 along (1, -0.5): alpha grows with u and falls with v
    slope = np.linalg.lstsq(np.column_stack([np.ones(len(c)), nodes[:, :2]]), c, rcond=None)[0]
    assert slope[1] > 0 > slope[2]
