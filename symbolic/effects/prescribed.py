"""Prescribed displacements in the extended equilibrium: the multipliers' block.

A model with prescribed points (``TissueModel.prescribed``: the pads of the two-pad
extensometer, docs/realskin.md) adds Lagrange multipliers lam (r, 3) [N] to the state,
after the effects' extra state,

    s = [vec(Delta_free); vec(extra state); vec(lam)],

and to the extended equilibrium (docs/model.md eq. 22, as ``TissueModel.state_residual``)

    h(s, p) += [(I3 (x) A^T) vec(lam); 0; (I3 (x) A) vec(Delta_free)],
    load_k   = [-F_B,k; 0; -vec(Q d_k)],

with A = Q A_free the independent constraint rows on the free points and d_k the case's
prescribed displacements [mm]. The block is linear in s and the same for every case and
every p: a constant unit term with coefficient 1 on the linear path. It makes dg/ds a
symmetric indefinite (KKT) matrix, which is factorised by LU, never by Cholesky.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.effects.casedata import CaseData
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


def n_multipliers(model: TissueModel) -> int:
    """Length of vec(lam): 3 r (0 without prescribed points)."""
    return 3 * model.n_constraints


def constraint_term(model: TissueModel, n_state: int) -> sp.csr_matrix:
    """[[0, 0, I3 (x) A^T], [0, 0, 0], [I3 (x) A, 0, 0]] on s, (n_state, n_state): the
    multipliers' part of dg/ds (the module docstring)."""
    coupling = sp.kron(sp.identity(3), model._constraint_free).tocoo()
    start = n_state - n_multipliers(model)
    rows = np.concatenate([coupling.col, start + coupling.row])
    cols = np.concatenate([start + coupling.row, coupling.col])
    data = np.concatenate([coupling.data, coupling.data])
    return sp.csr_matrix((data, (rows, cols)), shape=(n_state, n_state))


def constraint_load(model: TissueModel, case: CaseData) -> np.ndarray:
    """-vec(Q d_k), the case's load on the constraint rows [mm], (3 r,)."""
    if case.prescribed is None:
        raise ValueError("a model with prescribed points needs each case's displacements d")
    return -(model._constraint_rows @ np.asarray(case.prescribed, dtype=float)).T.reshape(-1)


def with_constraint_rows(model: TissueModel, rest: ca.MX, s: ca.MX) -> ca.MX:
    """``rest`` (a part of h, zero on the multipliers' rows) plus the multipliers' block
    applied to s; ``rest`` itself for a model without prescribed points."""
    if not model.n_constraints:
        return rest
    return rest + ca.mtimes(to_casadi_sparse(constraint_term(model, s.numel())), s)
