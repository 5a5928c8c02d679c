"""The stiffness-imaging problem: a field of Young's modulus behind measured markers.

For the linear-elastic model (``symbolic.continuum_model.ContinuumModel``) with the
modulus field of eq. (I1), the stiffness on the free control points is

    K(c) = G^T diag(h(c)) G,      h(c) = f (x) (w_q E_ref exp(Phi c)),            (I2)

with G the stacked strain rows and divergence of eq. (C3) at the Gauss points
(7 n_q rows), f = (2 m, ..., 2 m, l) the Lame moduli per unit E (m = mu_L / E,
l = lambda / E at the model's nu), w_q the quadrature volumes and Phi the field's
collocation at the Gauss points. Each load case k solves the saddle system

    M(c) s_k = [[K(c), C^T], [C, 0]] [Delta_k; lam_k] = [F_k; Q d_k],              (I3)

and the whitened misfit is

    Phi_d(c) = 1/2 |W [A_k s_k + b_k]_k|^2 / sigma^2                                (I4)

with A_k, b_k those of ``InverseProblem`` (markers observed on the skin) and W the
whitening of the rest-marker noise every case shares (``solvers.inverse.noise``), so that
under pure noise 2 Phi_d ~ chi^2 with n_residuals degrees of freedom. Every load
case shares M(c): one sparse factorisation per c serves all forward and adjoint
solves (``Factor``: CHOLMOD for K(c) alone, SuperLU for the saddle matrix). The
derivative of K(c) s along a direction v of the field is

    (dK/dc v) Delta = G^T (f (x) (w_q E(q) (Phi v)_q) * (G Delta)),                 (I5)

so the adjoint gradient of Phi_d is -Phi^T (w_q E(q) sum_b f_b (G_b lam)(G_b Delta))
with M lam = A^T r / sigma^2 (one adjoint solve per case), and Gauss-Newton products
J v and J^T y cost one solve each. ``sensitivities`` forms the N columns of J (the
implicit-function route); the adjoint route never does. Every case observes the same
markers (less those hidden in it), so the rows of all A_k are a few distinct rows U,
and J is formed as

    A_k M^-1 B_k = (M^-1 U^T)[:, rows_k]^T B_k,      B_k = G^T diag(h'_k) Phi_7,    (I6)

one solve with the distinct rows' columns (3 x 81 for 9 x 9 markers) for all cases,
not N per case (2560 for 16 x 16 and 10 cases), whichever is fewer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sl
import scipy.sparse as sp

from solvers.forward.linearpath import factorise
from solvers.imaging.fieldsensitivity import ForceOperators, point_weights
from solvers.inverse.noise import Whitening
from solvers.inverse.problem import InverseProblem
from solvers.linalg.blas import one_thread
from solvers.linalg.cholmod import Cholesky
from symbolic.continuum import KPA, PhysicalGradient, lame
from symbolic.field import StiffnessField

DENSE_RIGHT_SIDES = 64
"""From this many right-hand sides on, ``Factor`` may solve with SuperLU's factors made dense."""

DENSE_BYTES = 2**27
"""The largest dense triangle (n^2 doubles, 128 MB: n up to 4096) ``Factor`` makes of SuperLU's
factors. Above it the copies cost more than they save, and their memory grows as n^2
(2.8 GB each at 19,440 unknowns)."""


