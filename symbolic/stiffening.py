"""Nonlinear stiffness K(B) updated from control-point distances (docs/model.md, eq. 1).

For every pair a != b with K0_ab != 0:

    eps_ab = (|b_a - b_b| - d_ab) / d_ab,       d_ab = |b0_a - b0_b|,
    K_ab(B) = K0_ab s(eps_ab),                  K_aa(B) = -sum_{b != a} K_ab(B).

Because each row of K(B) sums to zero,

    (K(B) Delta)_a = sum_{b != a} K_ab(B) (Delta_b - Delta_a),

so the elastic force is an edge sum, ``-G^T (k * s(eps) * (G Delta))`` with the
signed incidence matrix G of the edges. With s = 1 it equals K0 Delta.

**Choice** (the paper is silent): s scales only the spring-like couplings,
K0_ab < 0. A B-spline K0 also has positive off-diagonal entries (about 18 %
of them on the default 9 x 9 x 2 grid); scaling those by s >= 1 would
*soften* the model and, at k0 of order 10, destroy the equilibrium. With the
split, K(B) = K0 + sum_springs |K0_ab| (s_ab - 1) L_ab, where L_ab is the
PSD Laplacian of one edge, so K(B) >= K0 whenever s >= 1: stiffening stiffens.
The split is made per stiffness term, so it holds for any alpha, beta >= 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.sparse import to_casadi_sparse

StiffeningFunction = Callable[[ca.MX, ca.MX], ca.MX]
"""s(eps, k0): a CasADi-compatible function with s(0, k0) = 1."""


def quadratic_stiffening(strain, k0):
    """Default s(eps) = 1 + k0 eps^2 (**choice**, docs/model.md, eq. 1)."""
    return 1 + k0 * strain**2


def exponential_stiffening(strain, k0):
    """Alternative s(eps) = exp(k0 eps^2), Fung-like, also 1 at eps = 0."""
    return ca.exp(k0 * strain**2)


@dataclass(frozen=True)
class EdgeSet:
    """Pairs of control points coupled by K0, restricted to the free points.

    Attributes
    ----------
    values : numpy.ndarray
        K_t[a, b] of every stiffness term t on every edge, shape (n_edges, n_terms).
    incidence : scipy.sparse.csr_matrix
        G, shape (n_edges, n_free): +1 at a, -1 at b (columns of fixed points dropped).
    rest_vectors : numpy.ndarray
        b0_a - b0_b, shape (n_edges, 3) [mm].
    """

    values: np.ndarray
    incidence: sp.csr_matrix
    rest_vectors: np.ndarray

    @classmethod
    def build(cls, terms: list[sp.spmatrix], rest: np.ndarray, free: np.ndarray) -> EdgeSet:
        """Edges a < b with a non-zero in any term and at least one free end."""
        pattern = sp.csr_matrix(sum(abs(sp.csr_matrix(t)) for t in terms))
        upper = sp.triu(pattern, k=1).tocoo()
        free_position = np.full(rest.shape[0], -1)
        free_position[free] = np.arange(len(free))
        keep = (free_position[upper.row] >= 0) | (free_position[upper.col] >= 0)
        a, b = upper.row[keep], upper.col[keep]
        values = np.column_stack([np.asarray(sp.csr_matrix(t)[a, b]).ravel() for t in terms])
        n_edges = len(a)
        rows, cols, signs = [], [], []
        for ends, sign in ((a, 1.0), (b, -1.0)):
            on = free_position[ends] >= 0
            rows.append(np.arange(n_edges)[on])
            cols.append(free_position[ends][on])
            signs.append(np.full(on.sum(), sign))
        incidence = sp.csr_matrix(
            (np.concatenate(signs), (np.concatenate(rows), np.concatenate(cols))),
            shape=(n_edges, len(free)),
        )
        return cls(values, incidence, rest[a] - rest[b])

    def elastic_force(
        self, delta, coefficients, k0, stiffening: StiffeningFunction = quadratic_stiffening
    ):
        """(K(B) (B - B0)) on the free points, an (n_free, 3) CasADi expression.

        Parameters
        ----------
        delta : casadi.MX
            Displacement of the free control points, (n_free, 3) [mm].
        coefficients : casadi.MX
            Value of every stiffness term, (n_terms, 1) [N/mm].
        k0 : casadi.MX or float
            Stiffening parameter of s.
        stiffening : callable
            s(eps, k0).
        """
        incidence = to_casadi_sparse(self.incidence)
        relative = ca.mtimes(incidence, delta)
        rest = ca.DM(self.rest_vectors)
        rest_length = ca.DM(np.linalg.norm(self.rest_vectors, axis=1))
        length = ca.sqrt(ca.sum2((rest + relative) ** 2))
        strain = (length - rest_length) / rest_length
        springs = ca.mtimes(ca.DM(np.minimum(self.values, 0.0)), coefficients)
        others = ca.mtimes(ca.DM(np.maximum(self.values, 0.0)), coefficients)
        edge_stiffness = springs * stiffening(strain, k0) + others
        tension = ca.repmat(edge_stiffness, 1, 3) * relative
        return -ca.mtimes(incidence.T, tension)
