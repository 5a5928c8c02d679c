"""Modal analysis of the linear model and the damping that settles fastest
(docs/transient.md, eq. 22).

On the free control points the linear equation of motion (22) is, per component,

    M_ff B'' + D_ff B' + K_ff (B - B0) = F_B,    M = mu M_1,  D = gamma D_1,

and M_1 = D_1 = integral J^T J (eq. 13, 16): the damping is mass proportional,
D = c M with c = gamma / mu [1/s]. The generalised eigenproblem

    K_ff phi_i = omega_i^2 M_ff phi_i,       phi_i^T M_ff phi_j = delta_ij,

therefore decouples (22) into q_i'' + c q_i' + omega_i^2 q_i = phi_i^T F_B with
damping ratios zeta_i = gamma / (2 mu omega_i). The three components share M_ff,
D_ff and K_ff, so one n_free x n_free block is enough.

Every underdamped mode decays at the same rate c / 2; an overdamped mode at its slow
root c / 2 - sqrt(c^2 / 4 - omega_i^2) < c / 2. The asymptotic decay rate of the
whole response is therefore largest, omega_1, at critical damping of the lowest
mode, gamma_c = 2 mu omega_1. The 1 % settling time of the probe, computed here from
the exact modal step response, is what is minimised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.optimize as so

from symbolic.model import TissueModel

SETTLING_BAND = 0.01
"""Settled: the distance to the final displacement stays below 1 % of it."""


@dataclass(frozen=True)
class Modes:
    """Eigenpairs of K_ff phi = omega^2 M_ff phi for one displacement component.

    Attributes
    ----------
    omega : numpy.ndarray
        Undamped natural frequencies omega_i, ascending, (m,) [rad/s].
    shapes : numpy.ndarray
        Mode shapes phi_i as columns, M_ff-orthonormal, (n_free, m).
    mu : float
        Mass density of M = mu M_1 [t].
    """

    omega: np.ndarray
    shapes: np.ndarray
    mu: float

    def damping_ratios(self, gamma: float) -> np.ndarray:
        """zeta_i = gamma / (2 mu omega_i) for D = gamma D_1 (eq. 16)."""
        return gamma / (2.0 * self.mu * self.omega)

    @property
    def critical_gamma(self) -> float:
        """gamma_c = 2 mu omega_1 [N s/mm]: the lowest mode critically damped."""
        return float(2.0 * self.mu * self.omega[0])


def modal_basis(model: TissueModel, overrides: dict[str, float] | None = None) -> Modes:
    """The modes of the linear model (K0 of eq. 18, the tangent at rest when k0 != 0).

    Raises
    ------
    ValueError
        When D_1 is not proportional to M_1 (mu and gamma with different spatial
        fields), so that the damping does not decouple in the modes.
    """
    unit_mass = model.free_block(model.mass_matrix({"mu": 1.0})).toarray()
    unit_damping = model.free_block(model.damping_matrix({"gamma": 1.0})).toarray()
    if np.abs(unit_damping - unit_mass).max() > 1e-12 * np.abs(unit_mass).max():
        raise ValueError(
            "modal damping needs D_1 = M_1 (mass-proportional damping); the model has "
            "different spatial fields for mu and gamma"
        )
    values = model.values(overrides)
    stiffness = model.free_block(model.stiffness_matrix(overrides)).toarray()
    eigenvalues, shapes = sla.eigh(stiffness, values["mu"] * unit_mass)
    if eigenvalues[0] <= 0:
        raise ValueError("K_ff is singular on the free points: fix more control points")
    return Modes(np.sqrt(eigenvalues), shapes, values["mu"])


def unit_step_response(omega: np.ndarray, rate: float, times: np.ndarray) -> np.ndarray:
    """r_i(t) - 1 of q'' + c q' + omega_i^2 q = omega_i^2, q(0) = q'(0) = 0.

    Parameters
    ----------
    omega : numpy.ndarray
        omega_i, (m,) [rad/s].
    rate : float
        c = gamma / mu [1/s].
    times : numpy.ndarray
        t >= 0, (k,) [s].

    Returns
    -------
    numpy.ndarray
        (k, m): -exp(-c t / 2) (h(s t) + (c / 2) t k(s t)) with s = sqrt|c^2/4 - omega^2|,
        h = cosh, k = sinh(x)/x when overdamped, cos and sin(x)/x when underdamped;
        far into the overdamped regime the equivalent two-exponential form is used.
    """
    t = np.asarray(times, dtype=float)[:, None]
    half = 0.5 * rate
    disc = half**2 - omega[None, :] ** 2
    s = np.sqrt(np.abs(disc))
    x = s * t
    over = disc >= 0
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        near = np.where(over, np.cosh(np.minimum(x, 30.0)), np.cos(x))
        ratio = np.where(
            over, np.sinh(np.minimum(x, 30.0)) / np.maximum(x, 1e-300), np.sinc(x / np.pi)
        )
        ratio = np.where(x < 1e-8, 1.0, ratio)
        response = -np.exp(-half * t) * (near + half * t * ratio)
        slow = -(omega[None, :] ** 2) / (half + s)  # lambda_1, without cancellation
        fast = -half - s  # lambda_2
        far = -(fast * np.exp(slow * t) - slow * np.exp(fast * t)) / (fast - slow)
    return np.where(over & (x >= 30.0), far, response)


def _envelope(omega: np.ndarray, rate: float, t: float) -> np.ndarray:
    """Upper bounds of |r_i(t) - 1| at time t (decreasing for t >= 1 / min rho_i).

    (1 + c t / 2) exp(-rho_i t) with rho_i the slowest decay rate of mode i (cosh x
    and sinh(x)/x are below e^x); for overdamped modes also the two-exponential bound
    (|lambda_2| e^(lambda_1 t) + |lambda_1| e^(lambda_2 t)) / (2 s), whichever is smaller.
    """
    half = 0.5 * rate
    disc = half**2 - omega**2
    s = np.sqrt(np.abs(disc))
    slow = np.where(disc >= 0, omega**2 / (half + s), half)
    bound = (1.0 + half * t) * np.exp(-slow * t)
    with np.errstate(divide="ignore", invalid="ignore"):
        pair = ((half + s) * np.exp(-slow * t) + slow * np.exp(-(half + s) * t)) / (2 * s)
    return np.where((disc > 0) & np.isfinite(pair), np.minimum(bound, pair), bound)


def _slowest_rate(omega: np.ndarray, rate: float) -> float:
    """min_i rho_i, the slowest modal decay rate [1/s]."""
    half = 0.5 * rate
    disc = half**2 - omega**2
    return float(np.min(np.where(disc >= 0, omega**2 / (half + np.sqrt(np.abs(disc))), half)))


@dataclass(frozen=True)
class StepResponse:
    """Modal step response of observed points (from rest, constant load from t = 0).

    Attributes
    ----------
    modes : Modes
        The modal basis.
    weights : numpy.ndarray
        (m, p, 3): the static displacement of observed point j, component c, carried
        by mode i, (O phi_i)_j (phi_i^T F_c) / omega_i^2 [mm].
    """

    modes: Modes
    weights: np.ndarray

    @classmethod
    def build(cls, modes: Modes, force: np.ndarray, observation) -> StepResponse:
        """From F_B (n_free, 3) [N] and an observation matrix O (p, n_free)."""
        observed = np.asarray(observation @ modes.shapes)  # (p, m)
        static = (modes.shapes.T @ np.asarray(force)) / modes.omega[:, None] ** 2  # (m, 3)
        return cls(modes, observed.T[:, :, None] * static[:, None, :])

    @property
    def final(self) -> np.ndarray:
        """Steady displacement of the observed points, (p, 3) [mm]."""
        return self.weights.sum(axis=0)

    def displacement(self, times: np.ndarray, gamma: float) -> np.ndarray:
        """Displacement of the observed points at ``times`` [s], (k, p, 3) [mm]."""
        rate = gamma / self.modes.mu
        decay = unit_step_response(self.modes.omega, rate, times)
        return self.final[None] + np.einsum("ki,ipc->kpc", decay, self.weights)

    def settling_time(self, gamma: float, band: float = SETTLING_BAND) -> float:
        """First time after which |u(t) - u_inf| <= band |u_inf| for good [s].

        The horizon comes from the envelope bound, the search grid resolves every
        oscillation that carries weight, and the last crossing is refined by brentq.
        """
        rate = gamma / self.modes.mu
        omega = self.modes.omega
        size = np.linalg.norm(self.weights.reshape(len(omega), -1), axis=1)
        limit = band * np.linalg.norm(self.final)
        keep = size > 1e-6 * limit
        omega, weights, size = omega[keep], self.weights[keep], size[keep]
        horizon = 1.0 / _slowest_rate(omega, rate)
        while size @ _envelope(omega, rate, horizon) > limit:
            horizon *= 2.0
        under = omega[omega > rate / 2]
        resolution = horizon / 4000.0
        if under.size:
            period = 2 * np.pi / np.sqrt(under.max() ** 2 - rate**2 / 4)
            resolution = min(resolution, period / 16.0)
        times = np.linspace(0.0, horizon, int(np.ceil(horizon / resolution)) + 1)

        def excess(t):
            decay = unit_step_response(omega, rate, np.atleast_1d(t))
            error = np.einsum("ki,ipc->kpc", decay, weights)
            return np.linalg.norm(error.reshape(len(decay), -1), axis=1) - limit

        outside = np.flatnonzero(excess(times) > 0)
        if outside.size == 0:
            return 0.0
        last = outside[-1]
        if last + 1 == times.size:
            return float(times[-1])
        return float(so.brentq(lambda t: excess(t)[0], times[last], times[last + 1], xtol=1e-12))


@dataclass(frozen=True)
class DampingStudy:
    """The damping gamma that settles the probe fastest under a step load.

    Attributes
    ----------
    gamma : float
        Optimal gamma [N s/mm].
    settling_time : float
        Its 1 % settling time [s].
    critical_gamma : float
        2 mu omega_1, critical damping of the lowest mode [N s/mm].
    gammas, settling_times : numpy.ndarray
        The scan over gamma behind the bounded search [N s/mm], [s].
    """

    gamma: float
    settling_time: float
    critical_gamma: float
    gammas: np.ndarray
    settling_times: np.ndarray


def probe_observation(model: TissueModel, uv=(0.5, 0.5)) -> np.ndarray:
    """O, the row J(p) on the free points of the skin point p = (u, v, 1), (1, n_free)."""
    params = model.volume.outer_params(np.atleast_2d(np.asarray(uv, dtype=float)))
    return model.volume.collocation(params)[:, model.free].toarray()


def optimal_damping(
    model: TissueModel,
    force: np.ndarray,
    observation=None,
    overrides: dict[str, float] | None = None,
    bounds: tuple[float, float] = (0.05, 20.0),
    samples: int = 61,
) -> DampingStudy:
    """Minimise the probe's 1 % settling time over gamma (docs/transient.md, eq. 16, 22).

    Parameters
    ----------
    model : TissueModel
        The model; its linear stiffness K0 is used.
    force : numpy.ndarray
        F_B on the free points, (n_free, 3) [N], applied as a step at t = 0.
    observation : array_like, optional
        O (p, n_free); default the skin centre (``probe_observation``).
    overrides : dict, optional
        Parameter values (mu, alpha, ...) over the model's.
    bounds : tuple of float
        Search interval as multiples of the critical gamma 2 mu omega_1.
    samples : int
        Log-spaced scan points; the settling time jumps where an overshoot leaves the
        1 % band, so a scan brackets the global minimum before ``minimize_scalar``
        (bounded) refines it between the neighbours of the best sample.
    """
    modes = modal_basis(model, overrides)
    observation = probe_observation(model) if observation is None else observation
    response = StepResponse.build(modes, force, observation)
    critical = modes.critical_gamma
    gammas = critical * np.geomspace(bounds[0], bounds[1], samples)
    times = np.array([response.settling_time(g) for g in gammas])
    best = int(np.argmin(times))
    low, high = gammas[max(best - 1, 0)], gammas[min(best + 1, samples - 1)]
    found = so.minimize_scalar(
        response.settling_time, bounds=(low, high), method="bounded", options={"xatol": 1e-6 * low}
    )
    gamma, settled = (
        (found.x, found.fun) if found.fun <= times[best] else (gammas[best], times[best])
    )
    return DampingStudy(float(gamma), float(settled), critical, gammas, times)