class Factor:
    """The sparse factors of M(c) and solves with them.

    K(c) alone (no probe constraints, ``definite``) is symmetric positive definite:
    CHOLMOD factorises it (``solvers.linalg.cholmod.factorised``: SuperLU where cvxopt is
    missing, under ``DVS_FACTORISATION=superlu`` or where the Cholesky fails),
    and solves many right-hand sides four at a time (``Cholesky.solve_columns``). The
    saddle matrix of eq. (I3) is indefinite: SuperLU (``solvers.forward.linearpath.lu``). SuperLU
    solves on one BLAS thread (``solvers/linalg/blas.py``); for ``DENSE_RIGHT_SIDES``
    or more while n^2 doubles are at most ``DENSE_BYTES`` its factors are copied to
    dense triangles for the call and solved by BLAS-3 triangular solves
    (P_r M P_c = L U; the copies are not kept). Every path gives the same solution to
    rounding.
    """

    def __init__(self, matrix: sp.spmatrix, definite: bool = True):
        self.lu = factorise(matrix, definite)

    def solve(self, right: np.ndarray) -> np.ndarray:
        """M^-1 right, for one right-hand side or the columns of a matrix."""
        right = np.asarray(right, dtype=float)
        if isinstance(self.lu, Cholesky):
            with one_thread():
                return self.lu.solve_columns(right)
        n = right.shape[0]
        if right.ndim < 2 or right.shape[1] < DENSE_RIGHT_SIDES or 8 * n * n > DENSE_BYTES:
            with one_thread():  # SuperLU's thin BLAS calls
                return self.lu.solve(right)
        permuted = np.empty_like(right)
        permuted[self.lu.perm_r] = right
        middle = sl.solve_triangular(
            self.lu.L.toarray(), permuted, lower=True, unit_diagonal=True, check_finite=False
        )
        return sl.solve_triangular(self.lu.U.toarray(), middle, check_finite=False)[self.lu.perm_c]


@dataclass
class Forward:
    """The state of every load case at one field c (and the factorisation behind it)."""

    coefficients: np.ndarray
    states: list[np.ndarray]
    raw: np.ndarray
    """Stacked marker residuals [A_k s_k + b_k]_k [mm], not whitened."""
    residual: np.ndarray
    """The whitened residual r = W raw / sigma."""
    point_moduli: np.ndarray = field(repr=False)
    """w_q E(q) at the Gauss points [N/mm^2 mm^3] (eq. I2 without f)."""
    solve: object = field(repr=False)
    strains: np.ndarray | None = field(default=None, repr=False)
    """G Delta_k of every case, (7 n_q, n_cases), made on first use (one product)."""

    @property
    def misfit(self) -> float:
        """Phi_d of eq. (I4) [1] (whitened)."""
        return 0.5 * float(self.residual @ self.residual)


