"""The strain-stiffening planar energy (``symbolic.planar_stiffening``) and its whitened fit
(``experiments.realskin.planarstiffening``), docs/realskin.md "Strain stiffening on the
authors' model".

The energy tests need no data; the fit-level test reads the healthy frames from
``../shared/data`` and skips when it is absent.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from planarchecks import check_tangent_and_residual, healthy_mesh

from experiments.realskin import authors, mesh2d
from experiments.realskin.data import load_case
from experiments.realskin.planarstiffening import (
    STIFFENING_CAP,
    WhitenedExtensometer,
    fit,
    stiffening_start,
)
from symbolic.planar_neohookean import PlanarNeoHookean
from symbolic.planar_stiffening import EXPONENT_CAP, PlanarStiffening, exponential_term


@pytest.fixture(scope="module")
def coarse():
    return healthy_mesh()


def _random_state(mesh, seed=0):
    rng = np.random.default_rng(seed)
    model = PlanarStiffening(mesh.points, mesh.triangles)
    m = mesh.n_triangles
    model.set_parameters(
        rng.uniform(0.02, 0.1, m),
        rng.uniform(0.1, 0.45, m),
        rng.uniform(0.01, 0.2, m),
        rng.uniform(0.5, 5.0, m),
    )
    return model, 0.1 * rng.normal(size=2 * mesh.n_nodes), rng.normal(size=2 * mesh.n_nodes), rng


def test_tangent_and_residual_match_central_differences(coarse):
    """K v against (R(u + h v) - R(u - h v)) / 2h, and R . v against the energy's."""
    model, u, v, _ = _random_state(coarse)
    check_tangent_and_residual(model, u, v, tangent_rtol=1e-7, symmetry_rtol=1e-13)


def test_parameter_and_edge_force_derivatives_match_central_differences(coarse):
    model, u, v, rng = _random_state(coarse, seed=1)
    weights = (rng.uniform(size=coarse.n_triangles) > 0.5).astype(float)
    derivative = model.residual_derivatives(u, weights)
    normals, owners = coarse.moving_normals(), coarse.moving_owner
    by_u, by_p = model.edge_force_derivatives(u, normals, owners, weights)
    base = [model.young.copy(), model.poisson.copy(), model.k1.copy(), model.k2.copy()]
    h = 1e-6
    for j in range(4):
        shifted = []
        for sign in (1.0, -1.0):
            values = [b + sign * h * weights * (i == j) for i, b in enumerate(base)]
            model.set_parameters(*values)
            shifted.append((model.residual(u), model.edge_force(u, normals, owners)))
        model.set_parameters(*base)
        numeric = (shifted[0][0] - shifted[1][0]) / (2 * h)
        assert np.linalg.norm(numeric - derivative[:, j]) < 1e-7 * np.linalg.norm(numeric)
        numeric_force = (shifted[0][1] - shifted[1][1]) / (2 * h)
        assert np.abs(numeric_force - by_p[:, j]).max() < 1e-6 * np.abs(numeric_force).max()
    numeric = (
        model.edge_force(u + h * v, normals, owners) - model.edge_force(u - h * v, normals, owners)
    ) / (2 * h)
    assert np.abs(numeric - by_u @ v).max() < 1e-7 * np.abs(numeric).max()


def test_k1_zero_is_the_neo_hookean_model_exactly(coarse):
    model, u, _, rng = _random_state(coarse, seed=2)
    reference = PlanarNeoHookean(coarse.points, coarse.triangles, "strain")
    reference.set_parameters(model.young, model.poisson)
    model.set_parameters(model.young, model.poisson, 0.0, model.k2)
    assert model.energy(u) == reference.energy(u)
    assert np.array_equal(model.residual(u), reference.residual(u))
    assert (model.stiffness(u) != reference.stiffness(u)).nnz == 0
    weights = np.ones(coarse.n_triangles)
    assert np.array_equal(
        model.residual_derivatives(u, weights)[:, :2], reference.residual_derivatives(u, weights)
    )


