"""An inverse problem extended by effects (docs/model.md eq. 22, docs/inverse.md eq. 24).

``ExtendedProblem`` wraps a base ``InverseProblem`` and a list of active effects.
Its unknowns are p = [x; theta] (natural units), and for every load case k it
solves the extended equilibrium g_k(s, p) = 0 by Newton (sparse LU, as
``EquilibriumSolver``) and differentiates the observation residual exactly by
the implicit function theorem,

    dr_k/dp = dr_k/dp|_s - dr_k/ds (dg_k/ds)^-1 dg_k/dp.

The noise model is that of the datasets: every marker coordinate, rest and
loaded, has standard deviation sigma, and the rest markers are shared by all
load cases, so Cov(r) = sigma^2 (I + P P^T). Residuals and Jacobians are whitened
with W = (I + P P^T)^-1/2 (closed form, ``solvers.inverse.noise``): rho = W r has
covariance sigma^2 I under pure noise.

A model linear in the state (``ExtendedModel.linear_state``) takes the linear path
instead (``solvers.forward.linearpath``): one factorisation of the shared stiffness per
parameter value, every case and sensitivity solved with it. Newton stays the path of
the nonlinear bases and effects; where the base is linear and the nonlinear effects give
their forces in numbers (nonlinear_stiffening), Newton's g, dg/ds and dg/dp are
assembled numerically around them (the split path, ``solvers.diagnosis.splitpath``).

The base solvers stay untouched; ``solvers.diagnosis.fit.fit`` is the generic
nested least squares over any subset of p (scipy trf, exact Jacobian).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.diagnosis import newton, splitpath
from solvers.diagnosis.cache import SharedCache
from solvers.diagnosis.casadieval import NumericFunction
from solvers.diagnosis.observation import (
    case_data,
    force_errors,
    noise_model,
    point_errors,
    row_offsets,
)
from solvers.forward import linearpath
from solvers.forward.linearpath import StateJacobian
from solvers.inverse.noise import Whitening
from solvers.inverse.problem import InverseProblem, LoadCase
from solvers.inverse.space import LOG_PARAMETERS
from symbolic.effects.base import CaseData, Effect
from symbolic.effects.composition import ExtendedModel


def _dense(value) -> np.ndarray:
    return value.toarray() if sp.issparse(value) else np.asarray(value)


class ExtendedProblem:
    """Base inverse problem + active effects over a choice of its load cases.

    Parameters
    ----------
    base : InverseProblem
        The base problem (its active parameters become x; mu and gamma drop out).
    loads : list
        The dataset's loads (``PointForce``/``ProbeForce``), one per dataset case.
    effects : list of Effect
        Active effects.
    positions : list of int, optional
        Which of the base problem's cases to use (default all).
    indices : list of int, optional
        Dataset index of every base case (default 0, 1, ...).
    cache : dict, optional
        Store shared by problems derived with ``with_effects``: case data, noise
        model, extended models and their CasADi Functions.
    sigma : float, optional
        Noise level [mm] (default the base problem's ``noise_mm``); kept by
        ``with_effects``.
    """

    def __init__(
        self,
        base: InverseProblem,
        loads,
        effects: list[Effect],
        positions=None,
        indices=None,
        cache: dict | None = None,
        sigma: float | None = None,
    ):
        self.base = base
        self.sigma = base.noise_mm if sigma is None else sigma
        """The noise level [mm] that scales the effects' priors (``prior_matrix``)."""
        self.loads = loads
        self.positions = list(range(len(base.cases)) if positions is None else positions)
        self.indices = list(range(len(base.cases)) if indices is None else indices)
        self.model = base.model
        self.names = tuple(n for n, a in zip(base.names, base.active) if a)
        self.cache = SharedCache() if cache is None else cache
        key = ("model", tuple(id(e) for e in effects), tuple(self.positions))
        if key not in self.cache:
            cases = [self._case(k) for k in self.positions]
            self.cache[key] = ExtendedModel(
                self.model, self.names, list(effects), cases, self.cache
            )
        self.extended = self.cache[key]
        self._set_bounds()
        key = ("noise", tuple(self.positions))
        if key not in self.cache:
            self.cache[key] = self._noise_model()
        self.noise_model = self.cache[key]
        self.whitening = self.noise_model.matrix
        self.n_residuals = self.whitening.shape[0]

    def _case(self, position: int) -> CaseData:
        key = ("case", position)
        if key not in self.cache:
            self.cache[key] = case_data(self.base, self.loads, self.indices[position], position)
        return self.cache[key]

    def _noise_model(self) -> Whitening:
        """The whitening of the cases in use (``solvers.diagnosis.observation``)."""
        return noise_model(self.base, self.cases)

    def case_rows(self) -> list[int]:
        """The residual rows of every case in use: len(observed) n_obs + n_F."""
        return [int(n) for n in np.diff(row_offsets(self.base, self.cases))]

    # ----------------------------------------------------------------- layout
    @property
    def effects(self) -> list[Effect]:
        """Active effects."""
        return self.extended.effects

    @property
    def labels(self) -> list[str]:
        """Names of the entries of p."""
        return self.extended.labels

    @property
    def cases(self) -> list[LoadCase]:
        """The base load cases in use."""
        return [self.base.cases[k] for k in self.positions]

    def _set_bounds(self) -> None:
        space = self.base.space
        lower, upper, scale, log = [], [], [], []
        for name in self.names:
            i = space.names.index(name)
            lower.append(space.lower[i])
            upper.append(space.upper[i])
            scale.append(space.linear_scale[i])
            log.append(name in LOG_PARAMETERS)
        for effect in self.effects:
            lo, hi, sc = self.extended.effect_bounds(effect)
            lower += list(lo)
            upper += list(hi)
            scale += list(sc)
            log += [False] * len(lo)
        self.lower, self.upper = np.array(lower), np.array(upper)
        self.scale, self.log = np.array(scale), np.array(log)

    def to_internal(self, p: np.ndarray) -> np.ndarray:
        """z: log(p) for positive material parameters, p / scale otherwise."""
        p = np.asarray(p, dtype=float)
        return np.where(self.log, np.log(np.maximum(p, 1e-300)), p / self.scale)

    def to_natural(self, z: np.ndarray) -> np.ndarray:
        """p from z (exp only of the log entries: an effect's z may be large)."""
        z = np.asarray(z, dtype=float)
        p = z * self.scale
        p[self.log] = np.exp(z[self.log])
        return p

    def natural_derivative(self, z: np.ndarray) -> np.ndarray:
        """dp/dz, elementwise."""
        z = np.asarray(z, dtype=float)
        derivative = np.array(self.scale, dtype=float)
        derivative[self.log] = np.exp(z[self.log])
        return derivative

    def functions(self, position: int):
        """The CasADi Functions of the case at ``position`` (``CaseFunctions`` of
        ``symbolic.effects.functions``)."""
        return self.extended.functions(position)

    def slice_of(self, name: str) -> slice:
        """Where an effect's parameters sit in p."""
        return self.extended.slices[name]

    def start(self) -> np.ndarray:
        """Default p: the base space's start for x, zero for theta."""
        space = self.base.space
        x = [space.start[space.names.index(n)] for n in self.names]
        return np.concatenate([x, np.zeros(len(self.labels) - len(self.names))])

    # ------------------------------------------------------------- evaluation
    def numeric(self, position: int, name: str) -> NumericFunction:
        """A Function of the case at ``position`` wrapped for fast numeric calls."""
        return self.numeric_of(getattr(self.functions(position), name))

    def numeric_of(self, function) -> NumericFunction:
        """``function`` (of this effect set) wrapped for fast numeric calls, kept in the
        shared store with the set."""
        key = ("functions", self.extended.effect_set, "numeric", id(function))
        if key not in self.cache:
            self.cache[key] = (function, NumericFunction(function))
        return self.cache[key][1]

    linear_path = True
    """Take the linear path where ``linear_state`` allows (False: Newton per case, the
    reference the tests hold it against)."""

    @property
    def linear_state(self) -> bool:
        """True when every case shares one dg/ds that depends on p alone (the linear path)."""
        return self.linear_path and self.extended.linear_state

    def stiffness_factor(self, p: np.ndarray) -> StateJacobian:
        """The factorisation of the shared K(p) of a model linear in the state.

        Kept for the last p of each effect set; a K equal entry by entry to the last one
        factorised (of any set: a candidate at theta = 0, a refit on fewer cases) reuses
        its factors.
        """
        p = np.asarray(p, dtype=float)
        key = ("functions", self.extended.effect_set, "stiffness_factor")
        entry = self.cache.get(key)
        if entry is not None and np.array_equal(entry[0], p):
            return entry[1]
        matrix = linearpath.stiffness_matrix(self, p)
        last = self.cache.get("last_state_jacobian")
        if last is not None and last.same_as(matrix):
            factor = last
        else:
            split = 3 * self.model.n_free  # where an effect's extra state begins
            rows = linearpath.symmetric_rows(self, p)
            factor = StateJacobian(matrix, rows, split, definite=not self.model.n_constraints)
        self.cache["last_state_jacobian"] = factor
        self.cache[key] = (p.copy(), factor)
        return factor

    def linearise_all(
        self, p: np.ndarray, states: list, factor: StateJacobian | None = None, columns=None
    ):
        """Stacked r and dr/dp of every case at solved states (linear path only).

        ``factor`` is the factorisation of K(p) when the caller has it (default: made);
        ``columns`` limits the solve to those entries of p (the others stay zero).
        """
        factor = self.stiffness_factor(p) if factor is None else factor
        residuals, jacobians = linearpath.linearise(
            self, p, np.column_stack(states), factor, columns=columns
        )
        return np.concatenate(residuals), np.vstack(jacobians)

    def solve_state(
        self, position: int, p: np.ndarray, start=None, tolerance=1e-10, continuation=True
    ):
        """Newton on g(s, p) = 0 for one case; returns the state and its ``StateJacobian``
        (``solvers.diagnosis.newton``: the Jacobian of the last Newton step, exact for a
        model linear in s and accurate to the (tiny) last step otherwise).

        Newton starts from the case's last solve predicted to first order, else from
        ``start`` (default rest); where it fails, and ``continuation`` is on, the load is
        applied in steps from rest (``newton.solve_case``).
        """
        return newton.solve_case(self, position, p, start, tolerance, continuation)

    def _factorised(self, matrix: sp.spmatrix) -> StateJacobian:
        """A ``StateJacobian`` of dg/ds, reusing the last one when the matrix is the same.

        For a linear base model dg/ds depends on p only (no effect of the library
        varies it from case to case), so the load cases of one evaluation share one
        LU; the matrices are compared entry by entry, never assumed equal.
        """
        matrix = sp.csc_matrix(matrix)
        last = self.cache.get("last_state_jacobian")
        if last is not None and last.same_as(matrix):
            return last
        jacobian = StateJacobian(matrix, definite=not self.model.n_constraints)
        self.cache["last_state_jacobian"] = jacobian
        return jacobian

    def linearise(self, position: int, p: np.ndarray, state: np.ndarray, jacobian=None):
        """r and exact dr/dp of one case at a solved state (implicit function theorem).

        The state, ds/dp and dg/ds are kept for the next solve of this case on this
        problem (``solve_state``: the first-order start and its chord steps)."""
        if jacobian is None:
            jacobian = self._factorised(splitpath.equations(self, position, p)[1](state))
        dg_dp, r, dr_ds, dr_dp = splitpath.sensitivity(self, position, state, p)
        sensitivity = -jacobian.solve(_dense(dg_dp))
        total = dr_ds @ sensitivity + _dense(dr_dp)
        memory = (np.array(p, dtype=float), np.array(state), np.asarray(sensitivity), jacobian)
        self.cache[self._memory_key(position)] = memory
        return np.ravel(_dense(r)), total

    def forget_solves(self) -> None:
        """Drop the kept solves of this problem's cases: the next Newton starts from
        ``start`` or rest."""
        for position in range(len(self.positions)):
            self.cache.pop(self._memory_key(position), None)

    def _memory_key(self, position: int) -> tuple:
        """Where the last solve of the case at ``position`` is kept: with the effect set's
        Functions (dropped with them), by base case and by the layout of p."""
        effect_set = self.extended.effect_set
        return ("functions", effect_set, "newton", self.positions[position], tuple(self.labels))

    def evaluate(self, p: np.ndarray, starts=None):
        """Stacked raw residual r(p), its Jacobian dr/dp and the solved states."""
        r, jac, states, _ = self.evaluate_full(p, starts)
        return r, jac, states

    def evaluate_full(self, p: np.ndarray, starts=None):
        """As ``evaluate``, plus the sparse dg/ds of every case."""
        if self.linear_state:
            factor = self.stiffness_factor(p)
            states = linearpath.equilibria(self, p, factor)
            residuals, jacobians = linearpath.linearise(self, p, states, factor)
            columns = [states[:, k].copy() for k in range(states.shape[1])]
            return (
                np.concatenate(residuals),
                np.vstack(jacobians),
                columns,
                [factor] * len(columns),
            )
        starts = starts or [None] * len(self.positions)
        residuals, jacobians, states, state_jacobians = [], [], [], []
        for position in range(len(self.positions)):
            state, jac = self.solve_state(position, p, starts[position])
            r, dr = self.linearise(position, p, state, jac)
            residuals.append(r)
            jacobians.append(dr)
            states.append(state)
            state_jacobians.append(jac)
        return np.concatenate(residuals), np.vstack(jacobians), states, state_jacobians

    def residual(self, p: np.ndarray, starts=None) -> np.ndarray:
        """Stacked raw residual r(p) alone: the equilibria, no sensitivities."""
        if self.linear_state:
            states = linearpath.equilibria(self, p, self.stiffness_factor(p))
            observe = [
                self.numeric_of(self.extended.case_parts(k).observation)
                for k in range(states.shape[1])
            ]
            return np.concatenate(
                [np.ravel(_dense(f(states[:, k], p)[0])) for k, f in enumerate(observe)]
            )
        starts = starts or [None] * len(self.positions)
        residuals = []
        for position in range(len(self.positions)):
            state, _ = self.solve_state(position, p, starts[position])
            residuals.append(splitpath.residual(self, position, state, p))
        return np.concatenate(residuals)

    def whiten(self, values: np.ndarray) -> np.ndarray:
        """W values (vector or matrix)."""
        return self.whitening @ values

    def point_errors(self, r: np.ndarray) -> list[np.ndarray]:
        """Per case, the distance of every observed marker from its prediction [mm]."""
        return point_errors(self.base, self.cases, r)

    def force_errors(self, r: np.ndarray) -> list[np.ndarray | None]:
        """Per case, model minus measured force components [N] (None without a sensor)."""
        return force_errors(self.base, self.cases, r)

    def rms(self, r: np.ndarray) -> tuple[float, float]:
        """RMS and maximum marker distance over all cases [mm] (0 without markers)."""
        every = np.concatenate(self.point_errors(r))
        if not every.size:
            return 0.0, 0.0
        return float(np.sqrt(np.mean(every**2))), float(every.max())

    def force_rms(self, r: np.ndarray) -> float | None:
        """RMS of the force errors over all cases with a force sensor [N] (None: none)."""
        forces = [e for e in self.force_errors(r) if e is not None]
        return float(np.sqrt(np.mean(np.concatenate(forces) ** 2))) if forces else None

    def noise_rms(self, sigma: float) -> float:
        """Expected RMS marker distance of a pure-noise residual over the observed
        components: sigma sqrt(len(observed) tr(Sigma) / m)."""
        return self.noise_model.noise_rms(sigma, len(self.base.observed))

    def with_effects(self, effects: list[Effect], positions=None) -> ExtendedProblem:
        """The same base problem with other effects (or cases)."""
        chosen = self.positions if positions is None else positions
        return ExtendedProblem(
            self.base, self.loads, effects, chosen, self.indices, self.cache, self.sigma
        )

    def prior_matrix(self) -> np.ndarray | None:
        """P with |P p|^2 = sigma^2 sum_e |R_e theta_e|^2 [mm^2], (q, len(p)); None without
        priors.

        Appended to the whitened residual rho, these rows make the least-squares cost the
        negative log posterior of the effects with a prior (``Effect.prior``) in rho's units.
        """
        blocks = [(e, e.prior(self.model)) for e in self.effects]
        blocks = [(e, r) for e, r in blocks if r is not None]
        if not blocks:
            return None
        if not self.sigma:
            raise ValueError("an effect with a prior needs the noise level (sigma)")
        rows = []
        for effect, factor in blocks:
            row = np.zeros((factor.shape[0], len(self.labels)))
            row[:, self.slice_of(effect.name)] = self.sigma * factor
            rows.append(row)
        return np.vstack(rows)
