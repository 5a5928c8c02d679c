"""Sparse Cholesky through CHOLMOD (SuiteSparse) as the cvxopt wheel ships it.

K(p) of the continuum is symmetric positive definite, and SuperLU factorises it as a
general matrix. CHOLMOD's supernodal Cholesky is 2-5x faster on it and its solves
10-30x (docs/results/factorisation.md, measured by ``dvs bench factorisation``).

- **Library.** ``cvxopt.cholmod`` (the ``cholmod`` extra of pyproject.toml, installed
  by ``make``): a manylinux/macOS/Windows wheel that carries CHOLMOD with its own
  OpenBLAS, so nothing outside the virtual environment is needed. Where cvxopt is not
  installed, or ``DVS_FACTORISATION=superlu`` is set, ``factorised`` returns its
  fallback (SuperLU) and ``backend()`` says so.
- **Use.** ``Cholesky(matrix)`` factorises (AMD ordering, supernodal);
  ``solve`` takes one right-hand side or a matrix of them. A matrix that is not
  positive definite raises ``NotPositiveDefinite``. ``factorised`` is the entry point:
  CHOLMOD for a symmetric positive definite matrix, the fallback otherwise.
- **One pattern, many matrices.** A fit refactorises K(p) of one sparsity pattern many
  times. cvxopt takes a matrix as its own sparse type, whose construction from
  triplets sorts them (0.3 s for the 1.3 M entries of the lower triangle at
  27 x 27 x 4, twice the numeric factorisation). Each of the last ``PATTERNS_KEPT``
  patterns keeps that matrix, and a new matrix of the pattern only copies its values
  in. A closed factor is kept (``SPARES_KEPT``) and refactorised in place by the next
  matrix of its pattern, which skips the ordering and the symbolic analysis and
  reuses the factor's memory.
"""

from __future__ import annotations

import os

import numpy as np
import scipy.sparse as sp

try:
    import cvxopt
    import cvxopt.cholmod as _cvxopt_cholmod
except ImportError:  # the optional ``cholmod`` extra: SuperLU serves
    cvxopt = _cvxopt_cholmod = None


class NotPositiveDefinite(ValueError):
    """The matrix has a non-positive pivot: it is not SPD (or not numerically)."""


PATTERNS_KEPT = 4
"""Sparsity patterns whose cvxopt matrix is kept (most recent first): a diagnosis with
base_compliance alternates between four (K, K with the extra state, and the two blocks
of the block-triangular case)."""

SPARES_KEPT = 2
"""Numeric factors kept after their ``Cholesky`` is closed, for the next matrix of their
pattern."""


def available() -> bool:
    """True when cvxopt's CHOLMOD is installed and ``DVS_FACTORISATION`` is not
    ``superlu``."""
    return _cvxopt_cholmod is not None and os.environ.get("DVS_FACTORISATION") != "superlu"


def backend() -> str:
    """What ``factorised`` uses for a symmetric positive definite matrix."""
    return f"CHOLMOD (cvxopt {cvxopt.__version__})" if available() else "SuperLU"


def symmetric(matrix: sp.spmatrix, tolerance: float = 1e-10) -> bool:
    """True when u^T A v = v^T A u for two random vectors, to ``tolerance`` relative.

    Two products instead of forming A - A^T (0.06 s against 0.6 s at 13.5 M nonzeros).
    An asymmetry far below the tolerance passes; the Cholesky factor then solves the
    symmetric part, and ``solvers.forward.linearpath.solve_states`` refines against A.
    """
    rng = np.random.default_rng(0)
    u, v = rng.standard_normal((2, matrix.shape[0]))
    au, av = matrix @ u, matrix @ v
    scale = max(float(np.linalg.norm(au) * np.linalg.norm(v)), 1e-300)
    return bool(abs(float(u @ av) - float(v @ au)) <= tolerance * scale)