def test_at_rest_the_added_term_has_no_energy_stress_or_stiffness(coarse):
    """At u = 0 the stiffening model's energy, residual and stiffness are the neo-Hookean
    ones bit for bit for k1 > 0 (s = 0 and g = dIbar1/dF = 0 exactly at F = I), and the
    added energy is quartic in a small displacement (W(t u) / t^4 tends to a constant)."""
    model, u, _, _ = _random_state(coarse, seed=3)
    assert model.k1.min() > 0
    rest = np.zeros(2 * coarse.n_nodes)
    reference = PlanarNeoHookean(coarse.points, coarse.triangles, "strain")
    reference.set_parameters(model.young, model.poisson)
    assert model.energy(rest) == reference.energy(rest) == 0.0
    assert np.array_equal(model.residual(rest), reference.residual(rest))
    assert (model.stiffness(rest) != reference.stiffness(rest)).nnz == 0
    added = [model.energy(t * u) - reference.energy(t * u) for t in (1e-2, 5e-3)]
    assert added[0] > 0
    assert abs(added[0] / added[1] / 16.0 - 1.0) < 0.02, added  # quartic, not quadratic


def test_k1_zero_energy_density_is_the_neo_hookean_one_bit_for_bit():
    rng = np.random.default_rng(4)
    f = np.eye(2) + 0.3 * rng.normal(size=(20, 2, 2))
    f = f[np.linalg.det(f) > 0]
    points, triangles = _square_patch()
    model = PlanarStiffening(points, triangles)
    reference = PlanarNeoHookean(points, triangles, "strain")
    young, poisson = rng.uniform(0.02, 0.1, len(f)), rng.uniform(0.1, 0.45, len(f))
    model.young, model.poisson, model.k1, model.k2 = young, poisson, 0.0 * young, 3.0 + young
    reference.young, reference.poisson = young, poisson
    assert np.array_equal(model.energy_density(f), reference.energy_density(f))
    assert np.array_equal(model.stress(f), reference.stress(f))
    assert np.array_equal(model.tangent(f), reference.tangent(f))


