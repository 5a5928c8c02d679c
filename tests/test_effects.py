"""The effect library: off at theta = 0, exact derivatives, the physics of each term."""

from __future__ import annotations

import numpy as np
import pytest
from effectchecks import check_derivatives, check_theta_zero, simulated_setting

from experiments.phantom.simulate import (
    SimulationSettings,
    parse_effect_specs,
    simulate,
    simulate_with_effects,
)
from solvers.diagnosis.extended import ExtendedProblem
from symbolic.effects.library import ALL_EFFECT_NAMES, EFFECT_NAMES, make_effect
from symbolic.effects.load import basis_values
from symbolic.effects.measurement import cayley_rotation
from symbolic.effects.nonlinearity import stiffening_force
from symbolic.effects.skinrules import surface_frame, surface_rule
from symbolic.effects.stiffness import PreTension, VolumetricCoupling

DESIGN_NAMES = {
    "nonlinear_stiffening",
    "heterogeneity",
    "rigid_motion",
    "force_direction",
    "contact_offset",
    "contact_patch",
    "bending",
    "base_compliance",
    "pre_tension",
    "measurement_scale",
    "volumetric_coupling",
}


@pytest.fixture(scope="module")
def setting():
    """A simulated dataset, its base problem, the fitted base model and the library."""
    return simulated_setting()


def test_library_names_are_those_of_the_design():
    """The design's list, plus the continuum issue's shear term and surrounding tissue, and
    issue 40's layering (skin over fat): together the effects of docs/effects.md,
    "The effects"."""
    assert set(EFFECT_NAMES) == DESIGN_NAMES | {"shear_coupling", "surrounding_tissue", "layering"}
    for name in EFFECT_NAMES:
        effect = make_effect(name)
        assert effect.name == name
        sizes = {len(effect.parameter_names), len(effect.units), len(effect.scales)}
        assert sizes == {len(effect.lower)} == {len(effect.upper)}
        assert all(lo <= 0 <= hi for lo, hi in zip(effect.lower, effect.upper))
        assert effect.default_magnitude > 0
    with pytest.raises(ValueError, match="unknown effect"):
        make_effect("gravity")


def test_base_problem_matches_the_project_residual(setting):
    """With no effect, the composed residual is InverseProblem's at the same state."""
    problem, base_fit, _ = setting
    for position, case in enumerate(problem.cases):
        expected = problem.base.case_residual(case, base_fit.states[position])
        rows = slice(
            sum(3 * c.n_observations for c in problem.cases[:position]),
            sum(3 * c.n_observations for c in problem.cases[: position + 1]),
        )
        np.testing.assert_allclose(base_fit.residual[rows], expected, atol=1e-14)


@pytest.mark.parametrize("name", ALL_EFFECT_NAMES)
def test_theta_zero_reproduces_the_base_model_exactly(setting, name):
    """g and r at theta = 0 equal the base model's for any state, to rounding."""
    check_theta_zero(setting, name)


@pytest.mark.parametrize("name", ALL_EFFECT_NAMES)
def test_derivatives_match_finite_differences(setting, name):
    """The reduced Jacobian d r / d p (through the equilibrium) against central differences."""
    check_derivatives(setting, name)


def test_stiffening_closed_form_jacobian_matches_finite_differences(setting):
    """The custom dF/dDelta, dF/dc, dF/dk of nonlinear_stiffening, against central differences."""
    import casadi as ca

    problem, _, _ = setting
    model = problem.model
    force = stiffening_force(model)
    rng = np.random.default_rng(1)
    delta = rng.normal(0.0, 0.2, (model.n_free, 3))
    c = np.r_[2.6, 0.18, 1.7, np.zeros(len(model.terms) - 3)]
    jacobian = force.jacobian()(delta, c, 80.0, 5.0, force(delta, c, 80.0, 5.0))
    d_delta = np.array(jacobian[0])
    columns = rng.choice(3 * model.n_free, 12, replace=False)
    for column in columns:
        step = np.zeros(3 * model.n_free)
        step[column] = 1e-6
        shift = step.reshape(3, -1).T
        numeric = (
            np.array(force(delta + shift, c, 80.0, 5.0))
            - np.array(force(delta - shift, c, 80.0, 5.0))
        ).T.ravel() / 2e-6
        np.testing.assert_allclose(d_delta[:, column], numeric, atol=1e-6 * np.abs(numeric).max())
    numeric_k = (
        np.array(force(delta, c, 80.0 + 1e-4, 5.0)) - np.array(force(delta, c, 80.0 - 1e-4, 5.0))
    ).T.ravel() / 2e-4
    np.testing.assert_allclose(np.array(jacobian[2]).ravel(), numeric_k, rtol=1e-6, atol=1e-12)
    assert float(ca.norm_inf(force(delta, c, 0.0, 5.0))) == 0.0


