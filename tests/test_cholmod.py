"""CHOLMOD through ctypes (solvers/linalg/cholmod.py): the same solutions as SuperLU, the
fallbacks, and the switch. Skipped where the system has no libcholmod.so.3."""

import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.linalg import cholmod

pytestmark = pytest.mark.skipif(not cholmod.available(), reason="no CHOLMOD 3 on this system")


def _elasticity(shape=(6, 5, 3)):
    from experiments.inverse.factorisation import clamped_elasticity

    return clamped_elasticity(shape, (30.0, 25.0, 5.0))


def test_the_solution_is_superlus_for_one_and_many_right_hand_sides():
    matrix = _elasticity()
    right = np.random.default_rng(0).standard_normal((matrix.shape[0], 4))
    factor = cholmod.Cholesky(matrix)
    reference = spla.splu(matrix).solve(right)
    scale = np.abs(reference).max()
    assert np.abs(factor.solve(right) - reference).max() <= 1e-10 * scale
    assert np.abs(factor.solve(right[:, 1]) - reference[:, 1]).max() <= 1e-10 * scale
    assert factor.solve(right[:, 1]).shape == (matrix.shape[0],)


def test_factorised_falls_back_for_indefinite_and_unsymmetric_matrices():
    matrix = _elasticity()
    assert cholmod.symmetric(matrix)
    assert isinstance(cholmod.factorised(matrix, spla.splu), cholmod.Cholesky)
    shifted = (matrix - 2.0 * abs(matrix).max() * sp.eye(matrix.shape[0])).tocsc()
    with pytest.raises(cholmod.NotPositiveDefinite):
        cholmod.Cholesky(shifted)
    assert not isinstance(cholmod.factorised(shifted, spla.splu), cholmod.Cholesky)
    skew = matrix.tolil()
    skew[0, 1] += 1e-3 * abs(matrix).max()
    skew = skew.tocsc()
    assert not cholmod.symmetric(skew)
    solved = cholmod.factorised(skew, spla.splu)
    assert not isinstance(solved, cholmod.Cholesky)
    right = np.ones(matrix.shape[0])
    assert np.allclose(skew @ solved.solve(right), right)


def test_the_environment_switches_it_off():
    code = "from solvers.linalg import cholmod; print(cholmod.backend())"
    env = {"DVS_FACTORISATION": "superlu", "PATH": ""}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.stdout.strip() == "SuperLU", out.stderr
    assert cholmod.backend().startswith("CHOLMOD")


def test_one_analysis_serves_every_matrix_of_a_pattern_and_each_factor_stays_its_own():
    """The symbolic analysis is kept per pattern (``ANALYSES_KEPT``): a second matrix
    of the same pattern reuses it, and both factors, alive together, solve their own."""
    matrix = _elasticity((5, 4, 3))
    shift = sp.diags(np.linspace(0.1, 1.0, matrix.shape[0]) * abs(matrix).max())
    other = (2.0 * matrix + shift).tocsc()  # the diagonal is in the pattern: the same one
    assert np.array_equal(other.indices, matrix.indices)
    right = np.random.default_rng(2).standard_normal(matrix.shape[0])
    cholmod._analyses.clear()
    first, second = cholmod.Cholesky(matrix), cholmod.Cholesky(other)
    assert len(cholmod._analyses) == 1  # one pattern, one analysis
    for factor, reference in ((first, matrix), (second, other)):
        solved = factor.solve(right)
        assert np.abs(reference @ solved - right).max() <= 1e-10 * np.abs(right).max()
    shapes = [(6, 4, 3), (4, 6, 3), (5, 5, 3), (6, 5, 3), (5, 6, 3)]
    for shape in shapes:
        cholmod.Cholesky(_elasticity(shape))
    assert len(cholmod._analyses) == cholmod.ANALYSES_KEPT


def test_the_factorisation_takes_the_cores_and_leaves_blas_on_one_thread(monkeypatch):
    """Inside ``Cholesky`` CHOLMOD's OpenBLAS runs on ``threads()`` threads (the
    supernodes are dense blocks); outside it stays on one, where SuperLU's thin solves
    share that library's threads. One thread or several, the solution is the same."""
    matrix = _elasticity((8, 7, 3))
    right = np.random.default_rng(1).standard_normal((matrix.shape[0], 3))
    single = cholmod.Cholesky(matrix, blas_threads=1).solve(right)
    many = cholmod.Cholesky(matrix, blas_threads=2).solve(right)
    assert np.abs(many - single).max() <= 1e-12 * np.abs(single).max()
    if cholmod._blas_library is not None:
        assert cholmod._blas_library.openblas_get_num_threads() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert cholmod.threads() == 3 and cholmod.Cholesky(matrix).blas_threads == 3
    monkeypatch.setenv("OMP_NUM_THREADS", "not a number")
    assert cholmod.threads() >= 1


def test_a_closed_factor_is_refactorised_in_place_by_the_next_matrix_of_its_pattern():
    """``close`` keeps a successful factor as a spare of its pattern (``SPARES_KEPT``);
    the next ``Cholesky`` of that pattern factorises into it and solves exactly as a
    new factor does. A failed factor is freed, never kept, and spares go with their
    pattern's analysis."""
    matrix = _elasticity((5, 4, 3))
    other = (2.0 * matrix + sp.diags(np.full(matrix.shape[0], abs(matrix).max()))).tocsc()
    right = np.random.default_rng(3).standard_normal((matrix.shape[0], 2))
    cholmod._analyses.clear()
    cholmod._spares.clear()
    fresh = cholmod.Cholesky(other).solve(right)
    first = cholmod.Cholesky(matrix)
    address = first._factor.value
    first.close()
    assert [factor.value for _, factor in cholmod._spares] == [address]
    second = cholmod.Cholesky(other)
    assert second._factor.value == address and not cholmod._spares
    assert np.array_equal(second.solve(right), fresh)
    second.close()
    shifted = (matrix - 2.0 * abs(matrix).max() * sp.eye(matrix.shape[0])).tocsc()
    with pytest.raises(cholmod.NotPositiveDefinite):
        cholmod.Cholesky(shifted)  # took the spare, failed: freed
    assert not cholmod._spares
    kept = [cholmod.Cholesky(matrix) for _ in range(cholmod.SPARES_KEPT + 1)]
    for factor in kept:
        factor.close()
    assert len(cholmod._spares) == cholmod.SPARES_KEPT
    alive = cholmod.Cholesky(matrix)  # outlives its pattern's analysis
    shapes = [(6, 4, 3), (4, 6, 3), (5, 5, 3), (6, 5, 3)][: cholmod.ANALYSES_KEPT]
    for shape in shapes:  # new patterns evict the first's analysis and its spares
        cholmod.Cholesky(_elasticity(shape)).close()
    kept_patterns = {entry[3] for entry in cholmod._analyses}
    assert alive._serial not in kept_patterns
    assert {key for key, _ in cholmod._spares} <= kept_patterns
    spares = list(cholmod._spares)
    alive.close()  # freed: a later analysis at the same address is another pattern
    assert cholmod._spares == spares
    assert len(cholmod._spares) <= cholmod.SPARES_KEPT
