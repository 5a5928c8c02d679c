"""Element-batched assembly: integrals over the knot-span elements as stacks of small
dense products, scattered once into one sparse pattern (docs/continuum.md).

Every Gauss point of a volume spline lies in one knot span, its element, where the same
k = (p_u + 1)(p_v + 1)(p_w + 1) basis functions are nonzero. A scalar block of eq. (C3),

    G_ab = integral f P_a^T P_b dV = sum_e sum_(q in e) w_q g_qa g_qb^T,

is then a stack of (k, k) products, one per element (g_qa the k values of P_a at q),
added into the pattern of basis functions that share an element. The stacked K_mu and
K_lambda take those blocks as their 3 x 3 block rows on one pattern. No sparse-sparse
product is formed, which at 27 x 27 x 4 was most of the model's build.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class ElementAssembly:
    """The points grouped by element and the scalar pattern, made once per gradient.

    Parameters
    ----------
    operators : sequence of scipy.sparse.csr_matrix
        P_a, (n_q, n), all on one pattern with k entries per row (``of`` checks).
    """

    def __init__(self, operators):
        first = operators[0]
        n_q, n = first.shape
        k = int(first.indptr[1] - first.indptr[0])
        support = first.indices.reshape(n_q, k)
        # a span's support is a block of the tensor grid: its first index names it
        _, at, owner = np.unique(support[:, 0], return_index=True, return_inverse=True)
        elements, owner = support[at], np.ravel(owner)
        if not np.array_equal(elements[owner], support):
            raise ValueError("the points' supports are not blocks of a tensor grid")
        per_element = np.bincount(owner)
        if np.any(per_element != per_element[0]):
            raise ValueError("the elements hold different numbers of Gauss points")
        self.order = np.argsort(owner, kind="stable")
        self.n, self.k, self.elements = n, k, elements
        q = int(per_element[0])
        self.values = np.stack(
            [op.data.reshape(n_q, k)[self.order].reshape(len(elements), q, k) for op in operators]
        )  # (3, E, Q, k)
        rows = np.repeat(elements, k, axis=1).ravel().astype(np.int64)
        cols = np.tile(elements, (1, k)).ravel().astype(np.int64)
        keys, self.position = np.unique(rows * n + cols, return_inverse=True)
        self.position = np.ravel(self.position)
        self.indices = (keys % n).astype(np.int32)
        self.indptr = np.searchsorted(keys // n, np.arange(n + 1)).astype(np.int32)

    @classmethod
    def of(cls, operators) -> ElementAssembly | None:
        """The assembly, or None when the operators do not share one uniform pattern."""
        first = sp.csr_matrix(operators[0])
        counts = np.diff(first.indptr)
        same = all(
            np.array_equal(first.indptr, op.indptr) and np.array_equal(first.indices, op.indices)
            for op in operators[1:]
        )
        if not same or counts.size == 0 or np.any(counts != counts[0]):
            return None
        try:
            return cls(operators)
        except ValueError:
            return None

    def scalar_blocks(self, weight: np.ndarray) -> dict:
        """G_ab's entries on the scalar pattern, for every (a, b), at point weights w_q."""
        w = np.asarray(weight, dtype=float)[self.order].reshape(self.values.shape[1:3])
        size = self.indices.size
        blocks = {}
        for a in range(3):
            weighted = self.values[a] * w[:, :, None]  # (E, Q, k)
            for b in range(a, 3):
                local = np.matmul(weighted.transpose(0, 2, 1), self.values[b])  # (E, k, k)
                if a == b:  # symmetric up to rounding: made exactly so, element by element
                    local = 0.5 * (local + local.transpose(0, 2, 1))
                blocks[a, b] = np.bincount(self.position, local.ravel(), minlength=size)
                if a != b:
                    flipped = local.transpose(0, 2, 1).ravel()
                    blocks[b, a] = np.bincount(self.position, flipped, minlength=size)
        return blocks

    def stacked(self, blocks: dict) -> sp.csr_matrix:
        """The (3 n, 3 n) matrix whose block (i, k) has the entries ``blocks[i, k]`` on
        the scalar pattern (stacked order: the x components of every point, then y, z)."""
        n, indptr, size = self.n, self.indptr, self.indices.size
        counts = np.diff(indptr)
        row = np.repeat(np.arange(n), counts)
        within = np.arange(size) - indptr[row]
        data = np.empty(9 * size)
        indices = np.empty(9 * size, dtype=np.int32)
        for i in range(3):
            for k in range(3):
                at = 3 * size * i + 3 * indptr[row] + k * counts[row] + within
                data[at] = blocks[i, k]
                indices[at] = self.indices + k * n
        big_indptr = np.concatenate(
            [3 * indptr[:-1] + 3 * size * i for i in range(3)] + [[9 * size]]
        ).astype(np.int64)
        return sp.csr_matrix((data, indices, big_indptr), shape=(3 * n, 3 * n))
