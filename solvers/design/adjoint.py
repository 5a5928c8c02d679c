"""The sensitivities of many presses from the rows their markers share (the adjoint).

On the linear path (``solvers.forward.linearpath``) the sensitivity of press k is

    dr_k/dp = dr_k/dp|_s - dr_k/ds K^-1 dg_k/dp,

one solve per press and parameter: 780 right-hand sides for 260 presses and 3 base
parameters, 10 ms each at 27 x 27 x 4 (ten factorisations' worth). But every press
observes the same markers: dr_k/ds is a choice of the rows of one matrix U (the
marker rows W S the presses leave visible; 243 at most for 81 markers), so

    dr_k/ds K^-1 = E_k U K^-1 = E_k Z^T,      Z = K^-T U^T,                       (D9)

with E_k picking press k's rows. Z costs one solve per distinct row; every press's
sensitivity is then a dense product Z^T dg_k/dp. The rows are matched entry by entry
(pattern and values), never assumed equal. K^-T = K^-1 needs K symmetric, checked
entry by entry too; otherwise, or when the presses have fewer sensitivity columns than
distinct rows, ``linearise`` solves forward as ``solvers.forward.linearpath.linearise``
does, for the wanted columns alone. Either way dh/dp s_k is formed for the wanted
columns only, each unit term acting on a basis of the states (``compress``), and the
states themselves come from the independent loads (``equilibria``). The answers are
the forward path's to rounding (the products are regrouped).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.forward import linearpath
from solvers.linalg.blas import one_thread


def _dense(value) -> np.ndarray:
    return value.toarray() if sp.issparse(value) else np.asarray(value)


def symmetric(matrix: sp.spmatrix) -> bool:
    """True when the sparse ``matrix`` equals its transpose entry by entry."""
    difference = sp.csr_matrix(matrix) - sp.csr_matrix(matrix.T)
    difference.eliminate_zeros()
    return difference.nnz == 0


def distinct_rows(blocks: list) -> tuple[sp.csr_matrix, list[np.ndarray]]:
    """The distinct rows U of the stacked sparse ``blocks`` (equal in pattern and values)
    and, per block, the index in U of each of its rows."""
    stacked = sp.csr_matrix(sp.vstack([sp.csr_matrix(b) for b in blocks]))
    stacked.sort_indices()
    seen: dict = {}
    where = np.empty(stacked.shape[0], dtype=int)
    first = []
    for i in range(stacked.shape[0]):
        begin, end = stacked.indptr[i], stacked.indptr[i + 1]
        key = (stacked.indices[begin:end].tobytes(), stacked.data[begin:end].tobytes())
        if key not in seen:
            seen[key] = len(first)
            first.append(i)
        where[i] = seen[key]
    offsets = np.cumsum([0] + [b.shape[0] for b in blocks])
    return stacked[first], [where[a:b] for a, b in zip(offsets[:-1], offsets[1:])]


def load_parts(problem, p: np.ndarray) -> list:
    """Per case, -F_B(p) and -dF_B/dp (``ExtendedModel.case_parts``)."""
    parts = problem.extended.case_parts
    return [problem.numeric_of(parts(k).load)(p) for k in range(len(problem.positions))]


def linearise(problem, p: np.ndarray, states: np.ndarray, factor, columns=None, adjoint=None):
    """r and exact dr/dp of every case at solved states (linear path), as
    ``solvers.forward.linearpath.linearise``, by eq. (D9) when it takes fewer solves.

    Parameters
    ----------
    problem, p, states, factor, columns
        As ``solvers.forward.linearpath.linearise``.
    adjoint : bool, optional
        Eq. (D9) (True) or the forward path (False); default: eq. (D9) when K is
        symmetric and it takes fewer solves.

    Returns
    -------
    tuple
        Stacked raw residual r (not whitened) and dr/dp, (n_r,) and (n_r, n_p).
    """
    n_cases, n_p = states.shape[1], p.size
    wanted = linearpath.wanted_columns(n_p, columns)
    observe = problem.extended.case_parts
    observed = [problem.numeric_of(observe(k).observation)(states[:, k], p) for k in range(n_cases)]
    rows, where = distinct_rows([o[1] for o in observed])
    if adjoint is None:
        adjoint = rows.shape[0] < n_cases * int(wanted.sum())
    adjoint = adjoint and symmetric(factor.matrix)
    picked = np.flatnonzero(wanted)
    loads = load_parts(problem, p)
    dg_dp = force_columns(problem, p, states, picked)
    for k in range(n_cases):
        dg_dp[:, k] += _dense(loads[k][1])[:, picked]
    if adjoint:  # eq. (D9): Z = K^-1 U^T, (n_state, n_rows)
        adjoint_rows = factor.solve(rows.T.toarray())
        flat = dg_dp.reshape(states.shape[0], -1)
        projected = (adjoint_rows.T @ flat).reshape(-1, n_cases, picked.size)
    else:  # forward: K^-1 dg/dp, one solve per press and column that moves the state
        flat = dg_dp.reshape(states.shape[0], -1)
        sensitivity = np.zeros_like(flat)
        moving = np.flatnonzero(np.any(flat != 0.0, axis=0))
        if moving.size:
            sensitivity[:, moving] = factor.solve(flat[:, moving])
        sensitivity = sensitivity.reshape(-1, n_cases, picked.size)
    residuals, jacobians = [], []
    for k, (r, dr_ds, dr_dp) in enumerate(observed):
        jacobian = _dense(dr_dp) * wanted
        if adjoint:
            jacobian[:, picked] -= projected[where[k], k]
        else:
            jacobian[:, picked] -= dr_ds @ sensitivity[:, k]
        residuals.append(np.ravel(_dense(r)))
        jacobians.append(jacobian)
    return np.concatenate(residuals), np.vstack(jacobians)


def force_columns(problem, p: np.ndarray, states: np.ndarray, picked: np.ndarray) -> np.ndarray:
    """dh/dp_j s_k = sum_t dc_t/dp_j K_t s_k for the entries ``picked`` of p, (n_state,
    n_cases, n_picked) (``solvers.forward.linearpath.force_derivatives`` for those
    columns alone). Each K_t acts on a basis of the states (``compress``): the presses
    at one contact share three directions of state."""
    terms = problem.extended.stiffness_terms()
    slope = _dense(problem.numeric_of(terms.coefficients)(p)[1])[:, picked]  # (T, n_picked)
    n_state, n_cases = states.shape
    out = np.zeros((n_state, n_cases, picked.size))
    active = np.flatnonzero(np.any(slope != 0.0, axis=1))
    if not active.size:
        return out
    basis, coefficients = compress(states)
    for t in active:
        product = (terms.matrices[t] @ basis) @ coefficients  # K_t s_k, (n_state, n_cases)
        columns = np.flatnonzero(slope[t])
        out[:, :, columns] += product[:, :, None] * slope[t, columns]
    return out


RANK = 1e-13
"""Directions of a set of columns below this fraction of the largest singular value
are dropped (``compress``)."""


def compress(columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``columns`` (n, m) as Q C with Q (n, r) orthonormal and r its numerical rank: a
    QR, then the SVD of the small R; singular values below ``RANK`` of the largest
    are dropped (those columns are combinations of the others). (A pivoted QR gives
    the same.) On one BLAS thread (``solvers.linalg.blas``): on two busy cores the
    blocked QR of 6561 x 57 took 1.3-1.6 s with two threads, 0.04 s with one."""
    with one_thread():
        q, r = np.linalg.qr(columns)
        u, singular, vt = np.linalg.svd(r)
    rank = int(np.sum(singular > RANK * max(float(singular.max(initial=0.0)), 1e-300)))
    return q @ u[:, :rank], singular[:rank, None] * vt[:rank]


