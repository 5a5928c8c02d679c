"""The two-pad extensometer through the shared diagnosis (``solvers.diagnosis``).

The real-skin set-up (docs/realskin.md, "The experiment as a model load case") is a
``SkinSlabModel`` with both pads prescribed (Lagrange multipliers), DIC markers observed
in x and y, the moving pad's force observed through the multipliers, one load case per
frame and no applied force (``FrameLoad``). ``ExtendedProblem`` must pose exactly the
problem ``PlanarProblem`` poses, which the real-skin study solves with ``NestedSolver``:
the same residual and Jacobian at any p, on its linear path and on Newton's, and the same
fit.

Without data: a small synthetic slab built by the real-skin helpers
(``experiments.realskin.cases.load_cases``). With data (``shared_data``): today's healthy
base problem (``experiments.realskin.setup.build``).
"""

from __future__ import annotations

import numpy as np
import pytest
from effectchecks import check_derivatives, check_theta_zero, fitted_setting

from experiments.realskin.cases import FrameData, force_weight, load_cases
from experiments.realskin.geometry import Rect
from experiments.realskin.slab import Pads, slab_volume
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from solvers.diagnosis.guard import folds, halves
from solvers.inverse.nested import NestedSolver
from solvers.inverse.problem import PlanarProblem
from solvers.inverse.space import ParameterSpace
from symbolic.constraints import BoundaryConditions
from symbolic.effects.library import effect_library
from symbolic.loads import FrameLoad
from symbolic.skin_slab import SkinSlabModel
from symbolic.stiffening import exponential_stiffening

REGION = Rect(0.0, -5.0, 100.0, 45.0)
MOVING, FIXED = Rect(26.0, 16.0, 34.0, 24.0), Rect(66.0, 16.0, 74.0, 24.0)


def synthetic_problem() -> tuple[PlanarProblem, list]:
    """A 9 x 5 x 2 slab (inner layer fixed) pulled by its moving pad to 1 and 2 mm with
    DIC markers between the pads, then to 3 mm observed through the force alone: the
    base problem and its loads, made as the real-skin study makes them."""
    pads = Pads.build(REGION, MOVING, FIXED, per_side=3)
    model = SkinSlabModel(
        slab_volume(REGION, 2.0, (9, 5)),
        {"alpha_u": 0.012, "alpha_w": 0.06},
        BoundaryConditions(fix_inner=True),
        stiffening=exponential_stiffening,
        prescribed=pads.prescribed,
        isotropic=True,
    )
    x, y = np.meshgrid(np.linspace(38.0, 62.0, 5), np.linspace(12.0, 28.0, 3))
    reference = np.column_stack([x.ravel(), y.ravel()])
    rng = np.random.default_rng(5)
    share = (FIXED.x0 - reference[:, 0]) / (FIXED.x0 - MOVING.x1)  # 1 at the moving pad
    displacement = [
        np.column_stack([-t * share, 0.1 * t * (reference[:, 1] - 20.0) / 20.0])
        + rng.normal(0.0, 0.01, reference.shape)
        for t in (1.0, 2.0)
    ]
    data = FrameData(
        ["frame 1", "frame 2", "travel 3.00 mm (force only)"],
        np.array([[-1.0, 0.0], [-2.0, 0.05], [-3.0, 0.05]]),
        np.array([-0.02, -0.045, -0.08]),
        displacement + [None],
        reference,
        [1, 2, None],
    )
    cases = load_cases(model, pads, data, force_weight(data))
    space = ParameterSpace.create(
        ("alpha_u", "alpha_w"), {"alpha_u": 0.012, "alpha_w": 0.06}, {"alpha_u": (1e-5, 1e3)}
    )
    base = PlanarProblem(model, cases, space, noise_mm=0.01)
    return base, [FrameLoad(case.label) for case in cases]


def synthetic_setting(names) -> tuple:
    """The ``setting`` (``effectchecks``) of ``synthetic_problem`` with the effects
    ``names`` that extend the paper's energy (dnurbs)."""
    base, loads = synthetic_problem()
    return fitted_setting(base, loads, names, "dnurbs")


@pytest.fixture(scope="module")
def synthetic():
    """(ExtendedProblem without effects, its fit, the library) of ``synthetic_problem``."""
    return synthetic_setting(
        ("rigid_motion", "nonlinear_stiffening", "volumetric_coupling", "anisotropy")
    )