def test_stiffening_enters_newton_by_its_closed_form_tangent(setting):
    """dg/ds of a case with nonlinear_stiffening (its tangent added in closed form,
    ``Effect.internal_tangent``, not by AD of the force) against central differences of g."""
    problem, base_fit, library = setting
    extended = problem.with_effects([library["nonlinear_stiffening"]])
    p = np.concatenate([base_fit.p, [80.0]])
    n = extended.functions(0).n_state
    state = np.random.default_rng(2).normal(0.0, 0.2, n)
    g, tangent = extended.numeric(0, "newton")(state, p)
    equilibrium = extended.numeric(0, "equilibrium")
    for column in np.random.default_rng(3).choice(n, 12, replace=False):
        step = np.zeros(n)
        step[column] = 1e-6
        numeric = (equilibrium(state + step, p)[0] - equilibrium(state - step, p)[0]) / 2e-6
        exact = tangent[:, [column]].toarray()
        np.testing.assert_allclose(exact, numeric, atol=1e-6 * np.abs(numeric).max())


def test_load_effects_keep_the_total_force(setting):
    """sum_a F_B[a] = f for any contact offset and patch (partition of unity, eq. 20)."""
    problem, base_fit, library = setting
    names = ["force_direction", "contact_offset", "contact_patch"]
    extended = problem.with_effects([library[n] for n in names])
    p = np.concatenate([base_fit.p, [0.2, -0.1, 1.5, -1.0, 4.0]])
    case = extended.extended.cases[0]
    state = np.zeros(extended.functions(0).n_state)
    g = extended.numeric(0, "equilibrium")(state, p)[0].reshape(3, -1).T
    # g = -F_B(theta) at zero displacement; the inner layer is fixed and carries no load
    _, _, e1, e2, _ = _frame(problem, case)
    expected = case.force_vector + np.linalg.norm(case.force_vector) * (0.2 * e1 - 0.1 * e2)
    np.testing.assert_allclose(-g.sum(axis=0), expected, atol=1e-12)


def _probed(setting, name: str, radius: float = 4.0, shape: str = "gauss"):
    """The setting's loads as probes of ``radius`` [mm] and ``shape`` with effect ``name``:
    the problem, the radius, the probes, case 0's declared F_B and theta -> F_B(theta) -
    F_B of case 0 (at the zero state, so F_B is minus the equilibrium residual)."""
    from symbolic.loads import ProbeForce

    problem, _, library = setting
    loads = [ProbeForce(load.force, radius, uv=load.uv, shape=shape) for load in problem.loads]
    probed = ExtendedProblem(problem.base, loads, [])
    extended = probed.with_effects([library[name]])
    model = problem.model
    state = np.zeros(extended.functions(0).n_state)
    declared = loads[0].generalized(model.volume)[model.free]

    def change_at(theta) -> np.ndarray:
        p = np.concatenate([problem.start()[: len(problem.names)], theta])
        load = -extended.numeric(0, "equilibrium")(state, p)[0].reshape(3, -1).T
        return load - probed.extended.cases[0].force

    return problem, radius, loads, declared, change_at


