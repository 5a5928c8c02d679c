"""The linear path: every load case and every sensitivity from one factorisation per p.

For a model linear in the state whose every contribution to the model part h is a
unit term (``symbolic.effects.library.ExtendedModel.stiffness_terms``: the linear-elastic
base or the paper's base at k0 = 0, with any effect of the library but
nonlinear_stiffening) the extended equilibrium (docs/model.md, eq. 22) of load case k is

    g_k(s, p) = K(p) s - F_k(p),      K(p) = sum_t c_t(p) K_t,

with one stiffness for all cases, the K_t numeric matrices and only the coefficients
c(p) (and dc/dp) symbolic. With one factorisation of K(p),

    s_k = K^-1 F_k                                              (all cases: one solve),
    ds_k/dp = -K^-1 (sum_t dc_t/dp K_t s_k - dF_k/dp)           (one solve, n n_p columns),
    dr_k/dp = dr_k/ds ds_k/dp + dr_k/dp|_s                      (implicit function theorem).

K(p) and dK/dp s are sums of scipy products; CasADi evaluates c(p) and, per case, the
small load and observation Functions (``ExtendedModel.case_parts``). No Newton
iteration (the solve is exact; one step of iterative refinement restores the last
digits if needed), no per-case stiffness, no CasADi graph holding a stiffness. Effect
sets outside this form keep Newton case by case (``ExtendedProblem.solve_state``).

``StateJacobian`` is the factorisation both paths share: SuperLU with a symmetric
ordering and a low diagonal-pivot threshold (``FACTOR_OPTIONS``; the measured
alternatives are in docs/inverse.md).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg.blas import daxpy

from solvers.forward.componentwise import FACTOR_OPTIONS
from solvers.linalg.blas import one_thread
from solvers.linalg.cholmod import factorised, symmetric
from symbolic.sparse import term_matrix

REFINE = 1e-12
"""Relative equilibrium residual |K s - b| / |b| above which one refinement step runs."""


class StateJacobian:
    """dg/ds (sparse) with its factors, computed on first use.

    Parameters
    ----------
    matrix : scipy.sparse matrix
        dg/ds, square.
    rows : numpy.ndarray, optional
        A positive row scaling d for which diag(d) dg/ds is symmetric positive definite
        (base_compliance's inner rows carry its compliance c: divided by c they make
        K symmetric); then diag(d) dg/ds is factorised and the right-hand sides scaled
        alike, so CHOLMOD serves where SuperLU would have to.
    split : int, optional
        Where the free points' unknowns end and an effect's extra state begins. When
        the block below the diagonal there is empty (base_compliance at c = 0: its inner
        rows are M_I Delta_I alone), dg/ds is block upper triangular and is solved by
        back substitution with its two diagonal blocks factorised apart (both symmetric
        positive definite: CHOLMOD for each, where the whole matrix, not symmetric,
        went to SuperLU: 20 % of the CPU of one diagnosis at 47 x 40 x 7).
    definite : bool
        False for a matrix known to be indefinite (the KKT matrix of prescribed
        displacements, ``symbolic.effects.prescribed``): SuperLU at once, without a
        Cholesky attempt that would fail.
    """

    def __init__(
        self,
        matrix: sp.spmatrix,
        rows: np.ndarray | None = None,
        split: int | None = None,
        definite: bool = True,
    ):
        compressed = sp.issparse(matrix) and matrix.format in ("csr", "csc")
        self.matrix = matrix if compressed else sp.csc_matrix(matrix)
        self.rows = None if rows is None else np.asarray(rows, dtype=float)
        self.split = split
        self.definite = definite
        self._lu = None

    def _factorise(self):
        """CHOLMOD for an SPD K(p), else SuperLU (``solvers.linalg.cholmod.factorised``)."""
        if not self.definite:
            return lu(self.matrix if self.rows is None else _rows_scaled(self.matrix, self.rows))
        matrix, n = self.matrix, self.split
        if self.rows is None and n is not None and 0 < n < matrix.shape[0]:
            if matrix[n:, :n].count_nonzero() == 0:
                return _BlockTriangular(matrix, n)
        return _factorised(matrix if self.rows is None else _rows_scaled(matrix, self.rows))

    def solve(self, right: np.ndarray) -> np.ndarray:
        """(dg/ds)^-1 right, for one right-hand side or the columns of a matrix."""
        right = np.asarray(right, dtype=float)
        if self._lu is None:
            self._lu = self._factorise()
        if self.rows is not None:
            right = right * (self.rows if right.ndim == 1 else self.rows[:, None])
        with one_thread():  # thin BLAS blocks: threads only wait on each other
            return self._lu.solve(right)

    def same_as(self, matrix: sp.csc_matrix) -> bool:
        """True when ``matrix`` has this one's pattern and values, entry by entry."""
        mine = self.matrix
        return (
            mine.format == matrix.format
            and mine.shape == matrix.shape
            and np.array_equal(mine.indptr, matrix.indptr)
            and np.array_equal(mine.indices, matrix.indices)
            and np.array_equal(mine.data, matrix.data)
        )


