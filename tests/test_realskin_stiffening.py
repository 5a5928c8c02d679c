"""The strain-stiffening planar energy (``symbolic.planar_stiffening``) and its whitened fit
(``experiments.realskin.stiffening``), docs/realskin.md "Strain stiffening on the
authors' model".

The energy tests need no data; the fit-level test reads the healthy frames from
``../shared/data`` and skips when it is absent.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from experiments.realskin import authors, mesh2d
from experiments.realskin.data import load_case
from experiments.realskin.geometry import Rect, SkinGeometry
from experiments.realskin.stiffening import WhitenedExtensometer, fit
from symbolic.planar_neohookean import PlanarNeoHookean
from symbolic.planar_stiffening import PlanarStiffening

GEOMETRY = SkinGeometry(
    region=Rect(0.0, -5.0, 100.0, 45.0),
    pad_moving=Rect(26.0, 16.0, 34.0, 24.0),
    pad_fixed=Rect(66.0, 16.0, 74.0, 24.0),
    keloid=None,
    variables={},
)
"""The healthy case's geometry.geo, written out (the energy tests need no data)."""


@pytest.fixture(scope="module")
def coarse():
    return mesh2d.build_mesh(GEOMETRY, 2.0, 6.0)


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
    h = 1e-6
    tangent = model.stiffness(u)
    numeric = (model.residual(u + h * v) - model.residual(u - h * v)) / (2 * h)
    assert np.linalg.norm(numeric - tangent @ v) < 1e-7 * np.linalg.norm(tangent @ v)
    assert abs(tangent - tangent.T).max() < 1e-13 * abs(tangent).max()
    slope = (model.energy(u + h * v) - model.energy(u - h * v)) / (2 * h)
    assert abs(slope - model.residual(u) @ v) < 1e-7 * abs(slope)


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


def test_at_rest_the_added_term_has_no_energy_or_stress_but_a_bulk_stiffness(coarse):
    """At u = 0: W = 0 and P = 0, and the tangent gains 4 k1 d_iJ d_kL (s = I1 - 2 is
    linear in the strain, so the term is 2 k1 (tr eps)^2: lam + 4 k1 at small strain)."""
    model, _, _, _ = _random_state(coarse, seed=3)
    u = np.zeros(2 * coarse.n_nodes)
    reference = PlanarNeoHookean(coarse.points, coarse.triangles, "strain")
    reference.set_parameters(model.young, model.poisson)
    assert model.energy(u) == 0.0
    assert np.abs(model.residual(u)).max() < 1e-15
    eye = np.eye(2)
    bulk = 4.0 * model.k1[:, None, None, None, None] * np.einsum("iJ,kL->iJkL", eye, eye)
    added = model.stiffness(u) - reference.stiffness(u)
    expected = model.mesh.assemble_matrix(np.broadcast_to(bulk, (coarse.n_triangles, 2, 2, 2, 2)))
    assert abs(added - expected).max() < 1e-12 * abs(expected).max()


def test_the_whitened_fit_recovers_k1_and_k2_from_synthetic_data(shared_data):
    """Noise-free data made by the stiffening model on our coarse mesh (8 healthy frames to
    the full travel); from (E, nu, k1, k2) = (0.05, 0.3, 0.01, 1) the fit recovers the
    truth (0.03, 0.2, 0.05, 3) within 5 % for E, k1, k2 and 0.01 for nu."""
    data = load_case("healthy")
    frames = authors.load_frames(data, 10.0, count=8)
    mesh = mesh2d.build_mesh(data.geometry, 3.0)
    keep = ~np.asarray(data.spurious, dtype=bool)
    problem = WhitenedExtensometer(mesh, frames, 4, 0.0118, 1.5e-5, keep)
    truth = np.array([0.03, 0.2, 0.05, 3.0])
    made = problem.solve(truth, sensitivities=False)
    problem.frames = dataclasses.replace(frames, force_n=made.force)
    problem.observed = problem.at_points(made)
    result = fit(problem, (0.05, 0.3, 0.01, 1.0))
    relative = np.abs(result.x - truth) / truth
    assert relative[[0, 2, 3]].max() < 0.05, result.x
    assert abs(result.x[1] - truth[1]) < 0.01, result.x
