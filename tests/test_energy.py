"""Mass, damping and stiffness matrices (eq. 11-18)."""

import numpy as np
import pytest
import scipy.sparse as sp

from experiments.phantom.forehead import forehead_model
from symbolic.basis import VolumeBasis
from symbolic.energy import damping_matrix, mass_matrix, stiffness_terms


@pytest.fixture(scope="module")
def model():
    return forehead_model(parameters={"alpha_u": 2.6, "alpha_v": 0.18, "alpha_w": 1.7, "beta": 0.3})


def test_stiffness_is_symmetric_psd_with_translations_in_null_space(model):
    k = model.stiffness_matrix().toarray()
    scale = np.abs(k).max()
    assert np.max(np.abs(k - k.T)) < 1e-14 * scale
    assert np.max(np.abs(k.sum(axis=1))) < 1e-12 * scale
    eigenvalues = np.linalg.eigvalsh(k)
    assert eigenvalues.min() > -1e-12 * scale
    for axis in range(3):
        translation = np.zeros_like(model.rest)
        translation[:, axis] = 1.0
        assert np.max(np.abs(k @ translation)) < 1e-12 * scale


def test_stiffness_with_inner_layer_fixed_is_positive_definite(model):
    k_free = model.free_block(model.stiffness_matrix()).toarray()
    eigenvalues = np.linalg.eigvalsh(k_free)
    assert eigenvalues.min() > 1e-8 * eigenvalues.max()


def test_mass_matrix_integrates_density():
    """1^T M 1 = integral of mu over the parameter cube."""
    basis = VolumeBasis((6, 5, 2), (3, 3, 1))
    mass = mass_matrix(basis, density=lambda p: 1 + p[:, 0] * p[:, 1])
    ones = np.ones(basis.size)
    assert ones @ mass @ ones == pytest.approx(1.25, rel=1e-12)


def test_quadrature_rule_is_exact():
    basis = VolumeBasis((7, 6, 3), (3, 3, 2))
    pairs = [
        (mass_matrix(basis), mass_matrix(basis, extra_points=3)),
        (damping_matrix(basis, 15.0), damping_matrix(basis, 15.0, extra_points=3)),
    ]
    default, more = stiffness_terms(basis), stiffness_terms(basis, extra_points=3)
    pairs += [(default[name], more[name]) for name in default]
    for exact, refined in pairs:
        assert abs(exact - refined).max() < 1e-12 * abs(refined).max()


def test_spatially_varying_tension_is_linear_in_the_field():
    basis = VolumeBasis((5, 5, 2), (3, 3, 1))
    one = stiffness_terms(basis, {"alpha_u": lambda p: 1 + 0 * p[:, 0]})["alpha_u"]
    ramp = stiffness_terms(basis, {"alpha_u": lambda p: 1 + p[:, 0]})["alpha_u"]
    only_u = stiffness_terms(basis, {"alpha_u": lambda p: p[:, 0]})["alpha_u"]
    assert abs(ramp - one - only_u).max() < 1e-13
    assert isinstance(one, sp.csr_matrix)


def test_kronecker_assembly_equals_three_dimensional_quadrature():
    """The O(n) factorised path and a plain 3-D Gauss sum give the same matrices."""
    from symbolic.energy import weighted_gram

    basis = VolumeBasis((6, 5, 3), (3, 2, 2))
    constant = lambda p: np.full(len(p), 2.5)  # noqa: E731  (callable forces 3-D quadrature)
    for order in [(0, 0, 0), (1, 0, 0), (0, 0, 1), (1, 1, 0), (0, 2, 0)]:
        fast = weighted_gram(basis, order, 2.5)
        slow = weighted_gram(basis, order, constant)
        assert abs(fast - slow).max() < 1e-12 * abs(slow).max()
