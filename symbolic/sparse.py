"""Sparse matrices between scipy and CasADi: conversion and entries on a fixed pattern.

The model's numbers live in scipy sparse matrices; CasADi expressions take them as
sparse DMs (``to_casadi_sparse``). Sums of matrices with coefficients, A = sum_t c_t K_t,
are assembled on the union pattern from each term's entries there (``pattern_entries``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp


def to_casadi_sparse(matrix: sp.spmatrix) -> ca.DM:
    """A scipy sparse matrix as a CasADi sparse DM (structural zeros kept out).

    The matrix is copied first: ``eliminate_zeros`` works in place, and a CSC input would
    otherwise share (and lose) its arrays.
    """
    csc = sp.csc_matrix(matrix, copy=True)
    csc.eliminate_zeros()
    csc.sort_indices()
    pattern = ca.Sparsity(csc.shape[0], csc.shape[1], csc.indptr.tolist(), csc.indices.tolist())
    return ca.DM(pattern, csc.data.tolist())


def pattern_entries(pattern: sp.csc_matrix, matrix: sp.spmatrix) -> np.ndarray:
    """The entries of ``matrix`` at the nonzeros of ``pattern``, in its (CSC) order.

    Every nonzero of ``matrix`` must lie in ``pattern``; positions of ``pattern`` that
    ``matrix`` does not have get 0.
    """
    position = sp.csc_matrix(
        (np.arange(1, pattern.nnz + 1), pattern.indices, pattern.indptr), shape=pattern.shape
    )
    entries = sp.coo_matrix(matrix)
    keep = entries.data != 0
    rows, cols, values = entries.row[keep], entries.col[keep], entries.data[keep]
    data = np.zeros(pattern.nnz)
    if values.size == 0:
        return data
    index = np.asarray(position[rows, cols]).ravel() - 1
    if np.any(index < 0):
        raise ValueError("a matrix has entries outside the pattern")
    np.add.at(data, index, values)
    return data


def combination(blocks: list[sp.spmatrix]) -> tuple[ca.Sparsity, ca.DM]:
    """The union pattern of the blocks and the constant map U from coefficients to its
    nonzeros: sum_t c_t K_t has the nonzeros U c (``pattern_entries``)."""
    pattern = sp.csc_matrix(sum(abs(b) for b in blocks))
    pattern.sort_indices()
    columns = [sp.csc_matrix(pattern_entries(pattern, b)[:, None]) for b in blocks]
    unit = sp.hstack(columns, format="csc")  # column by column: no dense (nnz, T) array
    rows, cols = pattern.shape
    sparsity = ca.Sparsity(rows, cols, pattern.indptr.tolist(), pattern.indices.tolist())
    return sparsity, to_casadi_sparse(unit)


def combined(blocks: tuple[ca.Sparsity, ca.DM], coefficients: ca.MX) -> ca.MX:
    """sum_t c_t K_t as a sparse MX on the union pattern, from the blocks' ``combination``.

    The nonzeros are one constant sparse product U c, however many terms there are: a
    CasADi Function that evaluates it holds U and one result in its work, not a partial
    sum per term.
    """
    sparsity, unit = blocks
    return ca.MX(sparsity, ca.mtimes(unit, coefficients))


class SparseCallback(ca.Callback):
    """A numeric sparse matrix function (v, x, ...) -> A as a CasADi Function (a callback).

    Lets an MX graph use a matrix assembled in numpy (the neo-Hookean tangent in the
    effect library's Newton Jacobian and in the simultaneous inverse's derivatives). It
    has no derivatives of its own, so it may stand only where a derivative is the
    output. ``evaluate(v, x, ...)`` takes dense columns of the given ``sizes`` (one per
    input) and returns a sparse matrix whose nonzeros lie in ``pattern``.
    """

    def __init__(self, name: str, evaluate, sizes: tuple[int, ...], pattern: sp.csc_matrix):
        ca.Callback.__init__(self)
        self._evaluate, self._sizes = evaluate, tuple(sizes)
        self._csc = sp.csc_matrix(pattern)
        self._csc.sort_indices()
        rows, cols = self._csc.shape
        indptr, indices = self._csc.indptr.tolist(), self._csc.indices.tolist()
        self._pattern = ca.Sparsity(rows, cols, indptr, indices)
        self.construct(name, {})

    def get_n_in(self) -> int:
        return len(self._sizes)

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._sizes[i], 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return self._pattern

    def eval(self, args):
        matrix = sp.csc_matrix(self._evaluate(*[np.asarray(a).ravel() for a in args]))
        return [ca.DM(self._pattern, self.entries(matrix))]

    def entries(self, matrix: sp.csc_matrix) -> np.ndarray:
        """The matrix's entries on the pattern: its data when the structure is the
        pattern's (the assemblies' fixed patterns), else ``pattern_entries``."""
        same = (
            matrix.nnz == self._csc.nnz
            and np.array_equal(matrix.indptr, self._csc.indptr)
            and np.array_equal(matrix.indices, self._csc.indices)
        )
        return matrix.data if same else pattern_entries(self._csc, matrix)


class ProductTerm:
    """A unit stiffness term K_t known by its product: ``term @ x`` applies K_t without
    forming it, and ``matrix()`` assembles it on first need (then products use it).

    For a term whose matrix costs far more than a few products, e.g. a field-weighted
    K of the continuum at 27 x 27 x 4: a score test needs only K_t s at the fitted states,
    and K(p) needs K_t only once its coefficient is not zero.

    Parameters
    ----------
    size : int
        K_t is (size, size).
    product : callable
        x (size, m) -> K_t x (size, m).
    assemble : callable
        () -> K_t as a scipy sparse matrix.
    """

    def __init__(self, size: int, product, assemble):
        self.shape = (size, size)
        self._product, self._assemble, self._matrix = product, assemble, None

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        if self._matrix is not None:
            return self._matrix @ x
        return self._product(np.asarray(x, dtype=float))

    def matrix(self) -> sp.csr_matrix:
        """K_t, assembled once."""
        if self._matrix is None:
            self._matrix = sp.csr_matrix(self._assemble())
        return self._matrix


def padded(term, size: int):
    """A square unit term (matrix or ``ProductTerm``) with zero rows and columns appended
    up to ``size`` (the extended state's extra points)."""
    n = term.shape[0]
    if n == size:
        return term if isinstance(term, ProductTerm) else sp.csr_matrix(term)

    def grown(matrix):
        return sp.block_diag([matrix, sp.csr_matrix((size - n, size - n))], format="csr")

    if isinstance(term, ProductTerm):

        def product(x):
            return np.concatenate([term @ x[:n], np.zeros((size - n,) + x.shape[1:])])

        return ProductTerm(size, product, lambda: grown(term.matrix()))
    return grown(sp.csr_matrix(term))


def term_matrix(term) -> sp.spmatrix:
    """The sparse matrix of a unit term (a matrix or a ``ProductTerm``)."""
    return term.matrix() if isinstance(term, ProductTerm) else term