def _rows_scaled(matrix: sp.spmatrix, rows: np.ndarray) -> sp.spmatrix:
    """diag(rows) matrix, entry by entry on the stored values (the sparse product with
    ``sp.diags`` took 42 ms at 18,432 unknowns, 5.1 M nonzeros). It shares the matrix's
    index arrays where they are sorted."""
    if matrix.format == "csr":
        factors = np.repeat(rows, np.diff(matrix.indptr))
    elif matrix.format == "csc":
        factors = rows[matrix.indices]
    else:
        return sp.diags(rows) @ matrix
    ordered = matrix.has_sorted_indices  # else a sort of the copy must not reorder the matrix
    indices = matrix.indices if ordered else matrix.indices.copy()
    scaled = type(matrix)((matrix.data * factors, indices, matrix.indptr), matrix.shape)
    scaled.has_sorted_indices = ordered
    return scaled


def _factorised(matrix: sp.spmatrix):
    """CHOLMOD for a symmetric positive definite matrix, else SuperLU. The arrays of a
    symmetric CSR matrix are those of its CSC form (of its transpose, which is itself),
    so it goes to CHOLMOD without a conversion; SuperLU gets the CSC form."""
    if matrix.format == "csr" and symmetric(matrix):
        view = sp.csc_matrix((matrix.data, matrix.indices, matrix.indptr), shape=matrix.shape)
        view.has_sorted_indices = matrix.has_sorted_indices  # known: not checked again
        return factorised(view, lambda _: lu(matrix), known_symmetric=True)
    return factorised(sp.csc_matrix(matrix), lu)


def lu(matrix: sp.spmatrix):
    """SuperLU with the linear path's options (``FACTOR_OPTIONS``): the factor of an
    indefinite matrix (the saddle matrix of probe constraints), and CHOLMOD's fallback."""
    return spla.splu(sp.csc_matrix(matrix), **FACTOR_OPTIONS)


def factorise(matrix: sp.spmatrix, definite: bool = True):
    """K alone (``definite``): CHOLMOD (``solvers.linalg.cholmod.factorised``, SuperLU
    under its switch or where the Cholesky fails); the saddle matrix [[K, C^T], [C, 0]]
    is indefinite and goes straight to SuperLU (``lu``)."""
    return factorised(sp.csc_matrix(matrix), lu) if definite else lu(matrix)


class _BlockTriangular:
    """[[A, B], [0, D]]^-1 by back substitution: x_2 = D^-1 b_2, x_1 = A^-1 (b_1 - B x_2)."""

    def __init__(self, matrix: sp.csc_matrix, n: int):
        self.n = n
        self.upper = sp.csc_matrix(matrix[:n, n:])
        self.first = _factorised(matrix[:n, :n])
        self.second = _factorised(matrix[n:, n:])

    def solve(self, right: np.ndarray) -> np.ndarray:
        second = self.second.solve(right[self.n :])
        first = self.first.solve(right[: self.n] - self.upper @ second)
        return np.concatenate([first, second])


def _dense(value) -> np.ndarray:
    return value.toarray() if sp.issparse(value) else np.asarray(value)


def solve_states(factor: StateJacobian, right: np.ndarray) -> np.ndarray:
    """K^-1 right for the columns of ``right`` (n_state, n), refined once if needed."""
    states = factor.solve(right)
    defect = right - factor.matrix @ states
    scale = max(float(np.abs(right).max()), 1e-300)
    if float(np.abs(defect).max()) > REFINE * scale:
        states = states + factor.solve(defect)
    return states


