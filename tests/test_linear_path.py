"""The linear path (one factorisation per p for every case) against Newton per case.

``solvers.forward.linearpath`` replaces, for a model linear in the state, the per-case
Newton solve and sensitivity of ``ExtendedProblem``; these tests hold its residuals,
Jacobians, score statistics and left-out predictions against that reference, on the
paper's energy and on a continuum with data from scikit-fem.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from experiments.diagnosis.diagnose import BASE_NAMES, base_settings
from experiments.phantom.designs import DIAGNOSIS_CONTACTS, DIAGNOSIS_TILT_DEG
from experiments.phantom.fe import ReferenceSlab, SlabSolution, design_cases, reference_dataset
from experiments.phantom.simulate import simulate_with_effects
from experiments.problem.fitting import FitSettings, build_problem, dataset_loads
from solvers.diagnosis import guard
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from solvers.diagnosis.stats import score_test
from solvers.forward import linearpath
from symbolic.effects.library import ALL_EFFECT_NAMES, effect_library

EFFECT_SETS = (
    (),
    ("heterogeneity",),
    ("rigid_motion", "force_direction"),
    ("base_compliance",),
    ("contact_patch", "surrounding_tissue", "contact_offset"),
    ("pre_tension", "measurement_scale"),
    ("stiffness_field", "surrounding_tissue"),
)
"""Stiffness, per-case measurement, extra state, load and observation effects."""


@pytest.fixture(scope="module")
def paper():
    """Paper's energy at k0 = 0, diagnosis design (five contacts, ten cases)."""
    options = {"contacts": DIAGNOSIS_CONTACTS, "tilt_deg": DIAGNOSIS_TILT_DEG}
    dataset = simulate_with_effects({}, seed=5, **options)
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), [])
    return problem, fit(problem), effect_library(ALL_EFFECT_NAMES)


@pytest.fixture(scope="module")
def continuum():
    """The linear-elastic continuum on scikit-fem data of another mesh (diagnosis design)."""
    slab = ReferenceSlab(elements=(12, 12, 2))
    forces, contacts = design_cases("diagnosis", slab)
    dataset = reference_dataset(slab, forces, contacts, 4.0, solver=SlabSolution(slab))
    base = build_problem(dataset, base_settings(energy="linear-elastic"))
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), [])
    return problem, fit(problem), effect_library(ALL_EFFECT_NAMES, energy="linear-elastic")


def _point(problem: ExtendedProblem, base_p: np.ndarray) -> np.ndarray:
    """x from the base fit, every theta a third of its scale (alternating signs)."""
    theta = problem.scale[base_p.size :] / 3.0
    theta = theta * np.where(np.arange(theta.size) % 2, -1.0, 1.0)
    return np.clip(np.concatenate([base_p, theta]), problem.lower, problem.upper)


def _count_factorisations(monkeypatch) -> list:
    """A list that grows by one at every sparse factorisation of the linear path (CHOLMOD
    or SuperLU, ``solvers.linalg.cholmod.factorised``) and every LU of the Newton path."""
    calls = []
    original, choose = spla.splu, linearpath.factorised

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    def counted_choice(matrix, fallback, **options):
        calls.append(1)
        return choose(
            matrix, lambda m: original(sp.csc_matrix(m), **linearpath.FACTOR_OPTIONS), **options
        )

    monkeypatch.setattr(linearpath.spla, "splu", counted)
    monkeypatch.setattr(linearpath, "factorised", counted_choice)
    return calls


def _newton(problem: ExtendedProblem) -> ExtendedProblem:
    """The same problem on the reference path (Newton and a sensitivity per case)."""
    reference = problem.with_effects(problem.effects)
    reference.linear_path = False
    return reference


