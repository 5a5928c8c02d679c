"""CHOLMOD through cvxopt (solvers/linalg/cholmod.py): the same solutions as SuperLU,
small residuals, the fallbacks, the switch, and the patterns and factors kept. Skipped
where cvxopt (the ``cholmod`` extra) is not installed."""

import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.linalg import cholmod

pytestmark = pytest.mark.skipif(not cholmod.available(), reason="cvxopt is not installed")


def _elasticity(shape=(6, 5, 3), degrees=(2, 2, 2)):
    from experiments.inverse.factorisation import clamped_elasticity

    return clamped_elasticity(shape, (30.0, 25.0, 5.0), degrees)


def test_the_factor_solves_the_projects_stiffness_to_a_small_residual():
    """K of a clamped 3 x 3 x 2 spline box (the continuum's degrees): |K x - b| / |b|
    below 1e-10 for one right-hand side and for several, from CSC and CSR input."""
    matrix = _elasticity((7, 6, 4), (3, 3, 2))
    assert cholmod.symmetric(matrix)
    right = np.random.default_rng(4).standard_normal((matrix.shape[0], 3))
    for given in (matrix, matrix.tocsr()):
        factor = cholmod.Cholesky(given)
        solved = factor.solve(right)
        assert np.linalg.norm(matrix @ solved - right) <= 1e-10 * np.linalg.norm(right)
        one = factor.solve(right[:, 0])
        assert one.shape == (matrix.shape[0],)
        assert np.linalg.norm(matrix @ one - right[:, 0]) <= 1e-10 * np.linalg.norm(right[:, 0])


def test_the_solution_is_superlus_for_one_and_many_right_hand_sides():
    matrix = _elasticity()
    right = np.random.default_rng(0).standard_normal((matrix.shape[0], 4))
    factor = cholmod.Cholesky(matrix)
    reference = spla.splu(matrix).solve(right)
    scale = np.abs(reference).max()
    assert np.abs(factor.solve(right) - reference).max() <= 1e-10 * scale
    assert np.abs(factor.solve(right[:, 1]) - reference[:, 1]).max() <= 1e-10 * scale
    assert np.abs(factor.solve(np.ascontiguousarray(right)) - reference).max() <= 1e-10 * scale


def test_factorised_falls_back_for_indefinite_and_unsymmetric_matrices():
    matrix = _elasticity()
    assert cholmod.symmetric(matrix)
    assert isinstance(cholmod.factorised(matrix, spla.splu), cholmod.Cholesky)
    shifted = (matrix - 2.0 * abs(matrix).max() * sp.eye(matrix.shape[0])).tocsc()
    with pytest.raises(cholmod.NotPositiveDefinite):
        cholmod.Cholesky(shifted)
    fallen = cholmod.factorised(shifted, spla.splu)
    assert not isinstance(fallen, cholmod.Cholesky)
    right = np.ones(matrix.shape[0])
    assert np.allclose(shifted @ fallen.solve(right), right)
    skew = matrix.tolil()
    skew[0, 1] += 1e-3 * abs(matrix).max()
    skew = skew.tocsc()
    assert not cholmod.symmetric(skew)
    solved = cholmod.factorised(skew, spla.splu)
    assert not isinstance(solved, cholmod.Cholesky)
    assert np.allclose(skew @ solved.solve(right), right)


def test_the_environment_switches_it_off():
    code = "from solvers.linalg import cholmod; print(cholmod.backend())"
    env = {"DVS_FACTORISATION": "superlu", "PATH": ""}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.stdout.strip() == "SuperLU", out.stderr
    assert cholmod.backend().startswith("CHOLMOD (cvxopt")


def test_one_pattern_serves_every_matrix_of_it_and_each_factor_stays_its_own():
    """A pattern is kept (``PATTERNS_KEPT``): a second matrix of it reuses it, and both
    factors, alive together, solve their own matrix."""
    matrix = _elasticity((5, 4, 3))
    shift = sp.diags(np.linspace(0.1, 1.0, matrix.shape[0]) * abs(matrix).max())
    other = (2.0 * matrix + shift).tocsc()  # the diagonal is in the pattern: the same one
    assert np.array_equal(other.indices, matrix.indices)
    right = np.random.default_rng(2).standard_normal(matrix.shape[0])
    cholmod._patterns.clear()
    first, second = cholmod.Cholesky(matrix), cholmod.Cholesky(other)
    assert len(cholmod._patterns) == 1  # one pattern
    for factor, reference in ((first, matrix), (second, other)):
        solved = factor.solve(right)
        assert np.abs(reference @ solved - right).max() <= 1e-10 * np.abs(right).max()
    for shape in [(6, 4, 3), (4, 6, 3), (5, 5, 3), (6, 5, 3), (5, 6, 3)]:
        cholmod.Cholesky(_elasticity(shape))
    assert len(cholmod._patterns) == cholmod.PATTERNS_KEPT


def test_a_closed_factor_is_refactorised_in_place_by_the_next_matrix_of_its_pattern():
    """``close`` keeps a successful factor as a spare of its pattern (``SPARES_KEPT``);
    the next ``Cholesky`` of that pattern factorises into it and solves exactly as a
    new factor does. A failed factor is dropped, never kept, and spares go with their
    pattern."""
    matrix = _elasticity((5, 4, 3))
    other = (2.0 * matrix + sp.diags(np.full(matrix.shape[0], abs(matrix).max()))).tocsc()
    right = np.random.default_rng(3).standard_normal((matrix.shape[0], 2))
    cholmod._patterns.clear()
    cholmod._spares.clear()
    fresh = cholmod.Cholesky(other).solve(right)
    first = cholmod.Cholesky(matrix)
    factor = first._factor
    first.close()
    assert [kept for _, kept in cholmod._spares] == [factor]
    second = cholmod.Cholesky(other)
    assert second._factor is factor and not cholmod._spares
    assert np.allclose(second.solve(right), fresh, rtol=1e-12, atol=1e-12 * np.abs(fresh).max())
    second.close()
    shifted = (matrix - 2.0 * abs(matrix).max() * sp.eye(matrix.shape[0])).tocsc()
    with pytest.raises(cholmod.NotPositiveDefinite):
        cholmod.Cholesky(shifted)  # took the spare, failed: dropped
    assert not cholmod._spares
    kept = [cholmod.Cholesky(matrix) for _ in range(cholmod.SPARES_KEPT + 1)]
    for factor in kept:
        factor.close()
    assert len(cholmod._spares) == cholmod.SPARES_KEPT
    alive = cholmod.Cholesky(matrix)  # outlives its pattern
    for shape in [(6, 4, 3), (4, 6, 3), (5, 5, 3), (6, 5, 3)][: cholmod.PATTERNS_KEPT]:
        cholmod.Cholesky(_elasticity(shape)).close()  # new patterns evict the first
    assert not any(pattern is alive._pattern for pattern in cholmod._patterns)
    assert all(any(p is owner for p in cholmod._patterns) for owner, _ in cholmod._spares)
    spares = list(cholmod._spares)
    alive.close()  # its pattern is gone: not kept
    assert cholmod._spares == spares
    assert np.allclose(
        cholmod.Cholesky(matrix).solve(right[:, 0]), spla.spsolve(matrix, right[:, 0])
    )
