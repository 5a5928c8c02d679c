"""The linear model's equilibrium on one scalar factorisation (docs/model.md, eq. 18, 22).

For k0 = 0 the elastic force is K(x)(B - B0) with K(x) = I3 (x) A(x) on the free
control points: the same scalar matrix

    A(x) = sum_t c_t(x) K_t,        c_t = the value of term t's parameter (eq. 18),

acts on the x, y and z components alike. With prescribed displacements the state of one
component is [Delta; lam] and its block is the symmetric saddle matrix

    S(x) = [[A(x), C^T], [C, 0]],    C the independent constraint rows on the free points.

So one factorisation of the scalar block per parameter value serves the three
components, every load case and every sensitivity column:

    S [Delta_c; lam_c] = [F_c; Q d_c],                                    c = x, y, z
    S d[Delta_c; lam_c]/dx_j = -[sum_t (dc_t/dx_j) K_t Delta_c; 0].

The factorisation is SuperLU with a symmetric minimum-degree ordering (MMD on A^T + A,
diagonal pivots preferred): on the 33 x 33 x 4 phantom (3,267 free points, 336k
nonzeros) it takes 0.06 s, against 1.1 s for SuperLU's default ordering of I3 (x) A,
which ``solvers.forward.equilibrium`` factorised before (docs/inverse.md, "Speed at scale").
States use the layout of ``TissueModel.state_residual``: s = [vec(Delta); vec(lam)],
columns stacked (x components first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from symbolic.model import TissueModel
from symbolic.sparse import pattern_entries
from symbolic.unitterms import term_parameter

ORDERING = {"permc_spec": "MMD_AT_PLUS_A", "options": {"SymmetricMode": True}}
"""SuperLU options of the scalar factorisation: symmetric ordering, diagonal pivots."""

FACTOR_OPTIONS = {**ORDERING, "diag_pivot_thresh": 1e-3}
"""SuperLU with the symmetric ordering and diagonal pivots unless one is below 1e-3 of
its column: K(p) of base_compliance is not symmetric (its inner rows carry the
compliance c), and with SuperLU's default threshold of 1 its pivoting undid the
ordering, 26 s per factorisation at 27 x 27 x 4 against 2.2 s (the SPD K alone: no
change, 0.73 s)."""


@dataclass
class ScalarFactor:
    """S(x) factorised, and the x it belongs to."""

    x: np.ndarray
    stiffness: sp.csc_matrix
    lu: object

    def solve(self, right: np.ndarray) -> np.ndarray:
        """S^-1 right, for right (n + r, m) (any number of columns)."""
        return self.lu.solve(np.asarray(right, dtype=float))


class ScalarSystem:
    """A(x) assembled from the unit terms, factorised once per x, solved per component.

    Parameters
    ----------
    model : TissueModel
        A linear model (``model.is_linear(names)``).
    names : tuple of str
        The parameters x; those of stiffness terms change A, the others (mu, gamma) not.
    """

    def __init__(self, model: TissueModel, names: tuple[str, ...]):
        if not model.is_linear(tuple(names)):
            raise ValueError("the scalar system needs the linear model (k0 = 0, not estimated)")
        self.model, self.names = model, tuple(names)
        self.n, self.r = model.n_free, model.n_constraints
        values = model.values()
        self.terms = [
            t for t in model.terms if term_parameter(t) in names or values[term_parameter(t)]
        ]
        blocks = [sp.csc_matrix(model.free_block(model.terms[t])) for t in self.terms]
        coupling = sp.csr_matrix(model._constraint_free)
        size = self.n + self.r
        padded = [sp.block_diag([b, sp.csc_matrix((self.r, self.r))], "csc") for b in blocks]
        constraint = sp.vstack(
            [
                sp.hstack([sp.csc_matrix((self.n, self.n)), coupling.T]),
                sp.hstack([coupling, sp.csc_matrix((self.r, self.r))]),
            ]
        ).tocsc()
        pattern = (sum(abs(b) for b in padded) + abs(constraint)).tocsc()
        assert pattern.shape == (size, size)
        pattern.sort_indices()
        self._indices, self._indptr = pattern.indices.copy(), pattern.indptr.copy()
        self.unit = sp.csc_matrix(np.column_stack([pattern_entries(pattern, b) for b in padded]))
        self.fixed_part = pattern_entries(pattern, constraint)
        self.blocks = blocks
        base = np.array([values[term_parameter(t)] for t in self.terms], dtype=float)
        self.selection = np.array(
            [[term_parameter(t) == name for name in self.names] for t in self.terms], dtype=float
        ).reshape(len(self.terms), len(self.names))
        self.base = base * (self.selection.sum(axis=1) == 0)
        self.influential = self.selection.any(axis=0)
        self.reduce = np.asarray(model._constraint_rows, dtype=float)

    def coefficients(self, x) -> np.ndarray:
        """c(x): each term's coefficient, the fixed values or those in x."""
        return self.base + self.selection @ np.asarray(x, dtype=float).reshape(-1)

    def factor(self, x) -> ScalarFactor:
        """S(x) and its LU (SuperLU, symmetric ordering)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        data = self.unit @ self.coefficients(x) + self.fixed_part
        size = self.n + self.r
        matrix = sp.csc_matrix((data, self._indices, self._indptr), shape=(size, size))
        return ScalarFactor(x, matrix, spla.splu(matrix, **ORDERING))

    def state(self, factor: ScalarFactor, force: np.ndarray, prescribed: np.ndarray) -> np.ndarray:
        """s = [vec(Delta); vec(lam)] of one load case (F_B (n, 3) [N], d (m, 3) [mm])."""
        right = np.vstack([np.asarray(force, float), self.reduce @ np.asarray(prescribed, float)])
        solution = factor.solve(right)  # (n + r, 3): one column per component
        return np.concatenate([solution[: self.n].T.ravel(), solution[self.n :].T.ravel()])

    def sensitivity(self, factor: ScalarFactor, state: np.ndarray) -> np.ndarray:
        """ds/dx (n_state, len(names)) at a state, by the factor already made."""
        delta = state[: 3 * self.n].reshape(3, self.n).T  # (n, 3)
        columns = []
        for j in range(len(self.names)):
            weights = self.selection[:, j]
            if not weights.any():
                columns.append(np.zeros((self.n + self.r, 3)))
                continue
            right = sum(w * (b @ delta) for w, b in zip(weights, self.blocks) if w)
            columns.append(np.vstack([right, np.zeros((self.r, 3))]))
        stacked = -factor.solve(np.hstack(columns))  # (n + r, 3 p)
        out = np.empty((3 * (self.n + self.r), len(self.names)))
        for j in range(len(self.names)):
            block = stacked[:, 3 * j : 3 * j + 3]
            out[:, j] = np.concatenate([block[: self.n].T.ravel(), block[self.n :].T.ravel()])
        return out
