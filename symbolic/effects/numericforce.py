"""The stiffening force of eq. (1) in numbers: the split path's form of
``nonlinear_stiffening`` (``Effect.numeric_force``, ``solvers.diagnosis.splitpath``).

The same arithmetic as the CasADi Functions of ``symbolic.effects.nonlinearity`` (its
module docstring has the formulas), on numpy arrays and scipy matrices: with
a = r0 + G Delta, rel = G Delta, eps = (|a| - L) / L, the difference [f] = f(eps; kb + k)
- f(eps; kb) of s(eps; k) or of its derivatives, w = k_s [s] and q = k_s [ds/deps] / (L |a|),

    F             = -G^T (w * rel),
    dF_i/dDelta_j = -G^T diag(delta_ij w + q rel_i a_j) G,
    dF_i/dc       = -G^T ((rel_i [s]) * springs_of),
    dF/dk         = -G^T ((k_s ds/dk(eps; kb + k)) * rel),     dF/dkb = -G^T ((k_s [ds/dk]) * rel),

F stacked by columns (vec). CasADi evaluates only s(eps; k) and its two derivatives
edge by edge (``_stiffening_parts``); the tangent and the parameter columns come without
CasADi's custom Jacobian, which computes the whole tangent again (docs/realskin.md,
"Speed").
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.model import TissueModel

_QUIET = np.errstate(over="ignore", invalid="ignore")
"""As in CasADi's evaluation, an overflow far from equilibrium gives inf or NaN silently:
Newton reads a g that is not finite as a failed step."""


class NumericStiffening:
    """F, dF/dDelta and dF/dq of eq. (1)'s stiffening force for q = (c, k, kb): the term
    coefficients c, the effect's k and the model's own k0 (``NonlinearStiffening``).

    Parameters
    ----------
    model : TissueModel
        The model whose edges (``TissueModel.edges``) and s(eps; k) it uses.
    parts : casadi.Function
        (eps, k) -> (s, ds/deps, ds/dk) edge by edge (``_stiffening_parts``).
    """

    def __init__(self, model: TissueModel, parts):
        edges = model.edges()
        self.n_free = model.n_free
        self.incidence = sp.csr_matrix(edges.incidence, dtype=float)
        self.gather = sp.csr_matrix(self.incidence.T)
        self.springs_of = np.minimum(np.asarray(edges.values, dtype=float), 0.0)
        self.rest = np.asarray(edges.rest_vectors, dtype=float)
        self.rest_length = np.linalg.norm(self.rest, axis=1)
        self.parts = _EdgeParts(parts, len(self.rest_length))
        self._last = None
        self.mapping, self.indptr, self.indices, self.order = _tangent_layout(self.incidence)

    def _edges(self, delta: np.ndarray, q: np.ndarray) -> tuple:
        """rel, a, |a|, k_s and s, ds/deps, ds/dk at kb + k and at kb, edge by edge; kept
        for the last (Delta, q): Newton factorises where it has just evaluated F."""
        q = np.asarray(q, dtype=float)
        last = self._last
        if last is not None and np.array_equal(last[0], delta) and np.array_equal(last[1], q):
            return last[2]
        c, k, kb = q[:-2], q[-2], q[-1]
        relative = self.incidence @ delta
        vectors = self.rest + relative
        squares = vectors**2
        length = np.sqrt(squares[:, 0] + squares[:, 1] + squares[:, 2])
        strain = (length - self.rest_length) / self.rest_length
        new, old = self.parts(strain, kb + k), self.parts(strain, kb)
        pieces = (relative, vectors, length, self.springs_of @ c, new, old)
        self._last = (np.array(delta), q.copy(), pieces)
        return pieces

    @_QUIET
    def force(self, delta: np.ndarray, q: np.ndarray) -> np.ndarray:
        """vec(F), (3 n_free,) [N]."""
        relative, _, _, springs, new, old = self._edges(delta, q)
        return self._sum(springs * (new[0] - old[0]), relative)

    @_QUIET
    def tangent(self, delta: np.ndarray, q: np.ndarray) -> sp.csc_matrix:
        """d vec(F) / d vec(Delta), (3 n_free)-square CSC with sorted indices [N/mm]."""
        relative, vectors, length, springs, new, old = self._edges(delta, q)
        weight = springs * (new[0] - old[0])
        scale = springs * (new[1] - old[1]) / (self.rest_length * length)
        diagonals = np.empty((relative.shape[0], 9))
        for i in range(3):
            for j in range(3):
                diagonals[:, 3 * i + j] = scale * relative[:, i] * vectors[:, j]
            diagonals[:, 4 * i] += weight
        blocks = self.mapping @ diagonals  # (gram entries, 9): block (i, j) in column 3 i + j
        data = -np.ravel(blocks, order="F")[self.order]
        size = 3 * self.n_free
        out = sp.csc_matrix((data, self.indices.copy(), self.indptr.copy()), shape=(size, size))
        out.has_sorted_indices = True
        return out

    @_QUIET
    def slope(self, delta: np.ndarray, q: np.ndarray) -> np.ndarray:
        """d vec(F) / dq, (3 n_free, n_terms + 2): columns c, then k, then kb."""
        relative, _, _, springs, new, old = self._edges(delta, q)
        change = new[0] - old[0]
        columns = [
            -(self.gather @ ((relative[:, i] * change)[:, None] * self.springs_of))
            for i in range(3)
        ]
        by_c = np.vstack(columns)
        by_k = self._sum(springs * new[2], relative)
        by_kb = self._sum(springs * (new[2] - old[2]), relative)
        return np.column_stack([by_c, by_k, by_kb])

    def _sum(self, weights: np.ndarray, relative: np.ndarray) -> np.ndarray:
        """vec(-G^T (weights * rel))."""
        return -np.ravel(self.gather @ (weights[:, None] * relative), order="F")


class _EdgeParts:
    """(eps, k) -> (s, ds/deps, ds/dk) as numpy arrays, through buffers bound once: a
    call with numpy arguments converts them to CasADi's DM and back, 1.4 ms at 13,047
    edges against 0.1 ms."""

    def __init__(self, parts, n_edges: int):
        strain, k = ca.MX.sym("eps", n_edges), ca.MX.sym("k")
        dense = ca.Function("s_parts", [strain, k], [ca.densify(v) for v in parts(strain, k)])
        self._strain, self._k = np.zeros(n_edges), np.zeros(1)
        self._out = [np.zeros(dense.nnz_out(i)) for i in range(3)]
        self._function = dense  # the buffer evaluates it: kept alive with it
        self._buffer, self._evaluate = dense.buffer()
        for i, array in enumerate((self._strain, self._k)):
            self._buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self._out):
            self._buffer.set_res(i, memoryview(array))

    def __call__(self, strain: np.ndarray, k: float) -> list[np.ndarray]:
        self._strain[:] = strain
        self._k[0] = k
        self._evaluate()
        return [array.copy() for array in self._out]


def gram_layout(incidence: sp.csr_matrix) -> tuple[sp.csc_matrix, sp.csr_matrix]:
    """The CSC pattern of G^T diag(d) G (sorted) and the matrix M with its entries, in
    that pattern's order, equal to M d."""
    pattern = sp.csc_matrix(abs(incidence).T @ abs(incidence))
    pattern.sort_indices()
    position = sp.csc_matrix(
        (np.arange(pattern.nnz, dtype=float) + 1, pattern.indices, pattern.indptr),
        shape=pattern.shape,
    ).tocsr()
    coo = incidence.tocoo()
    by_edge: dict[int, list[tuple[int, float]]] = {}
    for e, a, sign in zip(coo.row, coo.col, coo.data):
        by_edge.setdefault(int(e), []).append((int(a), float(sign)))
    rows, cols, values = [], [], []
    for e, ends in by_edge.items():
        for a, sa in ends:
            for b, sb in ends:
                rows.append(int(position[a, b]) - 1)
                cols.append(e)
                values.append(sa * sb)
    mapping = sp.csr_matrix((values, (rows, cols)), shape=(pattern.nnz, incidence.shape[0]))
    return pattern, mapping


def _tangent_layout(incidence: sp.csr_matrix) -> tuple:
    """``gram_layout``'s M, and the CSC pattern of the 3 x 3 blocks of dF/dDelta
    together: its indptr and indices, and where each of its entries lies among the
    blocks' values stacked block by block (block (i, j) the (3 i + j)-th)."""
    pattern, mapping = gram_layout(incidence)
    labels = [
        [
            sp.csc_matrix(
                ((3 * i + j) * pattern.nnz + np.arange(pattern.nnz) + 1.0, *_arrays(pattern)),
                shape=pattern.shape,
            )
            for j in range(3)
        ]
        for i in range(3)
    ]
    whole = sp.csc_matrix(sp.bmat(labels))
    whole.sort_indices()
    order = whole.data.astype(np.int64) - 1
    return mapping, whole.indptr.copy(), whole.indices.copy(), order


def _arrays(pattern: sp.csc_matrix) -> tuple:
    return pattern.indices, pattern.indptr
