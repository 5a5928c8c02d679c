"""One-step schemes of the transient, a_{n+1} = c_a du + a_hat (docs/transient.md, eq. 23).

- ``newmark``: average acceleration (beta = 1/4, gamma_N = 1/2), 2nd order, no
  numerical damping;
- ``generalized_alpha``: Chung-Hulbert with spectral radius rho_inf at dt -> inf
  (2nd order; rho_inf < 1 damps the unresolved stiff modes);
- ``backward_euler``: 1st order, L-stable.

The integrator that uses them is ``solvers.transient.stepping``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Scheme:
    """A one-step scheme: a_{n+1} = c_a du + a_hat, v_{n+1} = c_v du + v_hat.

    The equation of motion is enforced at t_{n+1-alpha_f} with the inertia at
    n+1-alpha_m (generalised-alpha); alpha_m = alpha_f = 0 is Newmark.
    """

    name: str
    alpha_m: float = 0.0
    alpha_f: float = 0.0
    beta: float = 0.25
    gamma: float = 0.5
    order: int = 2

    @property
    def error_constant(self) -> float:
        """C in the local displacement error C dt^2 (a_{n+1} - a_n), |beta - gamma/2 + 1/12|.

        Zienkiewicz-Xie's beta - 1/6 for Newmark; the algorithmic acceleration of
        generalised-alpha lags by (gamma - 1/2) dt, which shifts it by -(gamma - 1/2)/2.
        """
        return abs(self.beta - 0.5 * self.gamma + 1.0 / 12.0)

    def matrix_coefficients(self, dt: float) -> tuple[float, float]:
        """(c_a, c_v): d a_{n+1} / d du [1/s^2] and d v_{n+1} / d du [1/s]."""
        if self.name == "backward_euler":
            return 1.0 / dt**2, 1.0 / dt
        return 1.0 / (self.beta * dt**2), self.gamma / (self.beta * dt)

    def predictors(self, dt: float, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(a_hat, v_hat): a_{n+1} and v_{n+1} at du = 0."""
        if self.name == "backward_euler":
            return -v / dt, np.zeros_like(v)
        a_hat = -v / (self.beta * dt) - (0.5 / self.beta - 1.0) * a
        return a_hat, v + dt * ((1.0 - self.gamma) * a + self.gamma * a_hat)


def generalized_alpha(rho_inf: float = 0.0) -> Scheme:
    """Chung-Hulbert generalised-alpha with spectral radius rho_inf in [0, 1] at dt -> inf.

    rho_inf = 1 is Newmark's average acceleration; rho_inf = 0 (the default and
    ``SCHEMES["generalized_alpha"]``) annihilates unresolved modes.
    """
    if not 0.0 <= rho_inf <= 1.0:
        raise ValueError(f"rho_inf must lie in [0, 1], got {rho_inf}")
    alpha_m = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    alpha_f = rho_inf / (rho_inf + 1.0)
    gamma = 0.5 - alpha_m + alpha_f
    return Scheme(
        "generalized_alpha", alpha_m, alpha_f, 0.25 * (1.0 - alpha_m + alpha_f) ** 2, gamma
    )


SCHEMES = {
    "newmark": Scheme("newmark"),
    "generalized_alpha": generalized_alpha(0.0),
    "backward_euler": Scheme("backward_euler", order=1),
}
"""The schemes by name; pass a ``Scheme`` for other parameters."""
