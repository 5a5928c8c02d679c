"""Forward model: residual Function, Newton, linearity, stiffening (eq. 1, 20, 22)."""

import casadi as ca
import numpy as np
import pytest

from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    probe_loads,
)
from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver, NewtonSettings
from symbolic.constraints import BoundaryConditions
from symbolic.loads import PointForce, PrescribedDisplacement, ProbeForce
from symbolic.model import TissueModel

CENTER = np.array([[0.5, 0.5, 1.0]])


@pytest.fixture(scope="module")
def model():
    return forehead_model()


def probe_displacement(model, equilibrium):
    return (model.volume.collocation(CENTER) @ (equilibrium.positions - model.rest))[0]


def test_linear_response_scales_with_force_and_inverse_alpha(model):
    force = model.generalized_force(probe_loads(model)[1])
    names = ("alpha_u", "alpha_v", "alpha_w")
    solver = EquilibriumSolver(model, names)
    alpha = np.array([TRUE_PARAMETERS[n] for n in names])
    base = solver.solve(force, alpha).positions - model.rest
    doubled = solver.solve(2 * force, alpha).positions - model.rest
    stiffer = solver.solve(force, 3.7 * alpha).positions - model.rest
    assert np.max(np.abs(doubled - 2 * base)) < 1e-10 * np.abs(base).max()
    assert np.max(np.abs(stiffer - base / 3.7)) < 1e-10 * np.abs(base).max()


def test_residual_is_a_named_function_in_positions_and_parameters(model):
    residual = model.residual_function(("alpha_u", "alpha_w"))
    assert residual.name() == "R"
    assert residual.name_in() == ["B_free", "x", "F_B", "lam", "d"]
    positions = model.rest[model.free] + 0.01
    out = residual(B_free=positions, x=[2.6, 1.7])
    k = model.free_block(model.stiffness_matrix())
    assert np.allclose(out["R"].full(), k @ np.full((model.n_free, 3), 0.01), rtol=1e-12)
    # derivatives in x exist: R is linear in alpha, so dR/dx is R at unit alpha
    x = ca.MX.sym("x", 2)
    jac = ca.Function("j", [x], [ca.jacobian(residual(positions, x, 0, 0, 0)[0], x)])
    assert jac([1.0, 1.0]).shape == (3 * model.n_free, 2)


def test_zero_stiffening_reproduces_linear_stiffness_exactly(model):
    rng = np.random.default_rng(1)
    delta = ca.MX.sym("d", model.n_free, 3)
    edges = model.edges().elastic_force(delta, model._term_coefficients(model.parameters), 0.0)
    force = ca.Function("f", [delta], [edges])
    value = rng.normal(size=(model.n_free, 3))
    linear = model.free_block(model.stiffness_matrix()) @ value
    assert np.max(np.abs(force(value).full() - linear)) < 1e-12 * np.abs(linear).max()


def test_newton_converges_quadratically_on_the_nonlinear_model():
    model = forehead_model(parameters={**TRUE_PARAMETERS, "k0": 50.0})
    force = model.generalized_force(probe_loads(model)[1])
    result = EquilibriumSolver(model).solve(force)
    history = np.array(result.residual_history)
    assert history[-1] < 1e-10 and result.iterations >= 4
    # asymptotic order from the last steps above round-off: log e_{k+1}/e_k over log e_k/e_{k-1}
    usable = history[history > 1e-13]
    ratios = np.log(usable[2:] / usable[1:-1]) / np.log(usable[1:-1] / usable[:-2])
    assert ratios[-1] > 1.8
    assert np.all(usable[2:] <= 5.0 * usable[1:-1] ** 2)


def test_stiffening_deflects_less_than_linear():
    settings = PhantomSettings()
    displacements = []
    for k0 in (0.0, 10.0, 50.0):
        model = forehead_model(settings, {**TRUE_PARAMETERS, "k0": k0})
        force = model.generalized_force(probe_loads(model, settings)[1])
        displacements.append(-probe_displacement(model, EquilibriumSolver(model).solve(force))[2])
    assert displacements[0] > displacements[1] > displacements[2] > 0


def test_point_force_from_3d_point_equals_force_at_uv(model):
    """A point 0.3 mm off the skin along its normal projects back to the same (u, v)."""
    uv = np.array([[0.3, 0.6]])
    point = model.volume.evaluate(model.volume.outer_params(uv))[0]
    point += 0.3 * model.volume.outer_normal(uv)[0]
    by_uv = PointForce([0, 0, -0.25], uv=uv[0]).generalized(model.volume)
    by_point = PointForce([0, 0, -0.25], point=point).generalized(model.volume)
    assert np.max(np.abs(by_uv - by_point)) < 1e-10


@pytest.mark.parametrize(
    "load",
    [
        PointForce([0.01, 0.02, -0.25], uv=[0.4, 0.5]),
        ProbeForce([0.01, 0.02, -0.25], radius=2.0, uv=[0.5, 0.5]),
    ],
)
def test_generalised_force_preserves_the_total_force(model, load):
    """Partition of unity: sum_a F_B[a] = f."""
    assert np.allclose(load.generalized(model.volume).sum(axis=0), load.force, atol=1e-14)