def _square_patch(n: int = 3):
    """The unit square [mm] as an n x n grid of nodes, two counter-clockwise triangles per
    cell."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    points = np.column_stack([x.ravel(), y.ravel()])
    node = np.arange(n * n).reshape(n, n)
    a, b, c, d = node[:-1, :-1], node[:-1, 1:], node[1:, 1:], node[1:, :-1]
    triangles = np.concatenate(
        [
            np.column_stack([a.ravel(), b.ravel(), c.ravel()]),
            np.column_stack([a.ravel(), c.ravel(), d.ravel()]),
        ]
    )
    return points, triangles


@pytest.mark.parametrize("k2", [0.0, 0.7, 4.0])
def test_pointwise_stress_and_tangent_match_central_differences_of_the_energy(k2):
    """P = dpsi/dF and A = dP/dF by central differences at random F (det F > 0), and the
    parameter derivatives dP/dk1, dP/dk2 against differences of P."""
    rng = np.random.default_rng(5)
    f = np.eye(2) + 0.25 * rng.normal(size=(12, 2, 2))
    f = f[np.linalg.det(f) > 0.2]
    points, triangles = _square_patch()
    model = PlanarStiffening(points, triangles)
    m = len(f)
    model.young, model.poisson = rng.uniform(0.02, 0.1, m), rng.uniform(0.1, 0.45, m)
    model.k1, model.k2 = rng.uniform(0.05, 0.5, m), np.full(m, k2)
    h = 1e-6
    stress, tangent = model.stress(f), model.tangent(f)
    for k in range(2):
        for ell in range(2):
            step = np.zeros((2, 2))
            step[k, ell] = h
            slope = (model.energy_density(f + step) - model.energy_density(f - step)) / (2 * h)
            assert np.abs(slope - stress[:, k, ell]).max() < 1e-8 * np.abs(stress).max()
            column = (model.stress(f + step) - model.stress(f - step)) / (2 * h)
            assert np.abs(column - tangent[:, :, :, k, ell]).max() < 1e-8 * np.abs(tangent).max()
    assert np.abs(tangent - tangent.transpose(0, 3, 4, 1, 2)).max() < 1e-14 * np.abs(tangent).max()
    derivatives = model.stress_derivatives(f)
    base = model.k1.copy(), model.k2.copy()
    for j, name in ((2, "k1"), (3, "k2")):
        shifted = []
        for sign in (1.0, -1.0):
            setattr(model, name, base[j - 2] + sign * h)
            shifted.append(model.stress(f))
        model.k1, model.k2 = base[0].copy(), base[1].copy()
        numeric = (shifted[0] - shifted[1]) / (2 * h)
        assert np.abs(numeric - derivatives[j]).max() < 1e-7 * np.abs(derivatives[j]).max()


def test_an_overflowing_or_infinite_k2_raises_floating_point_error():
    """k2 s^2 beyond the cap, and k2 = inf at s = 0 (NaN), fail the evaluation."""
    s = np.array([0.0, 0.1])
    with pytest.raises(FloatingPointError):
        exponential_term(s, np.ones(2), np.full(2, 1.01 * EXPONENT_CAP / 0.01))
    with pytest.raises(FloatingPointError):
        exponential_term(s, np.ones(2), np.array([np.inf, 1.0]))
    assert np.all(np.isfinite(exponential_term(s, np.ones(2), np.full(2, 0.99e4))))


def _closed_form_stress(l1, l2, young, poisson, k1, k2):
    """(P11, P22) [N/mm] of F = diag(l1, l2) by hand from psi(l1, l2) of eq. (S1):

        psi = mu/2 (l1^2 + l2^2 - 2 - 2 ln(l1 l2)) + lam/2 ln(l1 l2)^2
              + k1/(2 k2) (exp(k2 s^2) - 1),   s = (l1 l2)^(-2/3) (l1^2 + l2^2 + 1) - 3,

        P11 = dpsi/dl1 = mu (l1 - 1/l1) + lam ln(l1 l2) / l1
              + k1 s exp(k2 s^2) (l1 l2)^(-2/3) (2 l1 - (2/3) (l1^2 + l2^2 + 1) / l1),

    and P22 likewise with l1 and l2 swapped (P12 = P21 = 0).
    """
    mu = young / (2.0 * (1.0 + poisson))
    lam = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    trace = l1**2 + l2**2 + 1.0
    s = (l1 * l2) ** (-2.0 / 3.0) * trace - 3.0
    w1 = k1 * s * np.exp(k2 * s**2)

    def along(a):
        neo = mu * (a - 1.0 / a) + lam * np.log(l1 * l2) / a
        return neo + w1 * (l1 * l2) ** (-2.0 / 3.0) * (2.0 * a - 2.0 / 3.0 * trace / a)

    return along(l1), along(l2)


@pytest.mark.parametrize("stretches", [(1.3, 1.3), (0.85, 0.85), (1.4, 1.0), (0.8, 1.0)], ids=str)
def test_homogeneous_equibiaxial_and_uniaxial_stretch_on_a_patch(stretches):
    """u = (F - I) X with F = diag(l1, l2) on a unit-square patch (plane strain):
    every triangle's P is the closed form, the centre node is in equilibrium, and the
    reaction on the edge x = 1 is (P11, 0) x its length; the added term raises P11."""
    l1, l2 = stretches
    young, poisson, k1, k2 = 0.05, 0.3, 0.2, 2.0
    points, triangles = _square_patch()
    model = PlanarStiffening(points, triangles)
    model.set_parameters(young, poisson, k1, k2)
    f = np.diag([l1, l2])
    u = (points @ (f - np.eye(2)).T).ravel()
    p11, p22 = _closed_form_stress(l1, l2, young, poisson, k1, k2)
    expected = np.array([[p11, 0.0], [0.0, p22]])
    stress = model.stress(model.mesh.deformation_gradient(u))
    assert np.abs(stress - expected).max() < 1e-13 * abs(p11)
    residual = model.residual(u).reshape(-1, 2)
    assert np.abs(residual[4]).max() < 1e-13 * abs(p11)  # the centre node
    right = np.isclose(points[:, 0], 1.0)
    assert np.abs(residual[right].sum(axis=0) - [p11, 0.0]).max() < 1e-13 * abs(p11)
    neo = _closed_form_stress(l1, l2, young, poisson, 0.0, k2)[0]
    assert abs(p11) > abs(neo) and np.sign(p11) == np.sign(neo)


def test_the_whitened_fit_recovers_k1_and_k2_from_synthetic_data(shared_data):
    """Noise-free data made by the stiffening model on our coarse mesh (8 healthy frames to
    the full travel); from (E, nu, k1, k2) = (0.05, 0.3, 0.1, 100) the fit recovers the
    truth (0.03, 0.2, 0.2, 300) within 5 % for E, k1, k2 and 0.01 for nu. k2 is large
    because s = Ibar1 - 3 stays below 0.05 here: at k2 = 3, k2 s^2 < 0.01, the exponential
    is inert and k2 is not identifiable (the fit drives it to 0)."""
    data = load_case("healthy")
    frames = authors.load_frames(data, 10.0, count=8)
    mesh = mesh2d.build_mesh(data.geometry, 3.0)
    keep = ~np.asarray(data.spurious, dtype=bool)
    problem = WhitenedExtensometer(mesh, frames, 4, 0.0118, 1.5e-5, keep)
    truth = np.array([0.03, 0.2, 0.2, 300.0])
    made = problem.solve(truth, sensitivities=False)
    problem.frames = dataclasses.replace(frames, force_n=made.force)
    problem.observed = problem.at_points(made)
    result = fit(problem, (0.05, 0.3, 0.1, 100.0))
    relative = np.abs(result.x - truth) / truth
    assert relative[[0, 2, 3]].max() < 0.05, result.x
    assert abs(result.x[1] - truth[1]) < 0.01, result.x


@pytest.mark.parametrize("s_max", [0.011, 0.082])
def test_the_stiffening_start_is_active_at_s_max_and_the_bound_caps_it(s_max):
    """The start is the neo-Hookean (E, nu), k1 = E/10 and k2 s_max^2 = 1 exactly; the bound
    caps k2 s_max^2 at STIFFENING_CAP, inside EXPONENT_CAP."""
    young, poisson = 0.03, 0.13
    (e, nu, k1, k2), k2_max = stiffening_start((young, poisson), s_max)
    assert (e, nu, k1) == (young, poisson, young / 10.0)
    assert k2 * s_max**2 == pytest.approx(1.0, rel=1e-15)
    assert k2_max * s_max**2 == pytest.approx(STIFFENING_CAP, rel=1e-15)
    assert STIFFENING_CAP < EXPONENT_CAP / 2


def test_the_fit_stops_on_the_k2_bound(shared_data):
    """Data made with k2 s^2 beyond the bound: the fit ends on k2_max, not past it."""
    data = load_case("healthy")
    frames = authors.load_frames(data, 10.0, count=4)
    mesh = mesh2d.build_mesh(data.geometry, 3.0)
    keep = ~np.asarray(data.spurious, dtype=bool)
    problem = WhitenedExtensometer(mesh, frames, 4, 0.0118, 1.5e-5, keep)
    made = problem.solve(np.array([0.03, 0.2, 0.2, 300.0]), sensitivities=False)
    problem.frames = dataclasses.replace(frames, force_n=made.force)
    problem.observed = problem.at_points(made)
    result = fit(problem, (0.03, 0.2, 0.2, 50.0), max_evaluations=30, k2_max=100.0)
    assert result.x[3] <= 100.0 * (1 + 1e-12)
    assert result.x[3] == pytest.approx(100.0, rel=1e-3), result.x
