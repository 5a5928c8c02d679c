"""Transient solution of M B'' + D B' + K(B)(B - B0) = F_B(t) (docs/transient.md, eq. 22, 23).

On the free control points, with u = vec(B_free - B0_free) (x components, then y, z),

    M u'' + D u' + f(u; x) = F(t),     f(u; x) = K(B; x)(B - B0) = g(u, x, 0, d),

M = kron(I3, mu M_1), D = kron(I3, gamma D_1) (eq. 13, 16) and g the static residual
of ``TissueModel.state_residual``. Steady state, f(u) = F, is the paper's forward
solution; mu and gamma only shape the way there.

The one-step schemes (Newmark, generalised-alpha, backward Euler) are in
``solvers.transient.schemes``.

Each step solves r(du) = 0 for du = u_{n+1} - u_n by (modified) Newton with the
CasADi tangent df/du (sparse, SuperLU). For the linear model (k0 = 0) the effective
matrix is constant for a given dt: one factorisation per step size. Adaptive steps
use the embedded local error estimate C dt^2 (a_{n+1} - a_n) and step sizes dt_0 2^k,
so few factorisations are needed. Newmark has no numerical dissipation: at large dt its
unresolved stiff modes (rate gamma/mu) do not decay, so runs to steady state use
generalised-alpha with rho_inf = 0 (see docs/transient.md).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.forward.evaluator import casadi_to_scipy
from solvers.transient.modal import probe_observation
from solvers.transient.profiles import as_load
from solvers.transient.result import TransientResult, settling_time
from solvers.transient.schemes import SCHEMES, Scheme
from symbolic.model import TissueModel


class TransientError(RuntimeError):
    """A time step could not be completed (Newton failed at the smallest step)."""


_REFRESH, _SLOW = 0.5, 6
"""Modified Newton: a new tangent when |r| falls by less than _REFRESH in an iteration,
or at the next step after one that needed more than _SLOW iterations."""


@dataclass(frozen=True)
class StepSettings:
    """Step-size and Newton settings.

    Attributes
    ----------
    dt : float or None
        Fixed step [s]; None for adaptive steps.
    rtol, atol : float
        Adaptive steps keep the embedded estimate of the local displacement error
        (RMS) below atol + rtol RMS(u) [mm].
    dt_initial : float or None
        First adaptive step [s]; default sqrt(2 atol / RMS(a_0)).
    dt_max : float
        Largest adaptive step [s].
    newton_tol : float
        Newton stops at |r| <= newton_tol max(|F|, |f(u)|) [relative].
    max_newton : int
        Newton iterations per step before the step is rejected.
    max_steps : int
        Accepted steps before giving up.
    """

    dt: float | None = None
    rtol: float = 1e-4
    atol: float = 1e-9
    dt_initial: float | None = None
    dt_max: float = np.inf
    newton_tol: float = 1e-12
    max_newton: int = 25
    max_steps: int = 200_000


class _State(NamedTuple):
    t: float
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    f: np.ndarray


class TransientSolver:
    """The transient of one model for one choice of symbolic parameters ``names``.

    The CasADi Functions f(u, x) and df/du are built once; ``integrate`` can be
    called for many x, loads, mu and gamma.
    """

    def __init__(self, model: TissueModel, names: tuple[str, ...] = (), method="newmark"):
        if model.n_constraints:
            raise ValueError("transients with prescribed displacements are not supported")
        self.model, self.names = model, tuple(names)
        self.scheme = method if isinstance(method, Scheme) else SCHEMES.get(method)
        if self.scheme is None:
            raise ValueError(f"unknown method {method!r}; use one of {list(SCHEMES)}")
        g = model.state_residual(self.names)
        s, x = ca.MX.sym("s", g.size1_in(0)), ca.MX.sym("x", len(self.names))
        force = g(s, x, ca.MX(model.n_free, 3), ca.MX(0, 3))
        self.internal = ca.Function("f", [s, x], [force], ["s", "x"], ["f"])
        self.tangent = ca.Function("df_ds", [s, x], [ca.jacobian(force, s)], ["s", "x"], ["K"])
        self.unit_mass = model.free_block(model.mass_matrix({"mu": 1.0}))
        self.unit_damping = model.free_block(model.damping_matrix({"gamma": 1.0}))
        self.probe = probe_observation(model)

    def values(self, x, overrides) -> tuple[np.ndarray, dict]:
        """x as an array and all parameter values, with mu and gamma from overrides or x."""
        x = np.asarray([] if x is None else x, dtype=float).reshape(-1)
        if x.size != len(self.names):
            raise ValueError(f"expected {len(self.names)} values for {self.names}, got {x.size}")
        unknown = set(overrides or {}) - {"mu", "gamma"}
        if unknown:
            raise ValueError(
                f"overrides may set mu and gamma only, got {sorted(unknown)}; "
                "pass stiffness parameters as names and x"
            )
        dynamic = {n: v for n, v in zip(self.names, x) if n in ("mu", "gamma")}
        return x, self.model.values({**(overrides or {}), **dynamic})

    def integrate(
        self,
        load,
        t_end: float,
        x=None,
        overrides=None,
        settings=None,
        start=None,
        steady_tol: float | None = None,
    ) -> TransientResult:
        """Integrate eq. (22) from ``start`` (default rest), at rest velocity, to ``t_end``.

        Parameters
        ----------
        load : numpy.ndarray, Load or callable
            F_B(t) on the free points, (n_free, 3) [N]; an array is a step load.
        t_end : float
            Final time [s] (the run stops earlier at steady state if ``steady_tol``).
        x : array_like, optional
            Values of ``names``; mu and gamma among them set the dynamics.
        overrides : dict, optional
            mu [t] and gamma [N s/mm] for M and D (eq. 13, 16).
        settings : StepSettings, optional
            Fixed or adaptive steps, tolerances.
        start : numpy.ndarray, optional
            Initial s = vec(B_free - B0_free) [mm].
        steady_tol : float, optional
            Stop when |f(u) - F| <= tol |F| and sqrt(v^T M v / u^T f(u)) <= tol.
        """
        x, values = self.values(x, overrides)
        run = _Run(self, as_load(load), x, values, settings or StepSettings(), start)
        return run.solve(float(t_end), steady_tol)


def _factorize(matrix: sp.spmatrix) -> Callable[[np.ndarray], np.ndarray]:
    """SuperLU solve function (also for small blocks: it avoids BLAS thread overhead)."""
    return spla.splu(sp.csc_matrix(matrix)).solve


class _Run:
    """One integration: matrices for given mu, gamma and x, factorisations, counters.

    States are (n_free, 3) arrays; M and D act on each column with the same block.
    """

    def __init__(self, solver: TransientSolver, load, x, values, settings, start):
        self.solver, self.load, self.x, self.settings = solver, load, x, settings
        self.scheme, n = solver.scheme, solver.model.n_free
        self.mass = values["mu"] * solver.unit_mass
        self.damping = values["gamma"] * solver.unit_damping
        k0 = dict(zip(solver.names, x)).get("k0", solver.model.parameters["k0"])
        self.linear = k0 == 0.0
        self.factors: dict[float, Callable] = {}
        self.newton = self.jacobians = 0
        self.refresh = False
        u = np.zeros((n, 3)) if start is None else _matrix(np.asarray(start, dtype=float), n)
        self.stiffness = self._tangent(u)
        if self.linear:
            self.stiffness = _diagonal_block(self.stiffness, n)
        f = self.force(u)
        load0 = self._load(0.0)
        self.scale = max(np.linalg.norm(load0), np.linalg.norm(f), 1e-300)
        a = _factorize(self.mass)(load0 - f)
        self.state = _State(0.0, u, np.zeros((n, 3)), a, f)

    def _load(self, t: float) -> np.ndarray:
        return np.asarray(self.load(t), dtype=float).reshape(-1, 3)

    def force(self, u: np.ndarray) -> np.ndarray:
        """f(u) = K(B; x)(B - B0) on the free points, (n_free, 3) [N]."""
        if self.linear:
            return self.stiffness @ u
        return _matrix(np.asarray(self.solver.internal(u.ravel(order="F"), self.x)), len(u))

    def _tangent(self, u: np.ndarray) -> sp.csc_matrix:
        self.jacobians += 1
        self.factors.clear()
        return casadi_to_scipy(self.solver.tangent(u.ravel(order="F"), self.x))

    def _solve(self, dt: float, rhs: np.ndarray) -> np.ndarray:
        if dt not in self.factors:
            s = self.scheme
            c_a, c_v = s.matrix_coefficients(dt)
            block = (1 - s.alpha_m) * c_a * self.mass + (1 - s.alpha_f) * c_v * self.damping
            if not self.linear:
                block = sp.kron(sp.eye(3), block)
            self.factors[dt] = _factorize(block + (1 - s.alpha_f) * self.stiffness)
        if self.linear:
            return self.factors[dt](rhs)
        return _matrix(self.factors[dt](rhs.ravel(order="F")), len(rhs))

    def step(self, st: _State, dt: float) -> _State | None:
        """One step of the scheme; None when Newton fails."""
        s = self.scheme
        c_a, c_v = s.matrix_coefficients(dt)
        a_hat, v_hat = s.predictors(dt, st.v, st.a)
        load = (1 - s.alpha_f) * self._load(st.t + dt) + s.alpha_f * self._load(st.t)
        known = self.mass @ (s.alpha_m * st.a + (1 - s.alpha_m) * a_hat)
        known += self.damping @ (s.alpha_f * st.v + (1 - s.alpha_f) * v_hat)
        known += st.f - load
        if self.linear:  # r(du) = known + J du exactly
            du = -self._solve(dt, known)
            self.newton += 1
            f = self.stiffness @ (st.u + du)
            return _State(st.t + dt, st.u + du, c_v * du + v_hat, c_a * du + a_hat, f)
        return self._newton(st, dt, known, c_a, c_v, a_hat, v_hat, load)

    def _newton(self, st, dt, known, c_a, c_v, a_hat, v_hat, load) -> _State | None:
        """Modified Newton: the tangent is refreshed when the contraction is poor."""
        s = self.scheme
        tol = self.settings.newton_tol * max(self.scale, np.linalg.norm(load))
        du = dt * st.v + 0.5 * dt**2 * st.a  # Taylor predictor
        f, previous = (st.f if not du.any() else self.force(st.u + du)), np.inf
        mass, damping = (1 - s.alpha_m) * c_a * self.mass, (1 - s.alpha_f) * c_v * self.damping
        for iteration in range(self.settings.max_newton + 1):
            residual = known + mass @ du + damping @ du + (1 - s.alpha_f) * (f - st.f)
            norm = np.linalg.norm(residual)
            if norm <= tol:
                break
            if iteration == self.settings.max_newton or not np.isfinite(norm):
                self.refresh = True
                return None
            if self.refresh or norm > _REFRESH * previous:
                self.stiffness, self.refresh = self._tangent(st.u + du), False
            increment = self._solve(dt, residual)
            du = du - increment
            f, previous = self.force(st.u + du), norm
            self.newton += 1
            if np.linalg.norm(increment) <= 1e-13 * np.linalg.norm(st.u + du):
                break
        self.refresh = iteration > _SLOW
        return _State(st.t + dt, st.u + du, c_v * du + v_hat, c_a * du + a_hat, f)

    def _embedded(self, st: _State, dt: float) -> tuple[_State | None, float]:
        """One step and its local error estimate (Zienkiewicz-Xie for the 2nd-order schemes)."""
        new = self.step(st, dt)
        if new is None:
            return None, np.inf
        if self.scheme.order == 1:
            error = 0.5 * dt * (new.v - st.v)
        else:
            error = dt**2 * self.scheme.error_constant * (new.a - st.a)
        return new, self._error_norm(error, new)

    def _error_norm(self, error: np.ndarray, new: _State) -> float:
        bound = self.settings.atol + self.settings.rtol * np.sqrt(np.mean(new.u**2))
        return float(np.sqrt(np.mean(error**2)) / bound)

    def steady_measures(self, st: _State) -> tuple[float, float]:
        """(|f(u) - F| / |F|, sqrt(v^T M v / u^T f(u))) at a state."""
        load = self._load(st.t)
        static = np.linalg.norm(st.f - load) / max(self.scale, np.linalg.norm(load))
        energy, kinetic = float(np.vdot(st.u, st.f)), float(np.vdot(st.v, self.mass @ st.v))
        return float(static), float(np.sqrt(kinetic / energy)) if energy > 0 else np.inf

    def _first_step(self) -> float:
        if self.settings.dt_initial is not None:
            return self.settings.dt_initial
        acceleration = np.sqrt(np.mean(self.state.a**2))
        return float(np.sqrt(2 * self.settings.atol / acceleration)) if acceleration else 1e-6

    def solve(self, t_end: float, steady_tol: float | None) -> TransientResult:
        """Step to t_end (or steady state); adaptive steps double at most every other step.

        Holding dt for a step after each change keeps the algorithmic velocity and
        acceleration of generalised-alpha decaying at large dt (with dt doubling every
        step they decay only by 1/2 per step). Steps never exceed the elapsed time.
        """
        cfg, st = self.settings, self.state
        history, dt, rejected, steady_time = [st], cfg.dt or self._first_step(), 0, None
        previous = None
        while st.t < t_end * (1 - 1e-14) and len(history) <= cfg.max_steps:
            h = min(dt, t_end - st.t)
            if cfg.dt is not None:
                new = self.step(st, h)
                if new is None:
                    raise TransientError(
                        f"Newton failed at t = {st.t:.4g} s with dt = {h:.3g} s; "
                        "use a smaller dt or adaptive steps (dt=None)"
                    )
            else:
                new, error = self._embedded(st, h)
                if new is None or error > 1.0:
                    rejected, dt = rejected + 1, 0.5 * h
                    if dt < 1e-14 * max(t_end, 1.0):
                        raise TransientError(
                            f"step size underflow at t = {st.t:.4g} s; reduce the load "
                            "or the stiffening k0, or loosen rtol"
                        )
                    continue
                if h == previous and error * 2.0 ** (self.scheme.order + 1) <= 0.8:
                    dt = min(2.0 * h, cfg.dt_max, max(new.t, h))
            st, previous = new, h
            history.append(st)
            if steady_tol is not None and max(self.steady_measures(st)) <= steady_tol:
                steady_time = st.t
                break
        return self._result(history, rejected, steady_time)

    def _result(self, history: list[_State], rejected: int, steady_time) -> TransientResult:
        model = self.solver.model
        times = np.array([s.t for s in history])
        displacements = np.array([s.u for s in history])
        velocities = np.array([s.v for s in history])
        probe = np.einsum("pn,knc->kpc", self.solver.probe, displacements)
        probe_rate = np.einsum("pn,knc->kpc", self.solver.probe, velocities)
        static, kinetic = self.steady_measures(history[-1])
        return TransientResult(
            times=times,
            displacements=displacements,
            velocities=velocities,
            probe=probe[:, 0],
            state=history[-1].u.ravel(order="F"),
            positions=model.full_positions(displacements[-1]),
            steps=len(history) - 1,
            rejected=rejected,
            newton_iterations=self.newton,
            jacobian_evaluations=self.jacobians,
            steady=steady_time is not None,
            steady_time=steady_time,
            settling_time=settling_time(times, displacements, velocities),
            probe_settling_time=settling_time(times, probe, probe_rate),
            static_residual=static,
            kinetic_ratio=kinetic,
            method=self.scheme.name,
        )


def _matrix(vector: np.ndarray, n: int) -> np.ndarray:
    """vec(U) (columns stacked) back to U, (n, 3)."""
    return np.asarray(vector).reshape(3, n).T


def _diagonal_block(matrix: sp.spmatrix, n: int) -> sp.csr_matrix:
    """The common diagonal block K of kron(I3, K), checked."""
    matrix = sp.csr_matrix(matrix)
    block = matrix[:n, :n]
    if abs(matrix - sp.kron(sp.eye(3), block)).max() > 1e-12 * abs(block).max():
        raise ValueError("the linear stiffness is not the same for the three components")
    return block


_SOLVERS: OrderedDict = OrderedDict()


def transient_solver(model: TissueModel, names=(), method="newmark") -> TransientSolver:
    """A TransientSolver from a small cache (the last 8 models, names and methods)."""
    key = (id(model), tuple(names), method, tuple(sorted(model.parameters.items())))
    if key in _SOLVERS and _SOLVERS[key].model is model:
        _SOLVERS.move_to_end(key)
        return _SOLVERS[key]
    _SOLVERS[key] = TransientSolver(model, names, method)
    while len(_SOLVERS) > 8:
        _SOLVERS.popitem(last=False)
    return _SOLVERS[key]
