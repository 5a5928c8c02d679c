"""The fast paths of stiffness imaging equal the straightforward ones (docs/imaging.md,
"Speed"): K(c) by the elasticity blocks, J by the distinct observed rows (eq. I6-I7),
the factorisation's many-column solves and its switch, Morozov's search with predicted
comparisons, and the homogeneous fit's one-factorisation path."""

import copy

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import solvers.imaging.fieldproblem as fieldproblem
import solvers.inverse.nested as nested
from solvers.imaging.estimate import SOLVERS
from solvers.imaging.fieldproblem import Factor, FieldProblem
from solvers.imaging.regularization import Tikhonov
from solvers.imaging.weight import discrepancy_weight
from solvers.linalg.cholmod import Cholesky
from symbolic.field import StiffnessField

LENGTHS = (40.0, 40.0, 5.0)


@pytest.fixture(scope="module")
def field_problem(imaging_problem):
    return FieldProblem(imaging_problem, StiffnessField((4, 4)))


def test_stiffness_from_the_elasticity_blocks_is_eq_I2(field_problem):
    c = np.random.default_rng(0).normal(0.0, 0.3, field_problem.size)
    fast, reference = field_problem.stiffness(c), field_problem.reference_stiffness(c)
    assert abs(fast - reference).max() <= 1e-12 * abs(reference).max()


def test_sensitivities_by_the_observed_rows_equal_the_forward_columns(field_problem):
    fp = field_problem
    c = np.random.default_rng(1).normal(0.0, 0.3, fp.size)
    adjoint, forward = fp.sensitivities(c, "adjoint"), fp.sensitivities(c, "forward")
    assert np.abs(adjoint - forward).max() <= 1e-10 * np.abs(forward).max()
    v = np.random.default_rng(2).normal(size=fp.size)
    assert np.allclose(adjoint @ v, fp.jvp(c, v), rtol=1e-9, atol=1e-12 * np.abs(adjoint).max())


def _kkt(stiffness: sp.spmatrix, rows: int = 6) -> sp.csc_matrix:
    """[[K, C^T], [C, 0]] with C holding ``rows`` unknowns: an indefinite saddle matrix."""
    coupling = sp.identity(stiffness.shape[0], format="csr")[:: stiffness.shape[0] // rows][:rows]
    return sp.bmat([[stiffness, coupling.T], [coupling, None]], "csc")


def test_the_factors_many_column_solves_equal_a_sparse_solve(field_problem, monkeypatch):
    """CHOLMOD's blocked solve of K; SuperLU's of the saddle matrix with its factors made
    dense (n^2 doubles under ``DENSE_BYTES``) and without (over it)."""
    stiffness = field_problem.saddle(np.zeros(field_problem.size))
    saddle = _kkt(stiffness)
    rng = np.random.default_rng(3)
    for matrix, definite, dense_bytes in [
        (stiffness, True, fieldproblem.DENSE_BYTES),
        (saddle, False, fieldproblem.DENSE_BYTES),
        (saddle, False, 0),
    ]:
        monkeypatch.setattr(fieldproblem, "DENSE_BYTES", dense_bytes)
        factor = Factor(matrix, definite=definite)
        assert isinstance(factor.lu, Cholesky) == definite
        right = rng.normal(size=(matrix.shape[0], 70))  # >= DENSE_RIGHT_SIDES columns
        reference = spla.spsolve(matrix, right)
        scale = np.abs(reference).max()
        assert np.abs(factor.solve(right) - reference).max() <= 1e-10 * scale
        assert np.abs(factor.solve(right[:, 0]) - reference[:, 0]).max() <= 1e-10 * scale


def test_cholmod_and_superlu_give_the_same_map(imaging_problem, monkeypatch):
    """The factorisation switch (``DVS_FACTORISATION``) does not move the estimate."""
    field = StiffnessField((4, 4))
    maps = []
    for backend in ("cholmod", "superlu"):
        monkeypatch.setenv("DVS_FACTORISATION", backend)
        fp = FieldProblem(imaging_problem, field)
        factor = Factor(fp.saddle(np.zeros(fp.size)))
        assert isinstance(factor.lu, Cholesky) == (backend == "cholmod")
        estimate = SOLVERS["nested-sensitivity"](fp, Tikhonov(field, LENGTHS)).solve(100.0)
        maps.append(estimate.coefficients)
    assert np.abs(maps[0] - maps[1]).max() <= 1e-8 * np.abs(maps[1]).max()


def plain_bisection(fp, regularizer, method, target, bounds=(1e-2, 1e10), tolerance=0.02):
    """Morozov's search as it was before the predictions: every comparison a solve."""
    solve, high = method(fp, regularizer).solve, bounds[1]
    above = below = solve(high)
    low = high
    while below.chi2 > target:
        high, above = low, below
        low /= 10.0
        below = solve(low, above.coefficients)
    while np.log10(high / low) > tolerance:
        middle = np.sqrt(high * low)
        estimate = solve(middle, below.coefficients)
        if estimate.chi2 > target:
            high, above = middle, estimate
        else:
            low, below = middle, estimate
    return below if abs(below.chi2 - target) <= abs(above.chi2 - target) else above


def test_predicted_morozov_search_gives_the_bisections_weight_and_map(field_problem):
    fp = copy.copy(field_problem)
    fp._cache = None
    nodes = fp.field.nodes()
    truth = 0.8 * np.exp(-((nodes[:, 0] - 0.6) ** 2 + (nodes[:, 1] - 0.4) ** 2) / 0.1)
    rng = np.random.default_rng(5)
    states = field_problem.forward(truth).states
    fp.b = [-(a @ s) + rng.normal(0.0, fp.sigma, a.shape[0]) for a, s in zip(fp.A, states)]
    fp.whitening = sp.identity(fp.n_residuals, format="csr") / fp.sigma
    regularizer = Tikhonov(fp.field, LENGTHS)
    method = SOLVERS["nested-sensitivity"]
    reference = plain_bisection(fp, regularizer, method, float(fp.n_residuals))
    choice = discrepancy_weight(fp, regularizer, method)
    assert choice.reached
    assert choice.estimate.weight == reference.weight
    scale = np.abs(reference.coefficients).max()
    assert np.abs(choice.estimate.coefficients - reference.coefficients).max() <= 1e-6 * scale
    assert len(choice.path) < 10  # the bisection made 14 solves here


def test_homogeneous_fit_by_one_factorisation_equals_the_newton_path(imaging_problem, monkeypatch):
    problem = imaging_problem
    z = problem.space.to_internal(np.array([18.0, 0.42]))
    fast = nested.NestedSolver(problem)
    assert fast.continuum is not None
    monkeypatch.setattr(nested.ContinuumSystem, "applies", staticmethod(lambda p: False))
    reference = nested.NestedSolver(problem)
    (r_fast, j_fast), (r_ref, j_ref) = fast.evaluate(z), reference.evaluate(z)
    assert np.abs(r_fast - r_ref).max() <= 1e-10 * np.abs(r_ref).max()
    assert np.abs(j_fast - j_ref).max() <= 1e-10 * np.abs(j_ref).max()
