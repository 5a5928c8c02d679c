"""What a transient run returns, and the settling time of a sampled history.

The settling time is the first time after which |y(t) - y_end| <= 1 % |y_end| for
good, with the cubic Hermite interpolant between accepted steps (docs/transient.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from solvers.transient.modal import SETTLING_BAND


@dataclass
class TransientResult:
    """A transient run (docs/transient.md, eq. 22), from rest unless a start was given.

    Attributes
    ----------
    times : numpy.ndarray
        t_n of the accepted steps, (k,) [s].
    displacements, velocities : numpy.ndarray
        B_free - B0_free and B_free', (k, n_free, 3) [mm], [mm/s].
    probe : numpy.ndarray
        Displacement of the skin centre (u, v) = (0.5, 0.5), (k, 3) [mm].
    state : numpy.ndarray
        Final s = vec(B_free - B0_free) (the ``state_residual`` ordering).
    positions : numpy.ndarray
        Final B, (n, 3) [mm].
    steps, rejected, newton_iterations, jacobian_evaluations : int
        Work done.
    steady : bool
        Whether the steady-state rule was met before t_max.
    steady_time : float or None
        Time at which it was met [s].
    settling_time, probe_settling_time : float
        First time after which |u(t) - u_end| <= 1 % |u_end| for good, for all free
        control points and for the probe [s] (cubic Hermite between steps).
    static_residual, kinetic_ratio : float
        |f(u) - F| / |F| and sqrt(v^T M v / u^T f(u)) at the end.
    """

    times: np.ndarray
    displacements: np.ndarray
    velocities: np.ndarray
    probe: np.ndarray
    state: np.ndarray
    positions: np.ndarray
    steps: int
    rejected: int
    newton_iterations: int
    jacobian_evaluations: int
    steady: bool
    steady_time: float | None
    settling_time: float
    probe_settling_time: float
    static_residual: float
    kinetic_ratio: float
    method: str = ""

    def observe(self, observation) -> np.ndarray:
        """History of observed points O (p, n_free) @ displacement, (k, p, 3) [mm]."""
        return np.einsum("pn,knc->kpc", np.asarray(observation), self.displacements)


def settling_time(times, values, rates, band: float = SETTLING_BAND) -> float:
    """First t after which |y(t) - y_end| <= band |y_end| for good [s].

    ``values`` and ``rates`` are (k, m) samples of y and y'; between samples y is the
    cubic Hermite interpolant, and the last crossing is found by brentq.
    """
    values = np.asarray(values).reshape(len(times), -1)
    rates = np.asarray(rates).reshape(len(times), -1)
    final, limit = values[-1], band * np.linalg.norm(values[-1])
    outside = np.flatnonzero(np.linalg.norm(values - final, axis=1) > limit)
    if outside.size == 0:
        return float(times[0])
    last = int(outside[-1])
    t0, h = times[last], times[last + 1] - times[last]

    def excess(theta):
        p = [2 * theta**3 - 3 * theta**2 + 1, theta**3 - 2 * theta**2 + theta]
        p += [-2 * theta**3 + 3 * theta**2, theta**3 - theta**2]
        y = p[0] * values[last] + p[1] * h * rates[last]
        y = y + p[2] * values[last + 1] + p[3] * h * rates[last + 1]
        return np.linalg.norm(y - final) - limit

    return float(t0 + h * brentq(excess, 0.0, 1.0, xtol=1e-12))