def symmetric_lu(matrix: sp.spmatrix):
    """SuperLU for a symmetric positive definite matrix: a symmetric ordering, no pivoting."""
    import scipy.sparse.linalg as spla

    return spla.splu(
        sp.csc_matrix(matrix),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


def factorised(matrix: sp.spmatrix, fallback, known_symmetric: bool = False):
    """``Cholesky(matrix)`` when CHOLMOD is there and the matrix is symmetric positive
    definite, else ``fallback(matrix)`` (an object with ``solve``, SuperLU's say).
    ``known_symmetric`` skips the check when the caller made it."""
    if available() and (known_symmetric or symmetric(matrix)):
        try:
            return Cholesky(matrix)
        except NotPositiveDefinite:
            pass
    return fallback(matrix)


class _Pattern:
    """One sparsity pattern: its CSC index arrays (the key), where its lower triangle
    sits in the CSC values, and cvxopt's matrix of that lower triangle (CCS order is
    the CSC order of sorted indices, so values are copied in as they stand)."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray):
        n = indptr.size - 1
        self.indptr, self.indices = indptr.copy(), indices.copy()
        columns = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        self.lower = np.flatnonzero(indices >= columns)
        rows = indices[self.lower].astype(np.int64)
        self.matrix = cvxopt.spmatrix(
            cvxopt.matrix(np.zeros(self.lower.size)),
            cvxopt.matrix(rows),
            cvxopt.matrix(columns[self.lower]),
            (n, n),
        )

    def matches(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        return (
            self.indices.size == indices.size
            and np.array_equal(self.indptr, indptr)
            and np.array_equal(self.indices, indices)
        )


_patterns: list[_Pattern] = []
_spares: list = []  # [(pattern, numeric factor)], most recent first


def _pattern(csc: sp.csc_matrix) -> _Pattern:
    """The kept pattern of ``csc`` (moved to the front), else a new one."""
    for k, pattern in enumerate(_patterns):
        if pattern.matches(csc.indptr, csc.indices):
            _patterns.insert(0, _patterns.pop(k))
            return pattern
    pattern = _Pattern(csc.indptr, csc.indices)
    _patterns.insert(0, pattern)
    while len(_patterns) > PATTERNS_KEPT:
        gone = _patterns.pop()
        _spares[:] = [entry for entry in _spares if entry[0] is not gone]
    return pattern


def _spare(pattern: _Pattern):
    """A kept numeric factor of ``pattern``, else None."""
    for k, (owner, factor) in enumerate(_spares):
        if owner is pattern:
            del _spares[k]
            return factor
    return None


class Cholesky:
    """P A P^T = L L^T of a sparse symmetric positive definite matrix (CHOLMOD).

    Parameters
    ----------
    matrix : scipy.sparse matrix
        Square and symmetric; only its lower triangle is read.

    Raises
    ------
    RuntimeError
        When CHOLMOD is not available (see ``available``).
    NotPositiveDefinite
        When a pivot is not positive.
    """

    def __init__(self, matrix):
        if not available():
            raise RuntimeError(f"CHOLMOD is not available ({backend()} serves)")
        compressed = sp.issparse(matrix) and matrix.format == "csc" and matrix.dtype == float
        csc = matrix if compressed else sp.csc_matrix(matrix, dtype=float)
        csc.sort_indices()  # a no-op where the order is known
        self.n = csc.shape[0]
        self._pattern = _pattern(csc)
        lower = self._pattern.matrix
        lower.V = cvxopt.matrix(csc.data[self._pattern.lower])
        factor = _spare(self._pattern)
        if factor is None:
            factor = _cvxopt_cholmod.symbolic(lower)
        try:
            _cvxopt_cholmod.numeric(lower, factor)
        except ArithmeticError as error:  # the factor is dropped, never kept as a spare
            self._factor = None
            message = f"pivot {error.args[0]} of {self.n} is not positive"
            raise NotPositiveDefinite(message) from None
        self._factor = factor

    def solve(self, right: np.ndarray) -> np.ndarray:
        """A^-1 right, for a vector or the columns of a matrix."""
        right = np.asarray(right, dtype=float)
        block = cvxopt.matrix(np.asfortranarray(right.reshape(self.n, -1)))
        _cvxopt_cholmod.solve(self._factor, block)
        return np.asarray(block).reshape(right.shape)

    def solve_columns(self, right: np.ndarray) -> np.ndarray:
        """A^-1 right for the columns of a matrix, four at a time: cvxopt's ``solve``
        passes CHOLMOD one column at a time, its ``spsolve`` (a sparse right-hand side)
        four, which CHOLMOD's supernodal solve treats as a block (about half the time
        for many columns; docs/results/imaging-speed.md). The same solution to
        rounding."""
        right = np.asarray(right, dtype=float)
        if right.ndim < 2 or right.shape[1] < 2:
            return self.solve(right)
        sparse = cvxopt.sparse(cvxopt.matrix(np.asfortranarray(right)))
        solved = _cvxopt_cholmod.spsolve(self._factor, sparse)
        return np.asarray(cvxopt.matrix(solved)).reshape(right.shape)

    def close(self) -> None:
        """Release the factor (also done when the object is collected): kept as a spare
        of its pattern while that pattern is kept."""
        factor, self._factor = getattr(self, "_factor", None), None
        pattern = getattr(self, "_pattern", None)
        if factor is None or pattern is None:
            return
        try:
            if any(kept is pattern for kept in _patterns):
                _spares.insert(0, (pattern, factor))
                del _spares[SPARES_KEPT:]
        except TypeError:  # module globals gone at interpreter exit
            pass

    def __del__(self):
        self.close()