def stiffness_matrix(problem, p: np.ndarray, terms=None) -> sp.spmatrix:
    """K(p) = dh/ds = sum_t c_t(p) K_t from the unit terms (``ExtendedModel.stiffness_terms``,
    or the ``terms`` given: the split path's, ``solvers.diagnosis.splitpath``).

    A term whose coefficient is zero (an effect at theta = 0) is never assembled. Terms
    that share one sparsity pattern (the continuum's K_mu, K_lambda and the gradient's
    versions of them; a depth band of layering may cover only part of it) are
    summed on their stored values, in the terms' own (CSR) format: a sum of scipy
    matrices built the union pattern anew each time (1.2 s against 0.6 s for six terms
    of the 40 x 33 x 6 K, 13.5 M nonzeros), and a conversion to CSC cost a third of
    what is left (``_factorised`` gives CHOLMOD a symmetric CSR matrix as it stands).
    Terms of other patterns (an effect's extra state, a band) are added into the union
    of all the patterns, found once per set of terms (``_union``): the scipy sum and
    its conversion took 62 ms of every K(p) with base_compliance at 32 x 32 x 6
    (4.1 M nonzeros), 3 s of a default ``dvs next``. Which terms share the first one's
    pattern is found once per set of terms too.
    """
    terms = problem.extended.stiffness_terms() if terms is None else terms
    c = np.ravel(_dense(problem.numeric_of(terms.coefficients)(p)[0]))
    chosen = [
        (t, value, term_matrix(term))
        for t, (value, term) in enumerate(zip(c, terms.matrices))
        if value != 0.0
    ]
    chosen = [(t, value, matrix) for t, value, matrix in chosen if matrix.nnz]
    if not chosen:  # every coefficient zero
        return sp.csc_matrix(terms.matrices[0].shape)
    reference, _, first = chosen[0]
    for t, _, matrix in chosen[1:]:
        if (reference, t) not in terms.shares_pattern:
            terms.shares_pattern[reference, t] = _same_pattern(first, matrix)
    others = [(t, v, m) for t, v, m in chosen[1:] if not terms.shares_pattern[reference, t]]
    data = chosen[0][1] * first.data
    for t, value, matrix in chosen[1:]:  # in place: a temporary per term cost 2x
        if terms.shares_pattern[reference, t]:
            data = daxpy(matrix.data, data, a=value)
    if not others:  # never the terms' own index arrays
        summed = type(first)((data, first.indices.copy(), first.indptr.copy()), shape=first.shape)
        summed.has_sorted_indices = first.has_sorted_indices  # checked once, on the term
        return summed
    union = _union(terms, reference, first, others)
    if union is None:  # a term not in canonical form: scipy's sum
        return sp.csc_matrix(sum(value * matrix for _, value, matrix in chosen))
    indptr, indices, places = union
    summed = np.zeros(indices.size)
    summed[places[reference]] = data
    for t, value, matrix in others:
        summed[places[t]] += value * matrix.data
    out = sp.csr_matrix((summed, indices.copy(), indptr.copy()), shape=first.shape)
    out.has_sorted_indices = True  # the union's, sorted once
    return out


def _union(terms, reference: int, first, others) -> tuple | None:
    """The CSR pattern of K_reference and ``others`` together, and where each one's
    entries lie in it: (indptr, indices, {t: positions}), kept with the terms; None
    when a term is not canonical CSR (another format, duplicate or unsorted entries):
    the positions follow each term's own stored order."""
    key = ("union", reference, tuple(t for t, _, _ in others))
    if key not in terms.shares_pattern:
        matrices = [(reference, first)] + [(t, m) for t, _, m in others]
        if not all(m.format == "csr" and m.has_canonical_format for _, m in matrices):
            terms.shares_pattern[key] = None
            return None
        ones = sum(
            sp.csr_matrix((np.ones(m.nnz), m.indices, m.indptr), shape=m.shape) for _, m in matrices
        )
        ones.sort_indices()
        width = ones.shape[1]

        def keys(m):
            rows = np.repeat(np.arange(m.shape[0], dtype=np.int64), np.diff(m.indptr))
            return rows * width + m.indices

        where = keys(ones)
        places = {t: np.searchsorted(where, keys(m)) for t, m in matrices}
        terms.shares_pattern[key] = (ones.indptr, ones.indices, places)
    return terms.shares_pattern[key]


def _same_pattern(a, b) -> bool:
    """True when two compressed matrices store their entries at the same positions."""
    return (
        a.format == b.format in ("csr", "csc")
        and a.shape == b.shape
        and np.array_equal(a.indptr, b.indptr)
        and np.array_equal(a.indices, b.indices)
    )