def _solver(base: PlanarProblem) -> NestedSolver:
    """The nested inverse of ``solvers.inverse`` on the planar problem: the reference (a
    frame without equilibrium shortens trf's step)."""
    return NestedSolver(base, "trf", 1e-10, 100, failures="shrink")


def _reference(base: PlanarProblem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r and dr/dp (natural units) of ``NestedSolver`` on the planar problem."""
    solver = _solver(base)
    z = base.space.to_internal(p)
    r, jacobian = solver.evaluate(z)
    return r, jacobian / base.space.natural_derivative(z)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_a_frame_load_has_no_force_and_no_contact(synthetic):
    """f = 0, F_B = 0, no contact point: each frame is its own fold; the rows of a case are
    two per marker plus its force row, which the halves keep in the first half."""
    problem, _, _ = synthetic
    assert np.all(problem.loads[0].generalized(problem.model.volume) == 0.0)
    assert folds(problem) == [[0], [1], [2]]
    assert problem.case_rows() == [2 * 15 + 1, 2 * 15 + 1, 1]
    first = halves(problem)
    assert first.size == sum(problem.case_rows()) and first[30] and first[-1]


@pytest.mark.parametrize("path", ["linear", "newton"])
def test_residual_and_jacobian_are_the_planar_problems(synthetic, path):
    """At a p away from the fit, r and dr/dp of ``ExtendedProblem`` (the multipliers'
    block in h, -Q d_k in each case's load, the force row from lam) equal
    ``NestedSolver``'s on ``PlanarProblem``, on the linear path (one LU of the KKT
    matrix for all cases) and on Newton's."""
    problem, _, _ = synthetic
    problem.linear_path = path == "linear"
    try:
        assert problem.linear_state == (path == "linear")
        p = np.array([0.015, 0.04])
        r, jacobian, _ = problem.evaluate(p)
    finally:
        problem.linear_path = True
    expected_r, expected_jacobian = _reference(problem.base, p)
    assert _relative(r, expected_r) < 1e-10
    assert _relative(jacobian, expected_jacobian) < 1e-10


def test_the_kkt_matrix_goes_to_lu_without_a_cholesky_attempt(synthetic, monkeypatch):
    """dg/ds with multipliers is symmetric but indefinite: factorised by SuperLU at once."""

    from solvers.forward import linearpath

    problem, _, _ = synthetic

    def refused(*_):
        raise AssertionError("Cholesky attempted on the KKT matrix")

    monkeypatch.setattr(linearpath, "factorised", refused)
    problem.cache.pop("last_state_jacobian", None)
    problem.evaluate(np.array([0.013, 0.05]))


@pytest.mark.parametrize(
    "name", ["rigid_motion", "nonlinear_stiffening", "volumetric_coupling", "anisotropy"]
)
def test_effects_on_the_extensometer_are_off_at_zero(synthetic, name):
    """A per-case observation effect (rigid motion: the case parts widened around the
    multipliers), the stiffening (Newton) and the two linear membrane effects: g and r at
    theta = 0 are the base's."""
    check_theta_zero(synthetic, name, solved_atol=1e-10)


@pytest.mark.parametrize("name", ["volumetric_coupling", "anisotropy"])
def test_membrane_effect_derivatives_on_the_extensometer(synthetic, name):
    check_derivatives(synthetic, name)


def test_the_shared_membrane_effects_are_the_slabs_own_terms(synthetic):
    """volumetric_coupling at lambda on the slab is its in-plane Poisson coupling at
    c = lambda t / T_x (its C of lateral contraction, eq. of ``coupling_matrix``), and
    anisotropy at a is its tension ratio T_y / T_x = 1 + a: the same K on every control
    point."""
    import dataclasses

    from symbolic.skin_slab import ANISOTROPY, POISSON

    problem, base_fit, library = synthetic
    model = problem.model
    values = model.values(dict(zip(problem.names, base_fit.p)))
    free = lambda m: m.tocsr()[model.free][:, model.free]  # noqa: E731
    tension = model.membrane_tension(values)[0]
    thickness = float(np.ptp(model.rest[:, 2]))
    lam = 0.03
    volumetric = library["volumetric_coupling"].matrix(model)
    coupling = model.coupling_coefficients({**values, POISSON: lam * thickness / tension})[0]
    expected = coupling * model.couplings["div"]
    assert _relative((lam * volumetric).toarray(), expected.toarray()) < 1e-12
    a = 0.7
    stiffer = dataclasses.replace(model, anisotropy=1.0 + a)
    added = library["anisotropy"].stiffness_terms(model)[0]
    c_v = model.coefficient("alpha_v", values)
    k_base = sum(model.coefficient(t, values) * m for t, m in model.terms.items() if "@" not in t)
    k_after = sum(
        stiffer.coefficient(t, stiffer.values({**values, ANISOTROPY: 1.0 + a})) * m
        for t, m in stiffer.terms.items()
        if "@" not in t
    )
    componentwise = np.kron(np.eye(3), free(k_after - k_base).toarray())
    assert _relative(a * c_v * added.toarray(), componentwise) < 1e-12


def test_rigid_motion_derivatives_on_the_extensometer(synthetic):
    """dr/dp with rigid motion against central differences, of 1e-3 of a scale: the
    markers lie 10-90 mm from the origin, and a rotation of 1e-8 rad moves them by less
    than the rounding of their positions allows to difference."""
    check_derivatives(synthetic, "rigid_motion", theta_step=1e-3)


def test_stiffening_derivatives_on_the_extensometer(synthetic):
    """dr/dp with nonlinear_stiffening (Newton with the multipliers) against differences
    of 1e-4 in k0, at k0 = 0 (one-sided) and at 0.3, a real-skin value (the synthetic
    slab's coarse pads strain it far beyond skin's at the library's test point, 7)."""
    problem, base_fit, library = synthetic
    extended = problem.with_effects([library["nonlinear_stiffening"]])
    step = np.r_[0.0, 0.0, 1e-4]
    for k0 in (0.0, 0.3):
        p = np.r_[base_fit.p, k0]
        r, jacobian, _ = extended.evaluate(p)
        plus = extended.evaluate(p + step)[0]
        if k0 == 0.0:
            numeric = (4 * plus - 3 * r - extended.evaluate(p + 2 * step)[0]) / 2e-4
        else:
            numeric = (plus - extended.evaluate(p - step)[0]) / 2e-4
        assert _relative(numeric, jacobian[:, 2]) < 1e-5


def _continuation_agrees(problem: ExtendedProblem, position: int, p: np.ndarray) -> None:
    """Newton from rest fails on the case at ``position``; with the load continuation
    ``solve_state`` reaches g = 0 to its tolerance, and the state is
    ``EquilibriumSolver.solve_by_continuation``'s (displacements, then multipliers)."""
    from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver

    problem.forget_solves()  # from rest, not from a solve kept at another p
    with pytest.raises(EquilibriumError):
        problem.solve_state(position, p, continuation=False)
    problem.forget_solves()
    state, _ = problem.solve_state(position, p)
    equilibrium = problem.numeric(position, "equilibrium")
    g, rest = (equilibrium(s, p)[0].ravel() for s in (state, np.zeros_like(state)))
    assert np.linalg.norm(g) <= 1e-10 * np.linalg.norm(rest)
    case = problem.cases[position]
    solver = EquilibriumSolver(problem.model, ("alpha_u", "alpha_w", "k0"))
    reference = solver.solve_by_continuation(case.force, p, case.prescribed).state
    n = 3 * problem.model.n_free
    assert _relative(state[:n], reference[:n]) < 1e-8
    assert _relative(state[n:], reference[n:]) < 1e-6


def test_load_continuation_reaches_the_equilibrium_newton_misses(synthetic):
    """The stiffening at k0 = 0.8 on the synthetic slab's 3 mm travel: Newton from rest
    fails, the load continuation reaches the study's equilibrium."""
    problem, base_fit, library = synthetic
    extended = problem.with_effects([library["nonlinear_stiffening"]])
    _continuation_agrees(extended, 2, np.r_[base_fit.p, 0.8])


def test_fit_steps_back_from_a_failed_equilibrium(synthetic, monkeypatch):
    """An equilibrium that fails during trf is a NaN residual (trf shortens its step), not
    the end of the fit: with the second evaluation failing, the fit ends where it ends
    without the failure."""
    from solvers.forward.equilibrium import EquilibriumError

    problem, base_fit, _ = synthetic
    start = np.array([0.03, 0.2])
    expected = fit(problem, start)
    original, calls = problem.evaluate_full, []

    def failing_once(p, starts=None):
        calls.append(1)
        if len(calls) == 2:
            raise EquilibriumError("no equilibrium here")
        return original(p, starts)

    monkeypatch.setattr(problem, "evaluate_full", failing_once)
    fitted = fit(problem, start)
    assert len(calls) > 2 and fitted.success
    np.testing.assert_allclose(fitted.p, expected.p, rtol=1e-6)
    np.testing.assert_allclose(fitted.p, base_fit.p, rtol=1e-6)


# ----------------------------------------------------------------------------- real data
@pytest.fixture(scope="module")
def healthy(shared_data):
    """The healthy base problem of the real-skin study (``setup.build``), fitted by the
    nested inverse of ``solvers.inverse`` (the reference) and, posed as an
    ``ExtendedProblem`` without effects, by ``solvers.diagnosis.fit.fit``."""
    from experiments.realskin.setup import RealSkinSettings, build

    setup = build("healthy", RealSkinSettings())
    reference = _solver(setup.base).solve()
    problem = ExtendedProblem(setup.base, setup.loads, [])
    return setup, reference, problem, fit(problem)


@pytest.mark.realdata
def test_the_shared_fit_is_the_nested_inverses(healthy):
    """The shared fit ends where ``NestedSolver`` does: the same alpha and cost (|r|^2
    against its |r|^2 / 2); six DIC frames and four force-only travels, each its own
    fold. Printed: the RMS in-plane displacement per component and the RMS pad force."""
    setup, reference, problem, fitted = healthy
    rms = problem.rms(fitted.residual)[0] / np.sqrt(len(problem.base.observed))
    force = problem.force_rms(fitted.residual)
    print(f"alpha {fitted.p} ({reference.x}), RMS {rms:.6f} mm, force {force:.6f} N")
    assert fitted.success and problem.linear_state
    np.testing.assert_allclose(fitted.p, reference.x, rtol=1e-7)
    assert fitted.cost == pytest.approx(2.0 * reference.cost, rel=1e-8)
    assert folds(problem) == [[k] for k in range(len(setup.loads))]


@pytest.mark.realdata
@pytest.mark.parametrize("path", ["linear", "newton"])
def test_healthy_residual_and_jacobian_are_the_nested_solvers(healthy, path):
    """r and dr/dp at a p off the fit equal ``NestedSolver``'s on the study's
    ``PlanarProblem`` to 1e-8, on the linear path and on Newton's."""
    _, _, problem, _ = healthy
    p = np.array([0.015, 0.05])
    problem.linear_path = path == "linear"
    try:
        r, jacobian, _ = problem.evaluate(p)
    finally:
        problem.linear_path = True
    expected_r, expected_jacobian = _reference(problem.base, p)
    print(f"r {_relative(r, expected_r):.1e}, J {_relative(jacobian, expected_jacobian):.1e}")
    assert _relative(r, expected_r) < 1e-8
    assert _relative(jacobian, expected_jacobian) < 1e-8


@pytest.mark.realdata
def test_the_stiffening_score_test_sees_the_force_curves_bend(healthy):
    """The score test of ``nonlinear_stiffening`` at the linear fit: one-sided, a step to
    k0 > 0 (skin stiffens), and significant far beyond the Bonferroni level even over the
    model error's dispersion (the loop's rule)."""
    from solvers.diagnosis.guard import left_out
    from solvers.diagnosis.stats import score_test

    setup, _, problem, fitted = healthy
    effect = effect_library(("nonlinear_stiffening",))["nonlinear_stiffening"]
    phi = left_out(fitted, setup.noise_mm).dispersion
    test = score_test(fitted, effect, setup.noise_mm * np.sqrt(phi))
    print(f"T {test.statistic:.6g} over dispersion {phi:.4g}, k0 step {test.step[0]:.4g}")
    assert phi > 10.0  # model error dominates the DIC noise
    assert test.dof == 1 and test.step[0] > 0.0 and not test.note
    assert test.log_p < np.log(0.01 / 4)


@pytest.mark.realdata
@pytest.mark.slow
def test_load_continuation_at_the_longest_healthy_travel(healthy):
    """Healthy skin at the longest force-only travel (8.42 mm) with k0 = 1 and the linear
    fit's tensions: Newton from rest fails, the load continuation reaches the equilibrium
    ``EquilibriumSolver`` reaches."""
    _, _, problem, _ = healthy
    last = len(problem.cases) - 1
    effect = effect_library(("nonlinear_stiffening",))["nonlinear_stiffening"]
    extended = problem.with_effects([effect], positions=[last])
    _continuation_agrees(extended, 0, np.array([0.01199, 0.06124, 1.0]))
