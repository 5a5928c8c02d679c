"""The information of every candidate press, summed into the information of a design.

A press k adds its raw marker residual r_k (the markers it leaves visible) to the data.
Its columns, at the base fit x and theta = 0, are

    C_k = [ d r_k / d x  |  d r_k / d theta_e,  s_k,e  for every effect e ]

with the effect's signal solved at its magnitude, s_k,e = r_k(x, theta_e,1) - r_k(x, 0)
(eq. D2; one equilibrium per press and effect). The rest markers are shared by all
presses, so the residual covariance of a design D is sigma^2 (I + P P^T)
(``solvers.inverse.noise``), and the whitened Gram matrix of its columns is, by Woodbury,

    M(D) = sum_k C_k^T C_k - H^T (I + N)^-1 H,   H = sum_k P_k^T C_k,
                                                 N = sum_k diag(P_k^T P_k)          (D5)

(P_k picks the rest-marker coordinate of every residual of press k; N is diagonal:
how many presses see each rest coordinate). Every figure of a design (eqs. D1-D3) is
a function of M(D): the Fisher information is M_xx / sigma^2, the non-centrality the
Schur complement of eq. (D2). So a press is summarised once by three small arrays
(C_k^T C_k, P_k^T C_k, its counts), and a design of any size, with repeats, costs a
sum and one product. A press repeated sees the same rest markers again: (D5) counts
the shared rest noise, so two identical presses give less than twice the information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.design import adjoint
from solvers.design.candidates import Press
from solvers.design.pressloads import press_loads
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import EffectFit
from solvers.diagnosis.stats import extended_linearisation
from solvers.inverse.problem import InverseProblem, observation_case
from symbolic.effects.base import Effect


@dataclass(frozen=True)
class Totals:
    """The sums of eq. (D5) over a design: sum C^T C, H and N."""

    gram: np.ndarray
    shared: np.ndarray
    counts: np.ndarray

    def __add__(self, other: Totals) -> Totals:
        return Totals(
            self.gram + other.gram, self.shared + other.shared, self.counts + other.counts
        )

    def __sub__(self, other: Totals) -> Totals:
        return Totals(
            self.gram - other.gram, self.shared - other.shared, self.counts - other.counts
        )

    def matrix(self) -> np.ndarray:
        """M of eq. (D5) [mm^2 per unit of the columns]."""
        return self.gram - self.shared.T @ (self.shared / (1.0 + self.counts)[:, None])


@dataclass(frozen=True)
class Layout:
    """Where the columns of M sit: the estimated base parameters, then per effect its
    theta block and its signal.

    Attributes
    ----------
    names : tuple of str
        The estimated base parameters x.
    x : numpy.ndarray
        Their values at the fit (natural units).
    effects : tuple of (Effect, float or numpy.ndarray)
        Each effect with its magnitude (or its parameters theta).
    blocks : tuple of (numpy.ndarray, int)
        Per effect, the columns of theta and the column of the signal.
    """

    names: tuple[str, ...]
    x: np.ndarray
    effects: tuple
    blocks: tuple

    @property
    def nuisance(self) -> np.ndarray:
        """The columns of x."""
        return np.arange(len(self.names))


class InformationPool:
    """Candidate presses with their information (eq. D5), judged at a base fit.

    Parameters
    ----------
    fit : EffectFit
        The loop's base fit (no effects): its model, x and noise whitening.
    marker_uv : numpy.ndarray
        (u, v) of every marker on the model's rest skin, (m, 2).
    effects : sequence of (Effect, float or numpy.ndarray)
        The effects whose power is wanted, each with its magnitude, or with its
        parameters theta (a fitted effect; global effects only: one theta for all
        presses).
    """

    def __init__(self, fit: EffectFit, marker_uv: np.ndarray, effects=()):
        if fit.problem.effects:
            raise ValueError("a design is judged at a base fit (no effects)")
        for effect, _ in effects:
            if effect.per_case:
                raise ValueError(
                    f"{effect.name} has one theta per capture; no choice of press changes "
                    "what a capture shows of it"
                )
        self.fit = fit
        self.model = fit.problem.model
        self.marker_uv = np.asarray(marker_uv, dtype=float).reshape(-1, 2)
        self.n_markers = len(self.marker_uv)
        volume = self.model.volume
        self.rest = volume.collocation(volume.outer_params(self.marker_uv)) @ self.model.rest
        chosen = fit.estimated()
        base_names = list(fit.problem.names)
        names = tuple(n for n, keep in zip(base_names, chosen) if keep)
        blocks, start = [], len(names)
        for effect, _ in effects:
            blocks.append((np.arange(start, start + effect.dim), start + effect.dim))
            start += effect.dim + 1
        self.layout = Layout(names, fit.p[: len(base_names)][chosen], tuple(effects), tuple(blocks))
        self.width = start
        self.presses: list[Press] = []
        self.blocks: list[Totals] = []

    def add(self, presses: list[Press], seen: list[np.ndarray]) -> list[int]:
        """Compute the information of ``presses`` (each with the markers it sees, bool
        (m,)); returns their indices in the pool.

        Linear in the state (the linear path): one factorisation of K(x) for all presses
        (the fit's own), their states in one solve, their sensitivities by eq. (D9)
        (``solvers.design.adjoint``); per effect, one more factorisation where it adds
        state, and one at its magnitude where it changes K. Otherwise Newton per press.
        Pass all presses in one call: each call makes its own equilibria.
        """
        if not presses:
            return []
        loads = press_loads(presses, self.model.volume)
        base = self.fit.problem.base
        cases = []
        for load, mask in zip(loads, seen):
            observed = self.rest.copy()
            observed[~np.asarray(mask, dtype=bool)] = np.nan
            cases.append(observation_case(self.model, load, observed, self.marker_uv))
        problem = ExtendedProblem(
            InverseProblem(self.model, cases, base.space, base.noise_mm, base.rest_noise),
            loads,
            [],
            sigma=self.fit.problem.sigma,
        )
        x = self.fit.p[: len(self.fit.problem.names)]
        if problem.linear_state:  # the fit's factorisation of K(x) serves every press
            fitted = self.fit.state_jacobians
            if fitted and fitted[0] is not None:
                problem.cache["last_state_jacobian"] = fitted[0]
            r0, jac, states, factor = adjoint.evaluate(problem, x)
            factors = [factor] * len(states)
        else:
            r0, jac, states, factors = problem.evaluate_full(x)
        stacked = np.zeros((r0.size, self.width))  # C_k of every press, stacked
        stacked[:, self.layout.nuisance] = jac[:, self.fit.estimated()]
        for (effect, magnitude), (theta, signal) in zip(self.layout.effects, self.layout.blocks):
            derivative, solved = self._effect_columns(
                problem, x, effect, magnitude, states, factors
            )
            stacked[:, theta] = derivative
            stacked[:, signal] = solved - r0
        offsets = np.cumsum([0] + [3 * c.n_observations for c in cases])
        indices = []
        for k, (press, case) in enumerate(zip(presses, cases)):
            self.presses.append(press)
            block = stacked[offsets[k] : offsets[k + 1]]
            self.blocks.append(self._totals(case.marker_index, block))
            indices.append(len(self.presses) - 1)
        return indices

    @staticmethod
    def _effect_columns(problem, x, effect: Effect, magnitude: float, states, factors):
        """Stacked d r / d theta at theta = 0, and r at theta_1 (eq. D2), of every press."""
        extended = problem.with_effects(problem.effects + [effect])
        block = extended.slice_of(effect.name)
        if extended.linear_state:  # eq. (D9): the sensitivities from the shared rows
            p = np.concatenate([x, np.zeros(len(extended.labels) - len(x))])
            n_state = extended.extended.n_state
            starts = [np.concatenate([s, np.zeros(n_state - s.size)]) for s in states]
            same = all(n_state == s.size for s in states)
            factor = factors[0] if same else extended.stiffness_factor(p)
            columns = np.arange(block.start, block.stop)
            _, jacobian = adjoint.linearise(extended, p, np.column_stack(starts), factor, columns)
        else:
            extended, p, starts, jacobian = extended_linearisation(
                problem, x, states, factors, effect, candidate_only=True
            )
        value = np.asarray(magnitude, dtype=float)
        p[block] = value if value.ndim else effect.true_parameters(float(value), 1)
        if extended.linear_state:
            if same:  # K(theta_1) equal to K(x) entry by entry (a load, an observation
                # effect) reuses its factors (``ExtendedProblem.stiffness_factor``)
                extended.cache["last_state_jacobian"] = factor
            return jacobian[:, block], adjoint.residual(extended, p)
        return jacobian[:, block], extended.residual(p, starts)

    def _totals(self, marker_index: np.ndarray, block: np.ndarray) -> Totals:
        """C^T C, P^T C and the counts of one press (eq. D5)."""
        m, n = self.n_markers, len(marker_index)
        shared = np.zeros((3 * m, block.shape[1]))
        counts = np.zeros(3 * m)
        for c in range(3):
            shared[c * m + marker_index] = block[c * n : (c + 1) * n]
            counts[c * m + marker_index] = 1.0
        return Totals(block.T @ block, shared, counts)

    def empty(self) -> Totals:
        """The totals of no press."""
        m = self.n_markers
        return Totals(
            np.zeros((self.width, self.width)), np.zeros((3 * m, self.width)), np.zeros(3 * m)
        )

    def totals(self, design) -> Totals:
        """The totals of a design: pool indices, repeats allowed."""
        total = self.empty()
        for k in design:
            total = total + self.blocks[k]
        return total