@pytest.mark.parametrize("shape", ["gauss", "disc"])
def test_contact_patch_on_a_declared_probe_is_the_wider_patch(setting, shape):
    """On a probe of radius r0 the patch is exact at any width: F_B(theta) is the probe
    of the same shape and variance r0^2 / 4 + theta (``ProbeForce`` of that radius), and
    F_B(0) is the declared load to the last bit."""
    from symbolic.loads import ProbeForce

    problem, radius, loads, declared, change_at = _probed(setting, "contact_patch", shape=shape)
    model = problem.model
    for theta in (0.0, 3.0, 12.0):
        change = change_at([theta])
        wider_radius = 2.0 * np.sqrt(radius**2 / 4 + theta)
        wider = ProbeForce(loads[0].force, wider_radius, uv=loads[0].uv, shape=shape)
        expected = wider.generalized(model.volume)[model.free] - declared
        if theta == 0.0:
            assert np.max(np.abs(change)) == 0.0
        else:
            assert np.max(np.abs(change)) > 1e-3 * np.max(np.abs(declared))
            error = np.max(np.abs(change - expected)) / np.abs(declared).max()
            print(f"theta {theta}: error {error:.1e} of the largest entry")
            # ProbeForce integrates the wider probe on a coarser quadrature (spacing r / 10),
            # which resolves a disc's edge to a few 1e-5 (the Gaussian to 1e-8)
            assert error < (1e-6 if shape == "gauss" else 1e-4)


@pytest.mark.parametrize("shape", ["gauss", "disc"])
def test_contact_offset_moves_a_declared_probe_whole(setting, shape):
    """On a probe, F_B(delta) is the probe at the moved contact (``ProbeForce`` there), to
    second order in delta (the patch's centre moves in the tangent plane, the probe's on
    the curved skin), and F_B(0) is the declared load exactly."""
    from symbolic.loads import ProbeForce

    problem, radius, loads, declared, change_at = _probed(setting, "contact_offset", shape=shape)
    model = problem.model
    contact = np.asarray(loads[0].uv, dtype=float)
    du, dv, e1, e2, _ = surface_frame(model, contact)
    tangent = np.linalg.pinv(np.column_stack([du, dv]))
    errors = []
    for size in (0.0, 0.5, 1.0):
        delta = size * np.array([0.6, 0.8])
        change = change_at(delta)
        if size == 0.0:
            assert np.max(np.abs(change)) == 0.0
            continue
        uv = contact + tangent @ (delta[0] * e1 + delta[1] * e2)
        there = ProbeForce(loads[0].force, radius, uv=uv, shape=shape)
        there = there.generalized(model.volume)[model.free]
        expected = there - declared
        assert np.max(np.abs(change - expected)) < 0.01 * np.max(np.abs(expected))
        errors.append(np.max(np.abs(change - expected)) / np.max(np.abs(declared)))
    print("errors at 0.5 and 1 mm, of the largest declared entry:", errors)
    assert 3.0 < errors[1] / errors[0] < 5.0  # second order: the error quadruples


def _frame(problem, case):
    return surface_frame(problem.model, case.contact_uv)


def test_symbolic_basis_matches_the_numeric_one():
    import casadi as ca

    from symbolic.basis import BSplineBasis

    basis = BSplineBasis(3, 9)
    t = ca.MX.sym("t")
    function = ca.Function("N", [t], [basis_values(basis, 0.1 + t, 0), basis_values(basis, t, 2)])
    values, second = (np.array(v).ravel() for v in function(0.27))
    np.testing.assert_allclose(values, basis.evaluate_dense([0.37])[0], atol=1e-15)
    np.testing.assert_allclose(second, basis.evaluate_dense([0.27], 2)[0], atol=1e-12)


def test_cayley_rotation_is_a_rotation():
    omega = np.array([0.3, -0.2, 0.5])
    rotation = np.array(cayley_rotation(omega))
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    small = np.array(cayley_rotation(1e-6 * omega))
    skew = np.array([[0, -0.5, -0.2], [0.5, 0, -0.3], [0.2, 0.3, 0]]) * 1e-6
    np.testing.assert_allclose(small - np.eye(3), skew, atol=1e-12)


def test_volumetric_matrix_sees_only_volume_change(setting):
    """K_lambda: symmetric PSD, zero on rigid motions, 9 eps^2 V on a dilation u = eps x."""
    problem, _, _ = setting
    model = problem.model
    matrix = VolumetricCoupling().matrix(model)
    points = model.rest
    np.testing.assert_allclose((matrix - matrix.T).toarray(), 0.0, atol=1e-12)
    center = points.mean(axis=0)
    for mode in (
        np.tile([1.0, 0.0, 0.0], (len(points), 1)),
        np.cross([0.2, -0.3, 1.0], points - center),
    ):
        vector = mode.T.ravel()
        assert abs(vector @ matrix @ vector) < 1e-9 * np.abs(matrix).max() * len(points)
    dilation = (1e-3 * (points - center)).T.ravel()
    _, area, _, _ = surface_rule(model, 1.0, 6)
    radius, thickness = 80.0, 5.0  # the phantom: a spherical layer, so V = A/R^2 (R^3 - r^3)/3
    volume = area.sum() / radius**2 * (radius**3 - (radius - thickness) ** 3) / 3
    assert dilation @ matrix @ dilation == pytest.approx(9e-6 * volume, rel=2e-3)