def symmetric_rows(problem, p: np.ndarray) -> np.ndarray | None:
    """The row scaling that makes K(p) symmetric, from the one effect with extra state
    (on the linear path its rows follow the free points', before the multipliers of
    prescribed points), or None."""
    model = problem.extended.model
    n_free, n_state = 3 * model.n_free, problem.extended.n_state
    for effect in problem.effects:
        scale = effect.extra_row_scale(p[problem.slice_of(effect.name)])
        if scale is not None:
            rows = np.ones(n_state)
            rows[n_free : n_state - 3 * model.n_constraints] = scale
            return rows
    return None


def _case(problem, k: int, name: str):
    """The numeric load or observation Function of case k (``ExtendedModel.case_parts``)."""
    return problem.numeric_of(getattr(problem.extended.case_parts(k), name))


def equilibria(problem, p: np.ndarray, factor: StateJacobian) -> np.ndarray:
    """The states of every case at p, (n_state, n_cases), from one solve."""
    loads = [
        np.ravel(_dense(_case(problem, k, "load")(p)[0])) for k in range(len(problem.positions))
    ]
    return solve_states(factor, -np.column_stack(loads))


def force_derivatives(problem, p: np.ndarray, states: np.ndarray, terms=None) -> np.ndarray:
    """dh/dp at every state, (n_state, n_cases n_p), case by case side by side:
    dh/dp_j s_k = sum_t dc_t/dp_j K_t s_k, one sparse product per term whose coefficient
    depends on p (the terms of ``stiffness_matrix``)."""
    terms = problem.extended.stiffness_terms() if terms is None else terms
    slope = _dense(problem.numeric_of(terms.coefficients)(p)[1])  # (T, n_p)
    n_state, n_cases = states.shape
    out = np.zeros((n_state, n_cases, p.size))
    for t in np.flatnonzero(np.any(slope != 0.0, axis=1)):
        product = terms.matrices[t] @ states  # (n_state, n_cases)
        columns = np.flatnonzero(slope[t])
        out[:, :, columns] += product[:, :, None] * slope[t, columns]
    return out.reshape(n_state, n_cases * p.size)


def wanted_columns(n_p: int, columns=None) -> np.ndarray:
    """The mask of the entries of p whose sensitivities are wanted (all when None)."""
    if columns is None:
        return np.ones(n_p, dtype=bool)
    wanted = np.zeros(n_p, dtype=bool)
    wanted[np.asarray(columns, dtype=int)] = True
    return wanted


def linearise(problem, p: np.ndarray, states: np.ndarray, factor: StateJacobian, columns=None):
    """r and exact dr/dp of every case at solved states, from one multi-column solve.

    Parameters
    ----------
    problem : ExtendedProblem
        A problem whose ``extended.linear_state`` is true.
    p : numpy.ndarray
        Parameters (natural units).
    states : numpy.ndarray
        Solved states, (n_state, n_cases).
    factor : StateJacobian
        The factorisation of K(p).
    columns : array of int, optional
        The entries of p whose sensitivities are solved (default all); the others'
        columns of dr/dp are zero.

    Returns
    -------
    tuple
        Per case, the raw residual r_k and dr_k/dp (dense).
    """
    n_cases, n_p = len(problem.positions), p.size
    dh_dp = force_derivatives(problem, p, states)
    dg_dp = np.hstack(
        [
            dh_dp[:, k * n_p : (k + 1) * n_p] + _dense(_case(problem, k, "load")(p)[1])
            for k in range(n_cases)
        ]
    )
    sensitivity = np.zeros_like(dg_dp)
    wanted = wanted_columns(n_p, columns)
    moving = np.flatnonzero(np.any(dg_dp != 0.0, axis=0) & np.tile(wanted, n_cases))
    if moving.size:  # a parameter that moves no state (a per-case measurement) is unsolved
        sensitivity[:, moving] = -factor.solve(dg_dp[:, moving])
    residuals, jacobians = [], []
    for k in range(n_cases):
        r, dr_ds, dr_dp = _case(problem, k, "observation")(states[:, k], p)
        block = sensitivity[:, k * n_p : (k + 1) * n_p]
        residuals.append(np.ravel(_dense(r)))
        jacobians.append(dr_ds @ block + _dense(dr_dp) * wanted)
    return residuals, jacobians
