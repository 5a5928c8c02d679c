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
whitening of the rest-marker noise every case shares (``solvers.noise``), so that
under pure noise 2 Phi_d ~ chi^2 with n_residuals degrees of freedom. Every load
case shares M(c): one sparse factorisation per c serves all forward and adjoint
solves. The derivative of K(c) s along a direction v of the field is

    (dK/dc v) Delta = G^T (f (x) (w_q E(q) (Phi v)_q) * (G Delta)),                 (I5)

so the adjoint gradient of Phi_d is -Phi^T (w_q E(q) sum_b f_b (G_b lam)(G_b Delta))
with M lam = A^T r / sigma^2 (one adjoint solve per case), and Gauss-Newton products
J v and J^T y cost one solve each. ``sensitivities`` forms the N columns of J (the
implicit-function route); the adjoint route never does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.noise import Whitening
from solvers.problem import InverseProblem
from symbolic.continuum import KPA, PhysicalGradient, lame
from symbolic.field import StiffnessField


@dataclass
class Forward:
    """The state of every load case at one field c (and the factorisation behind it)."""

    coefficients: np.ndarray
    states: list[np.ndarray]
    residual: np.ndarray
    solve: object = field(repr=False)

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
    """

    def __init__(self, problem: InverseProblem, stiffness_field: StiffnessField):
        model = problem.model
        if getattr(model, "energy", "dnurbs") != "linear-elastic":
            raise ValueError("stiffness imaging needs the linear-elastic model (--energy)")
        if not problem.noise_mm or problem.noise_mm <= 0:
            raise ValueError("stiffness imaging needs the dataset's noise level (noise_mm > 0)")
        self.problem = problem
        self.field = stiffness_field
        self.sigma = float(problem.noise_mm)
        self.reference_kpa = float(model.parameters["E"])
        gradient = model.gradient
        free = PhysicalGradient(
            tuple(op[:, model.free].tocsr() for op in gradient.operators),
            gradient.volume,
            gradient.points,
        )
        blocks = free.strain() + [free.divergence()]
        self.n_points = len(gradient.volume)
        self.G = sp.vstack(blocks).tocsr()
        mu_unit, lam_unit = lame(1.0, float(model.parameters["nu"]))
        self.moduli = np.array([2.0 * mu_unit] * 6 + [lam_unit]) / KPA
        """f of eq. (I2): moduli per unit E [N/mm^2 per N/mm^2]."""
        self.volume = gradient.volume
        self.Phi = stiffness_field.collocation(gradient.points)
        coupling = sp.kron(sp.identity(3), model._constraint_free).tocsr()
        self.coupling = coupling
        self.n_displacement = 3 * model.n_free
        self.right_hand_sides = np.column_stack([self._rhs(case) for case in problem.cases])
        self.A = [problem.case_residual_jacobian(c) for c in problem.cases]
        self.b = [problem.case_offset(c) for c in problem.cases]
        n = sum(len(b) for b in self.b)
        self.whitening = Whitening.of(problem.rest_noise_map(), n).matrix / self.sigma
        """W / sigma of eq. (I4), (n_residuals, n_residuals)."""
        self._cache: Forward | None = None

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
        per_point = self.volume * self.modulus(c) * KPA
        return np.kron(self.moduli, per_point)

    def stiffness(self, c: np.ndarray) -> sp.csc_matrix:
        """K(c) on the free control points, stacked (eq. I2) [N/mm]."""
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
        solve = spla.factorized(self.saddle(c))
        states = solve(self.right_hand_sides)
        states = [states[:, k] for k in range(states.shape[1])]
        raw = np.concatenate([a @ s + b for a, s, b in zip(self.A, states, self.b)])
        self._cache = Forward(c.copy(), states, self.whitening @ raw, solve)
        return self._cache

    def _strain_products(self, c, left: list[np.ndarray], right: list[np.ndarray]) -> np.ndarray:
        """Phi^T (w_q E(q) sum_b f_b (G_b l)(G_b r)), summed over the cases [N mm]."""
        total = np.zeros(self.n_points)
        for lhs, rhs in zip(left, right):
            g_left = (self.G @ lhs[: self.n_displacement]).reshape(7, -1)
            g_right = (self.G @ rhs[: self.n_displacement]).reshape(7, -1)
            total += self.moduli @ (g_left * g_right)
        return self.Phi.T @ (self.volume * self.modulus(c) * KPA * total)

    def _direction_force(self, c, direction: np.ndarray, state: np.ndarray) -> np.ndarray:
        """[(dK/dc v) Delta; 0] of eq. (I5)."""
        scale = np.kron(self.moduli, self.volume * self.modulus(c) * KPA * (self.Phi @ direction))
        force = self.G.T @ (scale * (self.G @ state[: self.n_displacement]))
        out = np.zeros_like(state)
        out[: self.n_displacement] = force
        return out

    # ------------------------------------------------------------- derivatives
    def gradient(self, c: np.ndarray) -> np.ndarray:
        """d Phi_d / dc by one adjoint solve per case (eq. I5) [1]."""
        return self.vjp(c, self.forward(c).residual)

    def jvp(self, c: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """J v, the stacked whitened residuals' change along v (one solve per case)."""
        state = self.forward(c)
        forces = np.column_stack([self._direction_force(c, direction, s) for s in state.states])
        changes = -state.solve(forces)
        return self.whitening @ np.concatenate([a @ changes[:, k] for k, a in enumerate(self.A)])

    def vjp(self, c: np.ndarray, vector: np.ndarray) -> np.ndarray:
        """J^T y for a stacked residual-sized y (one adjoint solve per case)."""
        state = self.forward(c)
        parts = np.split(self.whitening.T @ vector, np.cumsum([len(b) for b in self.b])[:-1])
        adjoints = state.solve(np.column_stack([a.T @ y for a, y in zip(self.A, parts)]))
        adjoints = [adjoints[:, k] for k in range(adjoints.shape[1])]
        return -self._strain_products(c, adjoints, state.states)

    def sensitivities(self, c: np.ndarray) -> np.ndarray:
        """J = d r / dc, all N columns (n_residuals, N): the implicit-function route."""
        state = self.forward(c)
        modulus = self.volume * self.modulus(c) * KPA
        columns = []
        for a, s in zip(self.A, state.states):
            strains = (self.G @ s[: self.n_displacement]).reshape(7, -1)
            scaled = (self.moduli[:, None] * strains * modulus).reshape(-1)
            forces = self.G.T @ sp.diags(scaled) @ sp.kron(np.ones((7, 1)), self.Phi)
            padded = np.zeros((len(s), self.size))
            padded[: self.n_displacement] = forces.toarray()
            columns.append(-(a @ state.solve(padded)))
        return self.whitening @ np.vstack(columns)

    def residual(self, c: np.ndarray) -> np.ndarray:
        """The stacked whitened residuals r(c)."""
        return self.forward(c).residual

    def rms_um(self, c: np.ndarray) -> float:
        """RMS marker distance [um] (unwhitened, as the reports give it)."""
        state = self.forward(c)
        raw = np.concatenate([a @ s + b for a, s, b in zip(self.A, state.states, self.b)])
        return float(1e3 * np.sqrt(3.0 * np.mean(raw**2)))