def test_pre_tension_matrix_is_the_skin_rotation_energy(setting):
    """K_sigma (stacked x, y, z): zero on translations; u = eps y e_z costs
    eps^2 integral n_z^2 |grad_s y|^2 = n_z^2 (1 - n_y^2), u = eps y e_y only
    n_y^2 (1 - n_y^2): it stiffens the normal displacement, not in-plane stretch."""
    problem, _, _ = setting
    model = problem.model
    matrix = PreTension().matrix(model).toarray()
    n = len(model.rest)
    assert matrix.shape == (3 * n, 3 * n)
    for k in range(3):
        translation = np.zeros(3 * n)
        translation[k * n : (k + 1) * n] = 1.0
        assert abs(translation @ matrix @ translation) < 1e-10
    params, area, _, _ = surface_rule(model, 1.0, 6)
    normals = model.volume.outer_normal(params[:, :2])
    gradient = 1.0 - normals[:, 1] ** 2
    for k in (1, 2):
        field = np.zeros(3 * n)
        field[k * n : (k + 1) * n] = 1e-3 * model.rest[:, 1]
        expected = 1e-6 * np.sum(area * normals[:, k] ** 2 * gradient)
        assert field @ matrix @ field == pytest.approx(expected, rel=1e-3)


def test_base_compliance_frees_the_inner_layer(setting):
    """c > 0 moves the inner layer under the probe; c = 0 keeps it at rest exactly."""
    problem, base_fit, library = setting
    extended = problem.with_effects([library["base_compliance"]])
    n_base = problem.functions(0).n_state
    for compliance, moved in ((0.0, False), (50.0, True)):
        state, _ = extended.solve_state(0, np.concatenate([base_fit.p, [compliance]]))
        inner = state[n_base:]
        assert (np.abs(inner).max() > 1e-3) == moved


def test_parse_effect_specs():
    assert parse_effect_specs(["rigid_motion=0.05", "bending"]) == {
        "rigid_motion": 0.05,
        "bending": make_effect("bending").default_magnitude,
    }
    assert parse_effect_specs([]) == {}
    for bad, match in (
        (["gravity"], "unknown effect"),
        (["bending=abc"], "must be a number"),
        (["bending", "bending=1"], "twice"),
        (["bending=nan"], "takes 0 to 10"),
        (["heterogeneity=5"], "takes -0.9 to 0.9"),
    ):
        with pytest.raises(ValueError, match=match):
            parse_effect_specs(bad)


def test_simulation_without_effects_is_simulate():
    """The same random stream and measurement as experiments.phantom.simulate."""
    ours = simulate_with_effects({}, seed=5)
    theirs = simulate(measurement=SimulationSettings(seed=5))
    for key in ("outer_rest", "inner_rest", "forces", "contacts"):
        np.testing.assert_array_equal(getattr(ours, key), getattr(theirs, key))
    np.testing.assert_allclose(ours.outer_loaded, theirs.outer_loaded, atol=1e-12)


def test_simulated_effects_are_not_declared():
    plain = simulate_with_effects({}, seed=2)
    hidden = simulate_with_effects({"contact_patch": 6.0, "force_direction": 0.3}, seed=2)
    for key in ("forces", "contacts", "probe_radius", "outer_rest", "inner_rest"):
        np.testing.assert_array_equal(getattr(plain, key), getattr(hidden, key))
    assert np.nanmax(np.abs(plain.outer_loaded - hidden.outer_loaded)) > 0.05
    assert set(hidden.extra) == set()


