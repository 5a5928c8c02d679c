"""The trapezoidal scheme (T1, T2) of ``solvers.dynamic`` and its exact forward sensitivities.

Eliminating v_{n+1} = 2 du / h - v_n (T1) with du = u_{n+1} - u_n leaves, per step,

    b(du) = (2/h) M du - 2 M v_n + D du + h/2 [f(u_n) + f(u_n + du) - F_n - F_{n+1}] = 0,

solved by Newton with J = (2/h) M + D + h/2 K(u_{n+1}), K = df/du (one step for the
linear model, where J depends only on h and x and is factorised once per step size).
Differentiating b = 0 with respect to x gives the sensitivities of the *discrete*
scheme (not of the ODE), exactly:

    J dS = -[ db/dx + h/2 (K(u_n) + K(u_{n+1})) S_u,n - 2 M S_v,n ],
    S_u,n+1 = S_u,n + dS,    S_v,n+1 = (2/h) dS - S_v,n,

with db/dx = dM/dx (v_{n+1} - v_n) + dD/dx du + h/2 (df/dx(u_n) + df/dx(u_{n+1})).
This is forward-mode differentiation of the time-stepping loop: p extra right-hand
sides per step, against the same factorisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.dynamic.problem import TimeGrid, parameter_values, unit_matrices
from solvers.forward.evaluator import casadi_to_scipy
from symbolic.model import TissueModel
from symbolic.unitterms import term_parameter


class SchemeError(RuntimeError):
    """Newton failed in a step of the scheme (nonlinear model only)."""


@dataclass
class SchemeRun:
    """One run of the scheme from rest.

    Attributes
    ----------
    displacements, velocities : numpy.ndarray
        u_n and v_n at every node, (N + 1, 3 n_free) [mm], [mm/s].
    sensitivities : numpy.ndarray or None
        du_n/dx at every node, (N + 1, 3 n_free, p) [mm per unit of x].
    newton_iterations : int
        Newton iterations over all steps.
    """

    displacements: np.ndarray
    velocities: np.ndarray
    sensitivities: np.ndarray | None
    newton_iterations: int


class TrapezoidalScheme:
    """Integrates (T1, T2) on a time grid for given x, with optional sensitivities.

    Parameters
    ----------
    model : TissueModel
        The model (without prescribed displacements).
    names : tuple of str
        Parameters given as x (the others keep ``model.parameters``).
    grid : TimeGrid
        The nodes of the scheme.
    newton_tol : float
        Newton (nonlinear model) stops at |b| <= newton_tol h max(|F|, |f|) [relative].
    max_newton : int
        Newton iterations per step.
    """

    def __init__(self, model: TissueModel, names, grid: TimeGrid, newton_tol=1e-13, max_newton=30):
        if model.n_constraints:
            raise ValueError("trajectories with prescribed displacements are not supported")
        self.model, self.names, self.grid = model, tuple(names), grid
        self.newton_tol, self.max_newton = newton_tol, max_newton
        self.unit_mass, self.unit_damping = unit_matrices(model)
        self.term_parameter = {term: term_parameter(term) for term in model.terms}
        self.linear = model.is_linear(self.names)
        self._blocks: dict | None = None
        if not self.linear:
            g = model.state_residual(self.names)
            s, x = ca.MX.sym("s", 3 * model.n_free), ca.MX.sym("x", len(self.names))
            force = g(s, x, ca.MX(model.n_free, 3), ca.MX(0, 3))
            self.internal = ca.Function("f", [s, x], [force], ["s", "x"], ["f"])
            self.tangent = ca.Function("df_ds", [s, x], [ca.jacobian(force, s)])
            self.force_x = ca.Function("df_dx", [s, x], [ca.jacobian(force, x)])

    # ------------------------------------------------------------------ pieces
    def _force(self, u: np.ndarray, x: np.ndarray) -> np.ndarray:
        """f(u; x) = K(B; x)(B - B0) on the free points, vec form [N]."""
        return np.asarray(self.internal(u, x)).ravel()

    def _force_x(self, u: np.ndarray, x: np.ndarray) -> np.ndarray:
        """df/dx at u, (3 n_free, p)."""
        return np.asarray(self.force_x(u, x))

    def _tangent(self, u: np.ndarray, x: np.ndarray) -> sp.csc_matrix:
        """K_t = df/du at u, sparse (3 n_free, 3 n_free) [N/mm]."""
        return casadi_to_scipy(self.tangent(u, x))

    # --------------------------------------------------------------------- run
    def run(self, loads: np.ndarray, x, sensitivities: bool = False) -> SchemeRun:
        """Integrate from rest with loads vec F(t_n) at the nodes, (N + 1, 3 n_free) [N].

        Parameters
        ----------
        loads : numpy.ndarray
            F at every node of ``grid``.
        x : array_like
            Values of ``names``.
        sensitivities : bool
            Also return du_n/dx (forward sensitivities of the scheme).
        """
        x = np.asarray(x, dtype=float).reshape(-1)
        if self.linear:
            return self._run_linear(loads, x, sensitivities)
        return self._run_general(loads, x, sensitivities)

    def _run_linear(self, loads, x, sensitivities) -> SchemeRun:
        """The linear model on one n_free x n_free block shared by x, y and z.

        States are (n_free, 3) arrays and sensitivities (n_free, 3 p) arrays, so every
        product is one small dense matrix times a block of columns.
        """
        values = parameter_values(self.model, self.names, x)
        blocks = self.blocks
        mass, damping = values["mu"] * blocks["mass"], values["gamma"] * blocks["damping"]
        stiffness = sum(float(values[name]) * matrix for name, matrix in blocks["terms"].items())
        derivative = [blocks["by_name"].get(name) for name in self.names]
        steps, n, p = self.grid.steps, self.model.n_free, len(self.names)
        forces = loads.reshape(len(loads), 3, n).transpose(0, 2, 1)
        u = np.zeros((steps.size + 1, n, 3))
        v = np.zeros_like(u)
        sens_u = np.zeros((steps.size + 1, n, 3 * p)) if sensitivities else None
        sens_v = np.zeros((n, 3 * p))
        factors: dict[float, spla.SuperLU] = {}
        for k, h in enumerate(steps):
            if h not in factors:
                factors[h] = spla.splu(sp.csc_matrix(2 / h * mass + damping + h / 2 * stiffness))
            rhs = 2 * mass @ v[k] - h * stiffness @ u[k] + h / 2 * (forces[k] + forces[k + 1])
            du = factors[h].solve(rhs)
            u[k + 1], v[k + 1] = u[k] + du, 2 / h * du - v[k]
            if not sensitivities:
                continue
            explicit = np.zeros((n, 3, p))
            for i, name in enumerate(self.names):
                if name == "mu":
                    explicit[:, :, i] = blocks["mass"] @ (v[k + 1] - v[k])
                elif name == "gamma":
                    explicit[:, :, i] = blocks["damping"] @ du
                elif derivative[i] is not None:
                    explicit[:, :, i] = h / 2 * derivative[i] @ (u[k] + u[k + 1])
            coupling = h * stiffness @ sens_u[k] - 2 * mass @ sens_v
            increment = -factors[h].solve(explicit.reshape(n, 3 * p) + coupling)
            sens_u[k + 1] = sens_u[k] + increment
            sens_v = 2 / h * increment - sens_v
        flat = u.transpose(0, 2, 1).reshape(len(u), -1)
        rates = v.transpose(0, 2, 1).reshape(len(v), -1)
        if sensitivities:
            sens_u = sens_u.reshape(len(u), n, 3, p).transpose(0, 2, 1, 3).reshape(len(u), -1, p)
        return SchemeRun(flat, rates, sens_u, steps.size)

    @property
    def blocks(self) -> dict:
        """Dense n_free x n_free blocks M_1, D_1 and K per parameter (built once)."""
        if self._blocks is None:
            model = self.model
            terms: dict[str, np.ndarray] = {}
            for term, matrix in model.terms.items():
                name = self.term_parameter[term]
                terms[name] = terms.get(name, 0) + model.free_block(matrix).toarray()
            self._blocks = {
                "mass": model.free_block(model.mass_matrix({"mu": 1.0})).toarray(),
                "damping": model.free_block(model.damping_matrix({"gamma": 1.0})).toarray(),
                "terms": terms,
                "by_name": {name: terms[name] for name in self.names if name in terms},
            }
        return self._blocks

    def _run_general(self, loads, x, sensitivities) -> SchemeRun:
        """Any model: Newton per step with the CasADi tangent, sparse 3 n_free algebra."""
        values = parameter_values(self.model, self.names, x)
        mass = values["mu"] * self.unit_mass
        damping = values["gamma"] * self.unit_damping
        steps = self.grid.steps
        n, p = 3 * self.model.n_free, len(self.names)
        u = np.zeros((steps.size + 1, n))
        v = np.zeros_like(u)
        sens_u = np.zeros((steps.size + 1, n, p)) if sensitivities else None
        sens_v = np.zeros((n, p))
        derivative = {"mu": self.unit_mass, "gamma": self.unit_damping}
        f0 = self._force(u[0], x)
        tangent0 = self._tangent(u[0], x)
        newton = 0
        for k, h in enumerate(steps):
            du, f1, tangent1, solve, count = self._newton(
                u[k], v[k], f0, loads[k] + loads[k + 1], h, x, mass, damping
            )
            newton += count
            u[k + 1], v[k + 1] = u[k] + du, 2 / h * du - v[k]
            if sensitivities:
                explicit = h / 2 * (self._force_x(u[k], x) + self._force_x(u[k + 1], x))
                for name, matrix in derivative.items():
                    if name in self.names:
                        i = self.names.index(name)
                        change = v[k + 1] - v[k] if name == "mu" else du
                        explicit[:, i] += matrix @ change
                coupling = h / 2 * (tangent0 @ sens_u[k] + tangent1 @ sens_u[k])
                increment = -solve(explicit + coupling - 2 * mass @ sens_v)
                sens_u[k + 1] = sens_u[k] + increment
                sens_v = 2 / h * increment - sens_v
            f0, tangent0 = f1, tangent1
        return SchemeRun(u, v, sens_u, newton)

    def _newton(self, u0, v0, f0, load_sum, h, x, mass, damping):
        """Newton on b(du) = 0 (nonlinear model); returns du, f(u1), K(u1), solve, count."""
        du = h * v0
        scale = max(np.linalg.norm(load_sum), np.linalg.norm(f0), 1e-300)
        known = -2 * mass @ v0 + h / 2 * (f0 - load_sum)
        for count in range(1, self.max_newton + 1):
            f1 = self._force(u0 + du, x)
            residual = 2 / h * mass @ du + damping @ du + known + h / 2 * f1
            tangent = self._tangent(u0 + du, x)
            solve = spla.splu(sp.csc_matrix(2 / h * mass + damping + h / 2 * tangent)).solve
            if np.linalg.norm(residual) <= self.newton_tol * h * scale and count > 1:
                return du, f1, tangent, solve, count
            du = du - solve(residual)
        raise SchemeError(
            f"Newton did not converge in {self.max_newton} iterations (h = {h:.3g} s); "
            "use more substeps or a smaller load"
        )
