"""The factorisation of K(p): SuperLU against CHOLMOD, side by side in one process.

K of a clamped quadratic B-spline box in linear elasticity (E 20 kPa, nu 0.45, a
40 x 30 x 5 mm patch with a margin, as the continuum base models of docs/continuum.md),
at the grids step 0 checks on FE tissue. Each solver factorises it twice (the median
is printed) and solves 10 right-hand sides, one BLAS thread each; the ratio is the
figure to compare (a shared machine moves both). CHOLMOD then runs again on the BLAS
threads it uses by default (``cholmod.threads``), wall time side by side.
``solvers.linalg.cholmod`` says why CHOLMOD needs an optimised BLAS. Part of ``make bench``
(``--diagnose``).
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.forward.componentwise import FACTOR_OPTIONS
from solvers.linalg import cholmod
from solvers.linalg.blas import one_thread

GRIDS = ((28, 23, 5), (40, 33, 6))
"""Control grids of the benchmark: row A's first and checked volumes (docs/continuum.md)."""


def clamped_elasticity(shape, lengths=(50.0, 40.0, 5.0)) -> sp.csc_matrix:
    """K [N/mm] of a box of quadratic B-splines, its bottom face clamped: SPD."""
    from symbolic.continuum import box_volume, elasticity_matrices, lame

    volume = box_volume(lengths, tuple(shape), (2, 2, 2))
    terms = elasticity_matrices(volume)
    mu, lam = lame(20.0, 0.45)
    matrix = (mu * terms["shear"] + lam * terms["volumetric"]).tocsc()
    n = volume.basis.size
    bottom = np.flatnonzero(volume.control_points[:, 2] < 1e-9)
    free = np.setdiff1d(np.arange(3 * n), np.concatenate([bottom + k * n for k in range(3)]))
    return matrix[free][:, free].tocsc()


def _timed(factorise, matrix, right):
    times = []
    for _ in range(2):
        begin = time.perf_counter()
        factor = factorise(matrix)
        times.append(time.perf_counter() - begin)
    begin = time.perf_counter()
    solution = factor.solve(right)
    return float(np.median(times)), time.perf_counter() - begin, solution


def factorisation_benchmark(grids=GRIDS, log=print) -> list[dict]:
    """Factorise and solve with SuperLU and with CHOLMOD on each grid; print the ratio."""
    rows = []
    for shape in grids:
        matrix = clamped_elasticity(shape)
        right = np.random.default_rng(0).standard_normal((matrix.shape[0], 10))
        with one_thread():
            lu, lu_solve, reference = _timed(
                lambda m: spla.splu(m, **FACTOR_OPTIONS), matrix, right
            )
            if not cholmod.available():
                log(f"factorisation {'x'.join(map(str, shape))}: SuperLU {lu:.2f} s; no CHOLMOD")
                continue
            chol, chol_solve, solution = _timed(
                lambda m: cholmod.Cholesky(m, blas_threads=1), matrix, right
            )
            threaded, threaded_solve, _ = _timed(cholmod.Cholesky, matrix, right)
        gap = float(np.abs(solution - reference).max() / np.abs(reference).max())
        row = {
            "grid": shape, "unknowns": matrix.shape[0], "nonzeros": matrix.nnz,
            "superlu_s": lu, "cholmod_s": chol, "superlu_solve_s": lu_solve,
            "cholmod_solve_s": chol_solve, "ratio": lu / chol, "gap": gap,
            "threads": cholmod.threads(), "threaded_s": threaded,
            "threaded_solve_s": threaded_solve,
        }  # fmt: skip
        log(
            f"factorisation {'x'.join(map(str, shape))} ({matrix.shape[0]} unknowns, "
            f"{matrix.nnz / 1e6:.1f} M nonzeros): SuperLU {lu:.2f} s, {cholmod.backend()} "
            f"{chol:.2f} s: {row['ratio']:.1f}x; 10 solves {lu_solve:.2f} against "
            f"{chol_solve:.2f} s; solutions agree to {gap:.1e}; CHOLMOD on "
            f"{row['threads']} BLAS threads {threaded:.2f} s ({chol / threaded:.2f}x), "
            f"10 solves {threaded_solve:.2f} s"
        )
        rows.append(row)
    return rows
