"""The split path: Newton's g, dg/ds and dg/dp assembled numerically around the forces
of the effects that are not unit terms.

A base model linear in the state whose effects enter h as unit terms (as on the linear
path, ``solvers.forward.linearpath``) or as internal forces alone (nonlinear_stiffening
on the real skin's slab: ``ExtendedModel.split_part``) has, for load case k,

    g_k(s, p) = K(p) s + n(s, p) + L_k(p),          K(p) = sum_t c_t(p) K_t,
    dg_k/ds   = K(p) + dn/ds,
    dg_k/dp   = sum_t dc_t/dp K_t s + dn/dp + dL_k/dp,

with L_k the case's load (``ExtendedModel.case_parts``). K(p) is summed numerically once
per p (``linearpath.stiffness_matrix``) and serves every case and every Newton step at
that p; n and its derivatives are the effects' own numbers (``Effect.numeric_force``,
``symbolic.effects.numericforce``), dg/ds is summed on a pattern found once
(``PatternSum``), and CasADi evaluates only functions of p (K's coefficients, the
forces' arguments) and each case's load and observation. The whole g of each case as
one CasADi Function held the stiffness among its constants, copied into its work vector
at every call, and evaluated the stiffening's custom Jacobian, tangent included, for
the parameter columns; the times of both are in docs/realskin.md ("Speed").

Newton itself is ``solvers.diagnosis.newton``'s; only where g and its derivatives come
from differs. Effect sets outside this form keep the case's CasADi Functions
(``CaseFunctions``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.forward import linearpath


def _dense(value) -> np.ndarray:
    return value.toarray() if sp.issparse(value) else np.asarray(value)


def equations(problem, position: int, p: np.ndarray):
    """The case's s -> g(s, p) (flat) and s -> dg/ds (sparse) at ``p``: in numbers on the
    split path, else the case's CasADi Functions."""
    part = problem.extended.split_part()
    if part is None:
        equilibrium = problem.numeric(position, "equilibrium")
        newton = problem.numeric(position, "newton")
        return (lambda s: equilibrium(s, p)[0].ravel()), (lambda s: newton(s, p)[1])
    stiffness, q, _ = at(problem, p)
    load = np.ravel(_dense(problem.numeric_of(_parts(problem, position).load)(p)[0]))
    adder = _adder(problem)
    n_free = problem.model.n_free

    def residual(state):
        force = sum(f.force(_delta(state, n_free), q[at_q]) for at_q, f in part.forces)
        out = stiffness @ state + load
        out[: 3 * n_free] += force
        return out

    def jacobian(state):
        delta = _delta(state, n_free)
        tangents = [f.tangent(delta, q[at_q]) for at_q, f in part.forces]
        tangent = tangents[0] if len(tangents) == 1 else sp.csc_matrix(sum(tangents))
        return adder(stiffness, _padded(tangent, state.size))

    return residual, jacobian


def sensitivity(problem, position: int, state: np.ndarray, p: np.ndarray) -> list:
    """dg/dp, r, dr/ds and dr/dp of the case at a state (as ``CaseFunctions.sensitivity``)."""
    part = problem.extended.split_part()
    if part is None:
        return problem.numeric(position, "sensitivity")(state, p)
    parts = _parts(problem, position)
    _, q, q_slope = at(problem, p)
    delta = _delta(state, problem.model.n_free)
    dg_dp = linearpath.force_derivatives(problem, p, state[:, None], part.terms)
    dg_dp += _dense(problem.numeric_of(parts.load)(p)[1])
    for at_q, force in part.forces:
        dg_dp[: delta.size] += force.slope(delta, q[at_q]) @ q_slope[at_q]
    return [dg_dp, *problem.numeric_of(parts.observation)(state, p)]