def equilibria(problem, p: np.ndarray, factor) -> np.ndarray:
    """The states of every case at p, (n_state, n_cases), from one solve per
    independent load: the presses at one contact have F_B = b f^T (eq. D8), so their
    loads span three directions per contact, whatever their forces (``compress`` finds
    them); K^-1 F = (K^-1 Q) C."""
    right = -np.column_stack([np.ravel(_dense(part[0])) for part in load_parts(problem, p)])
    basis, coefficients = compress(right)
    if not coefficients.shape[0]:
        return np.zeros_like(right)
    return linearpath.solve_states(factor, basis) @ coefficients


def residual(problem, p: np.ndarray) -> np.ndarray:
    """Stacked raw residual r(p) of a problem on the linear path (``ExtendedProblem.
    residual``'s, the equilibria by ``equilibria``)."""
    states = equilibria(problem, p, problem.stiffness_factor(p))
    observe = problem.extended.case_parts
    return np.concatenate(
        [
            np.ravel(_dense(problem.numeric_of(observe(k).observation)(states[:, k], p)[0]))
            for k in range(states.shape[1])
        ]
    )


def evaluate(problem, p: np.ndarray, factor=None):
    """r(p), dr/dp, the states and the factorisation of every case of a problem on the
    linear path (``ExtendedProblem.evaluate_full``'s, through ``equilibria`` and
    ``linearise``)."""
    factor = problem.stiffness_factor(p) if factor is None else factor
    states = equilibria(problem, p, factor)
    r, jacobian = linearise(problem, p, states, factor)
    return r, jacobian, [states[:, k].copy() for k in range(states.shape[1])], factor