def test_the_per_model_stores_let_a_model_go():
    """The module-level stores (``symbolic.effects.base.per_model``: frames, in
    ``symbolic.effects.skinrules``, and patches;
    ``symbolic.loads.surface_points``) hold a model or volume weakly: once the caller
    drops it, it is collected and its entries go. They held it strongly, and every model
    of every diagnosis stayed in memory (a notebook grew by 0.3-0.5 GB per diagnosis)."""
    import gc
    import weakref

    import symbolic.effects.skinrules as skinrules
    import symbolic.loads as loads
    from symbolic.continuum import box_volume
    from symbolic.continuum_model import ContinuumModel

    model = ContinuumModel(box_volume((20.0, 16.0, 4.0), (5, 5, 3), (2, 2, 2)))
    first = surface_frame(model, (0.5, 0.5))
    assert surface_frame(model, (0.5, 0.5)) is first  # built once
    loads.surface_points(model.volume, 1.0)
    alive, owners = weakref.ref(model), (id(model), id(model.volume))

    def entries():  # the stores' keys start with the id of their model or volume
        stored = list(skinrules._FRAMES) + list(loads._SURFACE_POINTS)
        return [key for key in stored if key[0] in owners]

    assert len(entries()) == 2
    del model
    gc.collect()
    assert alive() is None and entries() == []


def test_a_fields_two_continuum_terms_share_one_pass_and_equal_their_matrices(monkeypatch):
    """``field_products``: K_mu x and K_lambda x of one shape come from one
    ``elasticity_product`` and equal the assembled matrices' products."""
    from symbolic.continuum import box_volume
    from symbolic.continuum_model import ContinuumModel
    from symbolic.effects.stiffness import field_products

    model = ContinuumModel(box_volume((20.0, 16.0, 4.0), (5, 5, 3), (2, 2, 2)))
    effect = make_effect("heterogeneity")
    terms = field_products(model, effect)
    passes = []
    original = type(model.gradient).elasticity_product
    monkeypatch.setattr(
        type(model.gradient),
        "elasticity_product",
        lambda self, *a: passes.append(1) or original(self, *a),
    )
    x = np.random.default_rng(2).normal(size=(terms[0].shape[0], 3))
    products = [term @ x for term in terms]
    assert len(passes) == len(terms) // 2
    for term, product in zip(terms, products):
        expected = term.matrix() @ x
        assert np.abs(product - expected).max() <= 1e-10 * np.abs(expected).max()


def test_stiffening_effect_on_the_slab_is_the_slabs_own_k0():
    """``nonlinear_stiffening`` on a ``SkinSlabModel`` (model k0 = 0) adds exactly the slab's
    own eq. (1) force at k0 = k minus its linear force: the effect reads the slab's term
    coefficients through ``TissueModel.coefficient``, alpha_v tied to alpha_u by the
    in-plane isotropy, not the alpha_v parameter (whose default differs)."""
    import casadi as ca

    from experiments.realskin.geometry import Rect
    from experiments.realskin.slab import slab_volume
    from symbolic.constraints import BoundaryConditions
    from symbolic.effects.base import CaseSymbols
    from symbolic.skin_slab import SkinSlabModel
    from symbolic.stiffening import exponential_stiffening

    def slab(k0: float) -> SkinSlabModel:
        return SkinSlabModel(
            slab_volume(Rect(0.0, -5.0, 100.0, 45.0), 2.0, (8, 5)),
            {"alpha_u": 0.012, "alpha_w": 0.06, "k0": k0},
            BoundaryConditions(fix_inner=True),
            stiffening=exponential_stiffening,
            isotropic=True,
        )

    model, k = slab(0.0), 3.0
    tied = model.coefficient("alpha_v", model.values())
    assert abs(tied - model.values()["alpha_v"]) > 0.5 * tied  # the tie is not the default
    delta = ca.MX.sym("delta", model.n_free, 3)
    effect = make_effect("nonlinear_stiffening")
    added = effect.internal_force(model, CaseSymbols(delta, model.values()), ca.DM([k]))
    own = slab(k).elastic_force(delta, slab(k).values(), ()) - model.elastic_force(
        delta, model.values(), ()
    )
    forces = ca.Function("forces", [delta], [added, own])
    shift = np.random.default_rng(4).normal(0.0, 0.3, (model.n_free, 3))
    effect_force, slab_force = (np.array(f) for f in forces(shift))
    scale = np.abs(slab_force).max()
    print(f"largest force {scale:.2e} N, difference {np.abs(effect_force - slab_force).max():.1e}")
    assert scale > 1e-4
    assert np.abs(effect_force - slab_force).max() <= 1e-12 * scale
