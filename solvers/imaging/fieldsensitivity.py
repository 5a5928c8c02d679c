"""The field's force operators B_k^T = Phi_7^T diag(h'_k) G of eq. (I6), without
sparse-sparse products.

Per load case k, B_k^T (N, 3 n) splits by displacement component i into

    T_ik = sum_a Phi^T diag(t_ika) P_a,                                              (I7)

with P_a the physical-derivative operators (n_q, n) and the point weights t_ika from
the case's scaled strains h'_k (eq. I6): t_iii = h'_i + h'_div (normal strain and
divergence), t_ija = h'_(ia) / sqrt 2 for the shear row (ia), a != i. Every T_ik has
the pattern of Phi^T |P|, and its entries are linear in the weights: T_ik.data =
sum_a S_a t_ika with S_a (nnz(T), n_q) holding Phi[q, j] P_a[q, r] at the entry (j, r)
and column q. The S_a are formed once per problem; then each case costs three sparse
matrix products with a few dense columns instead of a product of two sparse matrices
(ten times slower per operation in scipy).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

SHEAR_ROWS = {(0, 1): 3, (0, 2): 4, (1, 2): 5}
"""Rows of h' holding the shear strains (Voigt order of ``PhysicalGradient.strain``)."""


class ForceOperators:
    """S_a of eq. (I7) for a field collocation Phi (n_q, N) and operators P_a (n_q, n).

    Parameters
    ----------
    phi : scipy.sparse matrix
        The field at the Gauss points, (n_q, N).
    operators : tuple of scipy.sparse.csr_matrix
        P_0, P_1, P_2 on the free points, (n_q, n).
    """

    def __init__(self, phi: sp.spmatrix, operators):
        phi = sp.csr_matrix(phi)
        n_q, n = operators[0].shape
        pattern = sp.csr_matrix(sum(abs(op) for op in operators))
        pattern.sort_indices()
        keys = _keys(pattern, n)
        aligned = []
        for op in operators:
            values = np.zeros(pattern.nnz)
            op = sp.csr_matrix(op)
            values[np.searchsorted(keys, _keys(op, n))] = op.data
            aligned.append(values)
        # the pairs (Phi entry, P entry) sharing a point q
        phi_count = np.diff(phi.indptr)
        p_count = np.diff(pattern.indptr)
        pairs = phi_count * p_count
        point = np.repeat(np.arange(n_q), pairs)
        offset = np.arange(pairs.sum()) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        repeat_count = np.repeat(p_count, pairs)
        phi_entry = phi.indptr[point] + offset // np.maximum(repeat_count, 1)
        p_entry = pattern.indptr[point] + offset % np.maximum(repeat_count, 1)
        del offset, repeat_count
        result = phi.indices[phi_entry].astype(np.int64) * n + pattern.indices[p_entry]
        unique, position = np.unique(result, return_inverse=True)
        del result
        self.shape = (phi.shape[1], n)
        self.rows, self.columns = np.divmod(unique, n)
        # one CSR pattern for the three maps: the pairs by entry (stable, so that each
        # row's points stay increasing), the maps differing only in their values
        order = np.argsort(np.ravel(position), kind="stable")
        indptr = np.zeros(len(unique) + 1, dtype=np.int64)
        np.cumsum(np.bincount(np.ravel(position), minlength=len(unique)), out=indptr[1:])
        indices = point[order].astype(np.int32)
        phi_values, p_entry = phi.data[phi_entry][order], p_entry[order]
        del position, point, phi_entry, order
        self.maps = [
            sp.csr_matrix((phi_values * values[p_entry], indices, indptr), shape=(len(unique), n_q))
            for values in aligned
        ]

    def blocks(self, weights: np.ndarray) -> list[list[sp.csr_matrix]]:
        """T_ik of eq. (I7) for the weights t (3, 3, n_q, n_cases) [i, a]: [k][i]."""
        n_cases = weights.shape[-1]
        data = sum(
            self.maps[a] @ weights[:, a].transpose(1, 0, 2).reshape(weights.shape[2], -1)
            for a in range(3)
        ).reshape(-1, 3, n_cases)
        return [
            [
                sp.csr_matrix((data[:, i, k], (self.rows, self.columns)), shape=self.shape)
                for i in range(3)
            ]
            for k in range(n_cases)
        ]


def point_weights(scaled: np.ndarray) -> np.ndarray:
    """t of eq. (I7), (3, 3, n_q, n_cases), from the scaled strains h' (7, n_q, n_cases)."""
    out = np.zeros((3, 3) + scaled.shape[1:])
    for i in range(3):
        out[i, i] = scaled[i] + scaled[6]
    for (i, j), row in SHEAR_ROWS.items():
        out[i, j] = out[j, i] = scaled[row] / np.sqrt(2.0)
    return out


def _keys(matrix: sp.csr_matrix, width: int) -> np.ndarray:
    rows = np.repeat(np.arange(matrix.shape[0], dtype=np.int64), np.diff(matrix.indptr))
    return rows * width + matrix.indices