@pytest.mark.parametrize("setting_name", ["paper", "continuum"])
@pytest.mark.parametrize("names", EFFECT_SETS, ids=lambda n: "+".join(n) or "base")
def test_linear_path_equals_newton_per_case(request, setting_name, names):
    """r, dr/dp, the states and r alone agree with the Newton path to 1e-10."""
    problem, base_fit, library = request.getfixturevalue(setting_name)
    chosen = [library[n] for n in names if n in library]
    extended = problem.with_effects(chosen)
    assert extended.linear_state
    assert extended.extended.stiffness_terms() is not None  # every effect has unit terms
    p = _point(extended, base_fit.p)
    r, jacobian, states = extended.evaluate(p)
    r_ref, jacobian_ref, states_ref = _newton(extended).evaluate(p)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-10 * np.abs(r_ref).max())
    scale = np.abs(jacobian_ref).max(axis=0) + 1e-300
    np.testing.assert_allclose(jacobian / scale, jacobian_ref / scale, rtol=0, atol=1e-10)
    for state, reference in zip(states, states_ref):
        np.testing.assert_allclose(state, reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    np.testing.assert_allclose(extended.residual(p), r, rtol=0, atol=1e-12 * np.abs(r).max())


def test_a_nonlinear_effect_or_energy_keeps_newton(paper):
    """k0 > 0 makes dg/ds depend on the state: no shared factorisation."""
    problem, _, library = paper
    assert problem.linear_state
    assert not problem.with_effects([library["nonlinear_stiffening"]]).linear_state


def test_one_factorisation_serves_every_case_and_sensitivity(continuum, monkeypatch):
    """One evaluation with sensitivities of ten cases: one LU, where Newton made one per
    distinct matrix and solved case by case."""
    problem, base_fit, library = continuum
    extended = problem.with_effects([library["heterogeneity"], library["rigid_motion"]])
    calls = _count_factorisations(monkeypatch)
    p = _point(extended, base_fit.p)
    extended.evaluate(p)
    assert len(calls) == 1
    extended.evaluate(p)  # the same p: the factorisation is kept
    assert len(calls) == 1
    assert len(extended.positions) == 10


def test_a_newton_steps_factorisation_serves_its_sensitivities(paper, monkeypatch):
    """Nonlinear in the state (k0 > 0): one LU per Newton step, and the last one serves
    the n_p sensitivity right-hand sides of the case (no factorisation of its own); dr/dp
    agrees with central differences of the re-solved residual."""
    problem, base_fit, library = paper
    extended = problem.with_effects([library["nonlinear_stiffening"]])
    p = _point(extended, base_fit.p)
    calls = _count_factorisations(monkeypatch)
    state, jacobian = extended.solve_state(0, p)
    steps = len(calls)
    r, dr = extended.linearise(0, p, state, jacobian)
    assert steps >= 2 and len(calls) == steps
    for j in range(p.size):
        h = 1e-6 * max(abs(p[j]), extended.scale[j])
        up, down = p.copy(), p.copy()
        up[j] += h
        down[j] -= h
        numeric = (
            extended.linearise(0, up, extended.solve_state(0, up, state)[0])[0]
            - extended.linearise(0, down, extended.solve_state(0, down, state)[0])[0]
        ) / (2 * h)
        assert np.abs(numeric - dr[:, j]).max() <= 1e-5 * max(np.abs(dr).max(), 1e-12)


@pytest.mark.parametrize("setting_name", ["paper", "continuum"])
def test_score_statistics_equal_newtons(request, setting_name):
    """Every candidate's score statistic and step, from the fit's columns plus the
    candidate's own, equal those of the full Newton linearisation."""
    problem, base_fit, library = request.getfixturevalue(setting_name)
    reference_fit = fit(_newton(problem))
    for name, effect in library.items():
        if name == "nonlinear_stiffening" or not effect.energies:
            continue
        test = score_test(base_fit, effect, base_fit.problem.sigma or 0.02)
        expected = score_test(reference_fit, effect, base_fit.problem.sigma or 0.02)
        assert test.dof == expected.dof, name
        assert test.statistic == pytest.approx(expected.statistic, rel=1e-7, abs=1e-8), name
        np.testing.assert_allclose(test.step, expected.step, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("effect", ["heterogeneity", "contact_offset", "rigid_motion"])
def test_linearised_guard_agrees_with_refits(paper, effect):
    """The left-out predictions by one Gauss-Newton step from the full fits give the
    refits' improvement to 1 %, or to well inside CLEAR_MARGIN near zero: where the
    linearised improvement decides, the refits would decide the same. Refined (the
    step taken again from where it lands) they come closer still."""
    problem, base_fit, library = paper
    new = fit(problem.with_effects([library[effect]]))
    sigma = 0.02
    approximate = guard._check(base_fit, new, sigma, {}, guard.linearised_left_out, "linearised")
    exact = guard._check(base_fit, new, sigma, {}, guard.predict_left_out, "exact")
    assert len(approximate.held_out) == 5  # one fold per contact
    error = abs(approximate.improvement - exact.improvement)
    assert error <= max(0.01 * abs(exact.improvement), 0.3 * guard.CLEAR_MARGIN), effect
    if abs(approximate.distance) >= guard.CLEAR_MARGIN:  # decided by the linearised G
        assert approximate.improves == exact.improves
    assert approximate.nuisance_after == exact.nuisance_after
    # the step taken again from where it lands: the gap shrinks (measured 17-84 fold)
    refined = guard._check(base_fit, new, sigma, {}, guard.refined_left_out, "refined")
    refined_error = abs(refined.improvement - exact.improvement)
    assert refined_error <= min(0.2 * error + 1e-3, 0.1 * guard.REFINED_MARGIN), effect


def test_guard_falls_back_to_refits_near_zero(paper, monkeypatch):
    """A linearised improvement within CLEAR_MARGIN of zero is taken again, refined; a
    refined one within REFINED_MARGIN of zero, or within STEP_FACTOR times its change by
    the second step, is decided by refits."""
    problem, base_fit, library = paper
    new = fit(problem.with_effects([library["contact_offset"]]))
    monkeypatch.setattr(guard, "CLEAR_MARGIN", 1e9)
    monkeypatch.setattr(guard, "REFINED_MARGIN", 1e9)
    check = guard.prediction_check(base_fit, new, 0.02)
    assert check.method == "exact"
    assert check.linearised_improvement is not None
    monkeypatch.setattr(guard, "REFINED_MARGIN", 0.0)
    monkeypatch.setattr(guard, "STEP_FACTOR", 1e9)  # a refined improvement too near
    assert guard.prediction_check(base_fit, new, 0.02).method == "exact"  # its change
    monkeypatch.setattr(guard, "STEP_FACTOR", 0.0)
    refined = guard.prediction_check(base_fit, new, 0.02)
    assert refined.method == "refined"
    assert refined.linearised_improvement == check.linearised_improvement
    monkeypatch.setattr(guard, "CLEAR_MARGIN", 0.0)
    assert guard.prediction_check(base_fit, new, 0.02).method == "linearised"


def test_the_guard_study_records_each_check_refitted_with_its_twins(paper):
    """``experiments.diagnosis.guardstudy`` decides a check by the refits, whatever its
    linearised improvement, records both, and puts the loop's guard back."""
    from experiments.diagnosis.guardstudy import recorded_checks
    from solvers.diagnosis import loop

    problem, base_fit, library = paper
    new = fit(problem.with_effects([library["contact_offset"]]))
    rows: list = []
    with recorded_checks(rows):
        check = loop.prediction_check(base_fit, new, 0.02)
    assert loop.prediction_check is guard.prediction_check
    twin = guard._check(base_fit, new, 0.02, {}, guard.linearised_left_out, "linearised")
    refined = guard._check(base_fit, new, 0.02, {}, guard.refined_left_out, "refined")
    assert check.method == "exact"
    assert rows == [
        {
            "effects": ["contact_offset"],
            "exact": check.improvement,
            "linearised": twin.improvement,
            "refined": refined.improvement,
            "folds": 5,
        }
    ]


@pytest.mark.parametrize("name", ("paper", "continuum"))
def test_base_compliance_rows_divided_by_c_make_k_symmetric(name, request):
    """diag(d) K with d = 1/c on the foundation's rows is symmetric positive definite, so
    CHOLMOD factorises it (``BaseCompliance.extra_row_scale``), and the solve is K's own."""
    from solvers.linalg import cholmod

    if not cholmod.available():
        pytest.skip("no CHOLMOD on this system")
    problem, base_fit, library = request.getfixturevalue(name)
    extended = problem.with_effects([library["base_compliance"]])
    p = _point(extended, base_fit.p)
    assert p[extended.slice_of("base_compliance")][0] > 0.0
    factor = extended.stiffness_factor(p)
    assert not cholmod.symmetric(factor.matrix)
    right = np.random.default_rng(0).standard_normal(factor.matrix.shape[0])
    solution = factor.solve(right)
    assert isinstance(factor._lu, cholmod.Cholesky)
    reference = spla.spsolve(factor.matrix.tocsc(), right)
    assert np.abs(solution - reference).max() <= 1e-9 * np.abs(reference).max()


@pytest.mark.parametrize("name", ("paper", "continuum"))
def test_base_compliance_at_zero_is_block_triangular_and_solved_so(name, request):
    """At c = 0 the foundation's rows are M_I Delta_I alone: dg/ds is block upper
    triangular, solved by back substitution over its two SPD diagonal blocks (CHOLMOD
    each, where available), to SuperLU's solution of the whole."""
    from solvers.linalg import cholmod

    problem, base_fit, library = request.getfixturevalue(name)
    extended = problem.with_effects([library["base_compliance"]])
    p = np.concatenate([base_fit.p, [0.0]])
    factor = extended.stiffness_factor(p)
    n = 3 * extended.extended.model.n_free
    assert factor.matrix.shape[0] > n and factor.matrix[n:, :n].count_nonzero() == 0
    right = np.random.default_rng(0).standard_normal((factor.matrix.shape[0], 3))
    solution = factor.solve(right)
    assert isinstance(factor._lu, linearpath._BlockTriangular)
    if cholmod.available():
        assert isinstance(factor._lu.first, cholmod.Cholesky)
    reference = spla.splu(factor.matrix.tocsc()).solve(right)
    assert np.abs(solution - reference).max() <= 1e-9 * np.abs(reference).max()
    coupled = extended.stiffness_factor(_point(extended, base_fit.p))  # c > 0: not split
    coupled.solve(right[:, 0])
    assert not isinstance(coupled._lu, linearpath._BlockTriangular)


def test_fits_stay_where_the_stiffness_fields_leave_the_material_stable(continuum, monkeypatch):
    """1 + sum of the fields' ``least_modulus`` bounds the relative modulus from below
    (exactly, for the gradient, at a corner of the volume); beyond it K(p) is indefinite,
    and a fit started there is brought back and never evaluates such a p."""
    from solvers.diagnosis.stability import (
        STIFFNESS_FLOOR,
        admissible,
        into_admissible,
        least_modulus,
    )
    from solvers.linalg import cholmod

    problem, base_fit, library = continuum
    extended = problem.with_effects([library["heterogeneity"], library["layering"]])
    model = extended.model
    grid = np.linspace(0.0, 1.0, 5)
    points = np.array(np.meshgrid(grid, grid, grid, indexing="ij")).reshape(3, -1).T
    fields = [f(points) for e in extended.effects for f in e.shapes(model)]
    for theta in ([0.5, -0.3, 0.0, 0.0], [0.6, 0.2, -0.3, 0.4], [-0.2, 0.1, 2.0, -0.5]):
        p = np.concatenate([base_fit.p, theta])
        modulus = 1.0 + sum(t * f for t, f in zip(theta, fields))
        assert least_modulus(extended, p) <= modulus.min() + 1e-12
    gradient = problem.with_effects([library["heterogeneity"]])
    corner = np.concatenate([base_fit.p, [-0.9, -0.9]])
    assert least_modulus(gradient, corner) == pytest.approx(-0.8)
    assert not admissible(gradient, corner)
    if cholmod.available():  # the box bounds alone let the material go unstable
        with pytest.raises(cholmod.NotPositiveDefinite):
            cholmod.Cholesky(linearpath.stiffness_matrix(gradient, corner))
        cholmod.Cholesky(linearpath.stiffness_matrix(gradient, into_admissible(gradient, corner)))
    seen = []
    evaluate = gradient.evaluate_full

    def recorded(p, *args, **kwargs):
        seen.append(least_modulus(gradient, p))
        return evaluate(p, *args, **kwargs)

    monkeypatch.setattr(gradient, "evaluate_full", recorded)
    fitted = fit(gradient, corner, max_evaluations=8)
    assert seen and min(seen) > STIFFNESS_FLOOR
    assert admissible(gradient, fitted.p)


def test_k_summed_on_a_shared_pattern_is_the_sum_of_its_terms(continuum):
    """The continuum's unit terms and the gradient's share one pattern, so K(p) is summed
    on their stored values (``linearpath.stiffness_matrix``); a depth band may cover only part
    of it and then takes the general sum. Both equal the scipy sum of c_t K_t."""
    from symbolic.sparse import term_matrix

    problem, base_fit, library = continuum
    settings = (
        (("heterogeneity",), [0.3, -0.2], True),
        (("heterogeneity", "layering"), [0.3, -0.2, 1.5, 0.4], None),  # bands: either way
    )
    for names, theta, shared in settings:
        extended = problem.with_effects([library[name] for name in names])
        p = np.concatenate([base_fit.p, theta])
        terms = extended.extended.stiffness_terms()
        matrices = [term_matrix(t) for t in terms.matrices]
        filled = [m for m in matrices if m.nnz]
        if shared is not None:
            assert all(linearpath._same_pattern(filled[0], m) for m in filled[1:]) == shared
        c = np.ravel(np.asarray(extended.numeric_of(terms.coefficients)(p)[0]))
        reference = sum(v * m for v, m in zip(c, matrices))
        summed = linearpath.stiffness_matrix(extended, p)
        difference = abs(summed - reference).max()
        assert difference <= 1e-12 * abs(reference).max()
        if shared:  # found once per set of terms; the sum never holds a term's arrays
            assert terms.shares_pattern and all(terms.shares_pattern.values())
            assert not any(np.shares_memory(summed.indices, m.indices) for m in filled)
        # a symmetric CSR K goes to CHOLMOD as it stands: the solve is K's own
        right = np.linspace(-1.0, 1.0, summed.shape[0])
        solution = linearpath._factorised(summed).solve(right)
        assert np.linalg.norm(reference @ solution - right) <= 1e-8 * np.linalg.norm(right)


def test_a_csr_matrix_that_is_not_symmetric_is_solved_as_itself():
    """``linearpath._factorised`` passes a symmetric CSR matrix's arrays to CHOLMOD as its CSC
    form; one that is not symmetric must not be read so (that would solve its transpose)."""
    rng = np.random.default_rng(3)
    n = 40
    matrix = sp.random(n, n, density=0.2, random_state=rng) + 5.0 * sp.identity(n)
    matrix = sp.csr_matrix(matrix)
    right = rng.standard_normal(n)
    solution = linearpath._factorised(matrix).solve(right)
    assert np.allclose(matrix @ solution, right, atol=1e-12)
    assert not np.allclose(matrix.T @ solution, right, atol=1e-6)


def test_a_sets_case_parts_are_those_of_its_case_effects_widened(continuum, monkeypatch):
    """Effects that change neither load nor observation (stiffness, extra state) leave a
    case's parts those of the effects that do, widened with zero columns and rows
    (``CaseParts.widened``): the same values as parts built for the whole set, and the
    smaller set's Functions built once for every set that shares it."""
    import casadi as ca

    import symbolic.effects.composition as effects

    problem, base_fit, library = continuum
    model = problem.extended
    built = []
    jacobian = ca.jacobian
    monkeypatch.setattr(ca, "jacobian", lambda *a: built.append(1) or jacobian(*a))

    def parts(names, cache):
        chosen = [library[n] for n in names]
        extended = effects.ExtendedModel(model.model, model.names, chosen, model.cases, cache)
        return extended, extended.case_parts(1)

    cache: dict = {}
    parts(("base_compliance",), cache)
    assert len(built) == 3  # the base set's load and observation, on the wider set's call
    parts(("heterogeneity",), cache)
    assert len(built) == 3  # shared
    names = ("contact_offset", "base_compliance", "heterogeneity")
    extended, widened = parts(names, cache)
    monkeypatch.setattr(effects, "changes_case", lambda effect: True)
    _, direct = parts(names, {})
    rng = np.random.default_rng(4)
    p = rng.standard_normal(extended.n_parameters)
    s = rng.standard_normal(extended.n_state)
    pairs = [(widened.load, direct.load, (p,)), (widened.observation, direct.observation, (s, p))]
    for mine, reference, inputs in pairs:
        for value, expected in zip(mine(*inputs), reference(*inputs)):
            assert value.shape == expected.shape
            np.testing.assert_array_equal(np.asarray(ca.densify(value)), ca.densify(expected))


def test_terms_of_other_patterns_are_added_into_their_union(continuum):
    """base_compliance's terms (its extra state) do not share the continuum's pattern:
    they are added into the union of the patterns, found once per set of terms
    (``linearpath._union``). K equals the scipy sum of c_t K_t, and the row scaling of K
    equals diag(d) K entry by entry."""
    from symbolic.sparse import term_matrix

    problem, base_fit, library = continuum
    for names in (("base_compliance",), ("base_compliance", "heterogeneity")):
        extended = problem.with_effects([library[name] for name in names])
        p = _point(extended, base_fit.p)
        terms = extended.extended.stiffness_terms()
        c = np.ravel(np.asarray(extended.numeric_of(terms.coefficients)(p)[0]))
        reference = sum(v * term_matrix(m) for v, m in zip(c, terms.matrices))
        summed = linearpath.stiffness_matrix(extended, p)
        assert abs(summed - reference).max() <= 1e-12 * abs(reference).max()
        unions = [k for k in terms.shares_pattern if k[0] == "union"]
        assert len(unions) == 1, unions
        again = linearpath.stiffness_matrix(extended, p)  # the union is found once
        assert [k for k in terms.shares_pattern if k[0] == "union"] == unions
        assert np.array_equal(again.data, summed.data)
        from symbolic.effects.functions import StiffnessTerms

        fresh = StiffnessTerms([], terms.coefficients)  # a CSC term: the scipy sum serves
        assert linearpath._union(fresh, 0, summed.tocsc(), [(1, 1.0, summed)]) is None
        rows = np.linspace(0.5, 2.0, summed.shape[0])
        for matrix in (summed, summed.tocsc()):
            scaled = linearpath._rows_scaled(matrix, rows)
            assert abs(scaled - sp.diags(rows) @ matrix).max() == 0.0