def residual(problem, position: int, state: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The case's observation residual r at a state, flat."""
    if problem.extended.split_part() is None:
        return np.ravel(_dense(problem.numeric(position, "residual")(state, p)[0]))
    observation = problem.numeric_of(_parts(problem, position).observation)
    return np.ravel(_dense(observation(state, p)[0]))


def _parts(problem, position: int):
    return problem.extended.case_parts(position)


def _delta(state: np.ndarray, n_free: int) -> np.ndarray:
    """Delta (n_free, 3) of the free points from s (columns stacked)."""
    return state[: 3 * n_free].reshape((n_free, 3), order="F")


def _padded(matrix: sp.csc_matrix, size: int) -> sp.csc_matrix:
    """A square CSC matrix with empty rows and columns appended up to ``size``."""
    extra = size - matrix.shape[1]
    if not extra:
        return matrix
    indptr = np.concatenate([matrix.indptr, np.full(extra, matrix.indptr[-1])])
    out = sp.csc_matrix((matrix.data, matrix.indices, indptr), shape=(size, size))
    out.has_sorted_indices = matrix.has_sorted_indices
    return out


def at(problem, p: np.ndarray) -> tuple:
    """K(p) of the split part (its stored zeros dropped), the forces' arguments q and
    dq/dp, kept for the last p of the effect set and labels: every case and Newton step
    at that p shares them."""
    p = np.asarray(p, dtype=float)
    key = ("functions", problem.extended.effect_set, "split_at", tuple(problem.labels))
    entry = problem.cache.get(key)
    if entry is None or not np.array_equal(entry[0], p):
        part = problem.extended.split_part()
        stiffness = linearpath.stiffness_matrix(problem, p, part.terms)
        stiffness.eliminate_zeros()  # a fresh matrix: the terms store zeros of the kron
        q, q_slope = problem.numeric_of(part.arguments)(p)
        entry = (p.copy(), stiffness, np.ravel(_dense(q)), _dense(q_slope))
        problem.cache[key] = entry
    return entry[1:]


def _adder(problem) -> PatternSum:
    key = ("functions", problem.extended.effect_set, "split_sum")
    if key not in problem.cache:
        problem.cache[key] = PatternSum()
    return problem.cache[key]


class PatternSum:
    """a + b for compressed square matrices, as CSC on the union of their patterns: the
    union and where each one's entries lie in it are found once per pair of patterns
    (K(p) keeps its pattern while the same coefficients are nonzero; dn/ds has the
    pattern of its Function), and each sum only places the stored values.

    Matrices with duplicate entries go to scipy's sum.
    """

    def __init__(self):
        self._patterns = None
        self._union = None

    def __call__(self, a: sp.spmatrix, b: sp.spmatrix) -> sp.csc_matrix:
        if not self._same(a, b):
            self._patterns = tuple(
                (m.format, m.shape, m.indptr.copy(), m.indices.copy()) for m in (a, b)
            )
            self._union = _union(a, b)
        if self._union is None:
            return sp.csc_matrix(a + b)
        indptr, indices, first, second = self._union
        data = np.zeros(indices.size)
        data[first] = a.data
        data[second] += b.data
        out = sp.csc_matrix((data, indices.copy(), indptr.copy()), shape=a.shape)
        out.has_sorted_indices = True
        return out

    def _same(self, a, b) -> bool:
        if self._patterns is None:
            return False
        return all(
            m.format == f
            and m.shape == shape
            and np.array_equal(m.indptr, indptr)
            and np.array_equal(m.indices, indices)
            for m, (f, shape, indptr, indices) in zip((a, b), self._patterns)
        )


def _keys(matrix) -> np.ndarray | None:
    """Column-major keys col n_rows + row of the stored entries, in stored order (None
    for a format other than CSR or CSC)."""
    n_rows = matrix.shape[0]
    outer = np.repeat(np.arange(len(matrix.indptr) - 1, dtype=np.int64), np.diff(matrix.indptr))
    inner = matrix.indices.astype(np.int64)
    if matrix.format == "csc":
        return outer * n_rows + inner
    if matrix.format == "csr":
        return inner * n_rows + outer
    return None


def _union(a, b) -> tuple | None:
    """The CSC pattern of a + b and the positions of a's and b's entries in it, or None
    when either is not compressed or has duplicate entries."""
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} and {b.shape}")
    keys = [_keys(m) for m in (a, b)]
    if any(k is None or np.unique(k).size != k.size for k in keys):
        return None
    union = np.union1d(*keys)
    n_rows, n_cols = a.shape
    columns, rows = np.divmod(union, n_rows)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(columns, minlength=n_cols))])
    places = [np.searchsorted(union, k) for k in keys]
    return indptr.astype(np.int32), rows.astype(np.int32), places[0], places[1]