def test_probe_converges_to_point_force_as_radius_shrinks(model):
    point = PointForce([0, 0, -0.25], uv=[0.5, 0.5]).generalized(model.volume)
    gaps = [
        np.abs(ProbeForce([0, 0, -0.25], r, uv=[0.5, 0.5]).generalized(model.volume) - point).max()
        for r in (4.0, 2.0, 1.0)
    ]
    assert gaps[0] > gaps[1] > gaps[2]


def test_prescribed_displacement_is_met_and_forces_balance():
    model0 = forehead_model()
    pad = np.array([[u, v] for u in (0.2, 0.25, 0.3) for v in (0.45, 0.5, 0.55)])
    model = TissueModel(
        model0.volume, TRUE_PARAMETERS, BoundaryConditions(), prescribed=PrescribedDisplacement(pad)
    )
    shift = np.tile([-0.5, 0.0, 0.0], (len(pad), 1))
    result = EquilibriumSolver(model).solve(np.zeros((model.n_free, 3)), prescribed=shift)
    pad_rows = model.volume.collocation(model.volume.outer_params(pad))
    moved = pad_rows @ (result.positions - model.rest)
    assert np.max(np.abs(moved - shift)) < 1e-10
    k = model.stiffness_matrix()
    support = (k @ (result.positions - model.rest))[model.fixed].sum(axis=0)
    # the pad's force on the tissue is balanced by the support's force on it
    assert np.allclose(model.constraint_force(result.multipliers), -support, atol=1e-10)
    assert model.constraint_force(result.multipliers)[0] < 0  # pulling along -x


def test_lateral_ring_fixed_is_stiffer(model):
    ring = forehead_model(PhantomSettings(fix_lateral=True))
    free = EquilibriumSolver(model).solve(model.generalized_force(probe_loads(model)[1]))
    fixed = EquilibriumSolver(ring).solve(ring.generalized_force(probe_loads(ring)[1]))
    assert 0 > probe_displacement(ring, fixed)[2] > probe_displacement(model, free)[2]


def test_newton_reports_failure_clearly():
    model = forehead_model(parameters={**TRUE_PARAMETERS, "k0": 50.0})
    force = model.generalized_force(probe_loads(model)[1])
    solver = EquilibriumSolver(model, settings=NewtonSettings(max_iterations=2))
    with pytest.raises(EquilibriumError, match="did not converge in 2 iterations"):
        solver.solve(force)


@pytest.mark.parametrize("prescribed", [False, True])
def test_closed_form_jacobian_equals_automatic_differentiation(prescribed):
    """The linear model's custom Jacobian is exact: same as CasADi AD on all inputs."""
    base = forehead_model()
    pad = PrescribedDisplacement(np.array([[0.2, 0.5], [0.25, 0.5], [0.8, 0.4]]))
    model = TissueModel(base.volume, TRUE_PARAMETERS, prescribed=pad if prescribed else None)
    names = ("alpha_u", "alpha_w", "beta")
    fast, plain = model.state_residual(names), model._state_residual(names)
    rng = np.random.default_rng(2)
    args = [rng.normal(size=fast.size_in(i)) for i in range(4)]
    for function in (fast, plain):
        assert function.n_in() == 4
    for i in range(4):
        jac = [f.jacobian()(*args, f(*args))[i].full() for f in (fast, plain)]
        if jac[1].size == 0:  # no prescribed points: d has no entries
            continue
        assert np.max(np.abs(jac[0] - jac[1])) < 1e-12 * max(1.0, np.abs(jac[1]).max())


@pytest.mark.parametrize("energy", ["dnurbs", "neo-hookean", "exponential"])
def test_the_residual_at_rest_is_the_load_alone(energy):
    """Newton's scale |g(0)| is computed as |[F_B; C d]| (``_load_norm``): every model's
    rest state is stress-free. Checked against g(0) itself, with random loads and
    prescribed displacements, on the nonlinear paper model and both large-strain ones."""
    from symbolic.continuum_model import ENERGIES

    base = forehead_model(parameters={**TRUE_PARAMETERS, "k0": 50.0})
    pad = PrescribedDisplacement(np.array([[0.2, 0.5], [0.25, 0.5], [0.8, 0.4]]))
    values = dict(TRUE_PARAMETERS, k0=50.0) if energy == "dnurbs" else {"E": 8.0, "nu": 0.3}
    if energy == "exponential":
        values["k1"] = 5.0
    options = {"support": 1e-3} if energy != "dnurbs" else {}
    model = ENERGIES[energy](base.volume, values, prescribed=pad, **options)
    names = ("k0",) if energy == "dnurbs" else ("E",)
    solver = EquilibriumSolver(model, names)
    rng = np.random.default_rng(3)
    force = rng.normal(size=(model.n_free, 3))
    prescribed = rng.normal(size=(model._constraint_rows.shape[1], 3))
    x = np.array([values[names[0]]])
    at_rest = solver.residual(np.zeros(solver.n_state), x, force, prescribed).full()
    assert solver._load_norm(force, prescribed) == pytest.approx(np.linalg.norm(at_rest), 1e-12)