class FieldProblem:
    """Model, load cases and stiffness field: the forward map c -> whitened residual.

    Parameters
    ----------
    problem : InverseProblem
        A linear-elastic model with its load cases; its ``noise_mm`` whitens the
        residual (eq. I4). Its model's E is E_ref and its nu is held.
    field : StiffnessField
        The basis of s = log(E / E_ref).
    reference_kpa, poisson : float, optional
        E_ref [kPa] and the held nu (default: the model's own), e.g. a homogeneous
        fit's, without rebuilding the problem.
    """

    def __init__(
        self,
        problem: InverseProblem,
        stiffness_field: StiffnessField,
        reference_kpa: float | None = None,
        poisson: float | None = None,
    ):
        model = problem.model
        if getattr(model, "energy", "dnurbs") != "linear-elastic":
            raise ValueError("stiffness imaging needs the linear-elastic model (--energy)")
        if not problem.noise_mm or problem.noise_mm <= 0:
            raise ValueError("stiffness imaging needs the dataset's noise level (noise_mm > 0)")
        self.problem = problem
        self.field = stiffness_field
        self.sigma = float(problem.noise_mm)
        self.reference_kpa = float(
            model.parameters["E"] if reference_kpa is None else reference_kpa
        )
        gradient = model.gradient
        free = PhysicalGradient(
            tuple(op[:, model.free].tocsr() for op in gradient.operators),
            gradient.volume,
            gradient.points,
        )
        self._free_gradient = free
        blocks = free.strain() + [free.divergence()]
        self.G = sp.vstack(blocks).tocsr()
        self.poisson = float(model.parameters["nu"] if poisson is None else poisson)
        mu_unit, lam_unit = lame(1.0, self.poisson)
        self.moduli = np.array([2.0 * mu_unit] * 6 + [lam_unit]) / KPA
        """f of eq. (I2): moduli per unit E [N/mm^2 per N/mm^2]."""
        self.volume = gradient.volume
        self.Phi = stiffness_field.collocation(gradient.points)
        self._phi_stacked = sp.kron(np.ones((7, 1)), self.Phi).tocsr()
        """Phi repeated for the 7 rows of G at each point, (7 n_q, N)."""
        coupling = sp.kron(sp.identity(3), model._constraint_free).tocsr()
        self.coupling = coupling
        self.n_displacement = 3 * model.n_free
        self.right_hand_sides = np.column_stack([self._rhs(case) for case in problem.cases])
        self.A = [problem.case_residual_jacobian(c) for c in problem.cases]
        self.observed_rows, self.rows_of_case = distinct_rows(self.A)
        """U of eq. (I6), the distinct rows of all A_k, and per case the index of each
        of its rows in U."""
        self.b = [problem.case_offset(c) for c in problem.cases]
        n = sum(len(b) for b in self.b)
        noise = Whitening.of(problem.rest_noise_map(), n)
        self.whitening = noise.matrix / self.sigma
        """W / sigma of eq. (I4), (n_residuals, n_residuals)."""
        self.noise_rms_mm = noise.noise_rms(self.sigma)
        """The RMS marker distance of a pure-noise residual [mm]."""
        self._cache: Forward | None = None
        self._force_operators: ForceOperators | None = None
        self._restriction: tuple | None = None
        self.nlp_cache: dict = {}
        """Simultaneous NLPs built for this problem (``solvers.imaging.estimate.simultaneous``)."""

    @property
    def size(self) -> int:
        """N, the number of field coefficients."""
        return self.field.size

    @property
    def n_residuals(self) -> int:
        """Number of scalar residuals over all cases."""
        return int(self.whitening.shape[0])

    def _rhs(self, case) -> np.ndarray:
        model = self.problem.model
        force = np.ravel(case.force, order="F")
        if self.coupling.shape[0] == 0:
            return force
        prescribed = model._constraint_rows @ case.prescribed
        return np.concatenate([force, np.ravel(prescribed, order="F")])

    # ------------------------------------------------------------- the map
    def modulus(self, c: np.ndarray) -> np.ndarray:
        """E at the Gauss points [kPa] (eq. I1)."""
        return self.reference_kpa * np.exp(self.Phi @ np.asarray(c, dtype=float))

    def weights(self, c: np.ndarray) -> np.ndarray:
        """h(c) of eq. (I2), (7 n_q,) [N/mm^2 mm^3]."""
        return np.kron(self.moduli, self.volume * self.modulus(c) * KPA)

    def stiffness(self, c: np.ndarray) -> sp.csc_matrix:
        """K(c) on the free control points, stacked (eq. I2) [N/mm].

        Assembled as mu' K_mu + lambda' K_lambda (``PhysicalGradient.elasticity`` of the
        model's gradient, element by element, with the modulus field E(q) as weight;
        mu', lambda' the Lame moduli per unit E), then restricted to the free points by
        an index map made once: the same matrix as G^T diag(h(c)) G to rounding, a
        tenth of the time at 27 x 27 x 4.
        """
        modulus = self.modulus(c) * KPA
        matrices = self.problem.model.gradient.elasticity(lambda points: modulus)
        mu_unit, lam_unit = lame(1.0, self.poisson)
        full = sp.csr_matrix(
            (mu_unit / KPA) * matrices["shear"] + (lam_unit / KPA) * matrices["volumetric"]
        )
        return self._restricted(full)

    def _restricted(self, full: sp.csr_matrix) -> sp.csc_matrix:
        """The free rows and columns of a (3 n, 3 n) matrix, by an index map kept for its
        pattern."""
        kept = self._restriction
        same = (
            kept is not None
            and np.array_equal(kept[0], full.indptr)
            and np.array_equal(kept[1], full.indices)
        )
        if not same:
            model = self.problem.model
            n = model.volume.basis.size
            free = np.concatenate([model.free + k * n for k in range(3)])
            template = sp.csr_matrix(
                (np.arange(1.0, full.nnz + 1.0), full.indices, full.indptr), shape=full.shape
            )
            sub = template[free][:, free].tocsc()
            order = sub.data.astype(np.int64) - 1
            kept = self._restriction = (full.indptr.copy(), full.indices.copy(), sub, order)
        sub, order = kept[2], kept[3]
        return sp.csc_matrix((full.data[order], sub.indices, sub.indptr), shape=sub.shape)

    def reference_stiffness(self, c: np.ndarray) -> sp.csc_matrix:
        """K(c) = G^T diag(h(c)) G of eq. (I2) as written, symmetrised (tests)."""
        matrix = self.G.T @ sp.diags(self.weights(c)) @ self.G
        return sp.csc_matrix(0.5 * (matrix + matrix.T))

    def saddle(self, c: np.ndarray) -> sp.csc_matrix:
        """M(c) of eq. (I3)."""
        if self.coupling.shape[0] == 0:
            return self.stiffness(c)
        return sp.bmat([[self.stiffness(c), self.coupling.T], [self.coupling, None]], "csc")

    def forward(self, c: np.ndarray) -> Forward:
        """States and whitened residuals of every case at c (cached for the last c)."""
        c = np.asarray(c, dtype=float)
        if self._cache is not None and np.array_equal(self._cache.coefficients, c):
            return self._cache
        solve = Factor(self.saddle(c), definite=self.coupling.shape[0] == 0).solve
        states = solve(self.right_hand_sides)
        states = [states[:, k] for k in range(states.shape[1])]
        raw = np.concatenate([a @ s + b for a, s, b in zip(self.A, states, self.b)])
        moduli = self.volume * self.modulus(c) * KPA
        self._cache = Forward(c.copy(), states, raw, self.whitening @ raw, moduli, solve)
        return self._cache

    def _scaled_strains(self, state: Forward, k: int) -> np.ndarray:
        """h'(Delta_k) = f (x) (w_q E(q)) * (G Delta_k), (7 n_q,): with it eq. (I5) is
        (dK/dc v) Delta_k = G^T (h' * (Phi_7 v)), Phi_7 the field repeated per row of G."""
        strains = self._strains(state)[:, k].reshape(7, -1)
        return (self.moduli[:, None] * strains * state.point_moduli).reshape(-1)

    def _strains(self, state: Forward) -> np.ndarray:
        """G Delta_k of every case at a kept state, (7 n_q, n_cases), cached on it."""
        if state.strains is None:
            displacements = np.column_stack(state.states)[: self.n_displacement]
            state.strains = self.G @ displacements
        return state.strains

    def _padded(self, displacement_part: np.ndarray) -> np.ndarray:
        """[x; 0]: a force on the displacements, zero on the constraint rows of eq. (I3)."""
        n_state = self.right_hand_sides.shape[0]
        out = np.zeros((n_state,) + displacement_part.shape[1:])
        out[: self.n_displacement] = displacement_part
        return out

    # ------------------------------------------------------------- derivatives
    def gradient(self, c: np.ndarray) -> np.ndarray:
        """d Phi_d / dc by one adjoint solve per case (eq. I5) [1]."""
        return self.vjp(c, self.forward(c).residual)

    def jvp(self, c: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """J v, the stacked whitened residuals' change along v (one solve per case)."""
        return self.jvp_at(self.forward(c), direction)

    def jvp_at(self, state: Forward, direction: np.ndarray) -> np.ndarray:
        """``jvp`` at the c of a kept ``forward`` result (its factorisation reused)."""
        field = self._phi_stacked @ direction
        forces = np.column_stack(
            [
                self._padded(self.G.T @ (self._scaled_strains(state, k) * field))
                for k in range(len(self.A))
            ]
        )
        return self._response(state, forces)

    def _response(self, state: Forward, forces: np.ndarray) -> np.ndarray:
        """The whitened marker change -W [A_k M^-1 f_k]_k / sigma of per-case forces f_k
        (columns of ``forces``, padded to the saddle system), one solve per case."""
        changes = -state.solve(forces)
        return self.whitening @ np.concatenate([a @ changes[:, k] for k, a in enumerate(self.A)])

    def vjp(self, c: np.ndarray, vector: np.ndarray) -> np.ndarray:
        """J^T y for a stacked residual-sized y (one adjoint solve per case)."""
        return self.vjp_at(self.forward(c), vector)

    def vjp_at(self, state: Forward, vector: np.ndarray) -> np.ndarray:
        """``vjp`` at the c of a kept ``forward`` result (its factorisation reused)."""
        parts = np.split(self.whitening.T @ vector, np.cumsum([len(b) for b in self.b])[:-1])
        adjoints = state.solve(np.column_stack([a.T @ y for a, y in zip(self.A, parts)]))
        total = sum(
            self._scaled_strains(state, k) * (self.G @ adjoints[: self.n_displacement, k])
            for k in range(len(self.A))
        )
        return -(self._phi_stacked.T @ total)

    def sensitivities(self, c: np.ndarray, route: str = "auto") -> np.ndarray:
        """J = d r / dc, all N columns (n_residuals, N): the implicit-function route.

        ``route`` "adjoint" solves for the distinct observed rows once (eq. I6),
        "forward" for the N columns of each case; "auto" takes the fewer solves.
        """
        state = self.forward(c)
        n_rows, n_forward = self.observed_rows.shape[0], self.size * len(self.A)
        if route == "adjoint" or (route == "auto" and n_rows < n_forward):
            columns = self._adjoint_sensitivities(state)
        elif route in ("forward", "auto"):
            columns = []
            for k, a in enumerate(self.A):
                forces = self.G.T @ sp.diags(self._scaled_strains(state, k)) @ self._phi_stacked
                columns.append(-(a @ state.solve(self._padded(forces.toarray()))))
        else:
            raise ValueError("route must be 'auto', 'adjoint' or 'forward'")
        return self.whitening @ np.vstack(columns)

    def _adjoint_sensitivities(self, state: Forward) -> list[np.ndarray]:
        """The per-case blocks -A_k M^-1 B_k of eq. (I6): Z = M^-1 U^T in one solve,
        then B_k^T Z = sum_i T_ik Z_i by eq. (I7) (``solvers.imaging.fieldsensitivity``)."""
        adjoints = state.solve(self.observed_rows.T.toarray())[: self.n_displacement]
        if self._force_operators is None:
            self._force_operators = ForceOperators(self.Phi, self._free_gradient.operators)
        scaled = np.stack(
            [self._scaled_strains(state, k).reshape(7, -1) for k in range(len(self.A))], axis=-1
        )
        components = np.split(adjoints, 3)
        blocks = []
        for parts, rows in zip(
            self._force_operators.blocks(point_weights(scaled)), self.rows_of_case
        ):
            blocks.append(-sum(t @ z[:, rows] for t, z in zip(parts, components)).T)
        return blocks

    def poisson_sensitivity(self, c: np.ndarray) -> np.ndarray:
        """d r / d nu at c, the held nu's column (n_residuals,): one solve per case.

        K depends on nu through f of eq. (I2) only, so (dK/dnu) Delta_k =
        G^T ((df/dnu) (x) (w_q E(q)) * (G Delta_k)), with d(2 m)/dnu = -1 / (1 + nu)^2
        and d(l)/dnu = (1 + 2 nu^2) / ((1 + nu)(1 - 2 nu))^2 per unit E.
        """
        state = self.forward(c)
        nu = self.poisson
        rate = np.array(
            [-1.0 / (1.0 + nu) ** 2] * 6 + [(1 + 2 * nu**2) / ((1 + nu) * (1 - 2 * nu)) ** 2]
        )
        forces = []
        for k in range(len(self.A)):
            strains = self._strains(state)[:, k].reshape(7, -1)
            forces.append(self.G.T @ ((rate[:, None] * strains * state.point_moduli).ravel()))
        return self._response(state, self._padded(np.column_stack(forces)))

    def residual(self, c: np.ndarray) -> np.ndarray:
        """The stacked whitened residuals r(c)."""
        return self.forward(c).residual

    def rms_um(self, c: np.ndarray) -> float:
        """RMS marker distance [um] (unwhitened, as the reports give it)."""
        return float(1e3 * np.sqrt(3.0 * np.mean(self.forward(c).raw ** 2)))


def distinct_rows(matrices) -> tuple[sp.csr_matrix, list[np.ndarray]]:
    """The distinct rows U of the stacked sparse ``matrices`` (same column count), and
    for each matrix the index in U of each of its rows (rows equal entry by entry)."""
    index, rows, where = {}, [], []
    for matrix in matrices:
        matrix = sp.csr_matrix(matrix)
        matrix.sort_indices()
        positions = np.empty(matrix.shape[0], dtype=int)
        for i in range(matrix.shape[0]):
            span = slice(matrix.indptr[i], matrix.indptr[i + 1])
            key = (matrix.indices[span].tobytes(), matrix.data[span].tobytes())
            if key not in index:
                index[key] = len(rows)
                rows.append(matrix[i])
            positions[i] = index[key]
        where.append(positions)
    width = matrices[0].shape[1]
    stacked = sp.vstack(rows).tocsr() if rows else sp.csr_matrix((0, width))
    return stacked, where
