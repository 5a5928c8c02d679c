"""The estimated parameters: names, start values, bounds and the internal coordinate z
(log x for the positive ones, x / scale for those that may be 0; docs/inverse.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.model import PARAMETERS
from symbolic.skin_slab import LOG_EXTRA

DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "mu": (1e-8, 1.0),
    "gamma": (1e-3, 1e4),
    "alpha_u": (1e-2, 1e2),
    "alpha_v": (1e-2, 1e2),
    "alpha_w": (1e-2, 1e2),
    "beta": (0.0, 10.0),
    "k0": (0.0, 1e3),
    "E": (1e-2, 1e5),
    "nu": (0.0, 0.49),
    "k1": (0.0, 1e4),
    "k2": (1e-2, 1e4),
    "kf1": (0.0, 1e4),
    "kf2": (1e-2, 1e4),
    "fibre_angle": (-90.0, 90.0),
}
"""Default bounds [natural units]; alpha spans four decades around the paper's values."""


LOG_PARAMETERS = frozenset({"mu", "gamma", "alpha_u", "alpha_v", "alpha_w", "E", "k2", "kf2"})


DYNAMIC_ONLY = frozenset({"mu", "gamma"})
"""Parameters that drop out of the steady state (eq. 22)."""


@dataclass(frozen=True)
class ParameterSpace:
    """Names, start values and bounds of the estimated parameters, and their scaling.

    Parameters
    ----------
    names : tuple of str
        Estimated parameters, from ``symbolic.model.PARAMETERS``.
    start, lower, upper : numpy.ndarray
        Start values and bounds in natural units.
    """

    names: tuple[str, ...]
    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def create(cls, names, start=None, bounds=None) -> ParameterSpace:
        """Defaults: the paper's start values and ``DEFAULT_BOUNDS``."""
        names = tuple(names)
        if not names:
            raise ValueError("choose at least one parameter to estimate, e.g. alpha_u")
        unknown = [n for n in names if n not in PARAMETERS]
        if unknown or len(set(names)) != len(names):
            raise ValueError(f"parameters must be distinct names from {list(PARAMETERS)}")
        start = {**{n: PARAMETERS[n].default for n in names}, **(start or {})}
        bounds = {**DEFAULT_BOUNDS, **(bounds or {})}
        x0 = np.array([float(start[n]) for n in names])
        lower = np.array([float(bounds[n][0]) for n in names])
        upper = np.array([float(bounds[n][1]) for n in names])
        for name, lo, hi, value in zip(names, lower, upper, x0):
            if not lo < hi:
                raise ValueError(f"bounds of {name} must satisfy lower < upper, got [{lo}, {hi}]")
            if name in LOG_PARAMETERS and lo <= 0:
                raise ValueError(
                    f"lower bound of {name} must be > 0 (it is estimated in log space)"
                )
            if not lo <= value <= hi:
                raise ValueError(f"start value of {name} = {value} lies outside [{lo}, {hi}]")
        return cls(names, x0, lower, upper)

    @property
    def log_scaled(self) -> np.ndarray:
        """True where the internal coordinate is log(x)."""
        return np.array([n in LOG_PARAMETERS for n in self.names])

    @property
    def linear_scale(self) -> np.ndarray:
        """Scale of the linear coordinates z = x / scale (the upper bound)."""
        return np.where(self.log_scaled, 1.0, np.maximum(np.abs(self.upper), 1e-12))

    def to_internal(self, x: np.ndarray) -> np.ndarray:
        """z from x."""
        x = np.asarray(x, dtype=float)
        return np.where(self.log_scaled, np.log(np.maximum(x, 1e-300)), x / self.linear_scale)

    def to_natural(self, z):
        """x from z; works on numbers and on CasADi expressions."""
        import casadi as ca

        if isinstance(z, ca.MX | ca.SX):
            parts = [
                ca.exp(z[i]) if log else z[i] * scale
                for i, (log, scale) in enumerate(zip(self.log_scaled, self.linear_scale))
            ]
            return ca.vertcat(*parts)
        z = np.asarray(z, dtype=float)
        return np.where(self.log_scaled, np.exp(z), z * self.linear_scale)

    def natural_derivative(self, z: np.ndarray) -> np.ndarray:
        """dx/dz, elementwise."""
        return np.where(self.log_scaled, np.exp(z), self.linear_scale)

    def internal_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on z."""
        return self.to_internal(self.lower), self.to_internal(self.upper)


class SkinParameterSpace(ParameterSpace):
    """``ParameterSpace`` that also knows ``symbolic.skin_slab``'s extra parameters (some
    estimated in log space); start values and bounds must all be given."""

    @classmethod
    def build(cls, names, start: dict, bounds: dict) -> SkinParameterSpace:
        """Names with start values and (lower, upper) bounds in natural units."""
        names = tuple(names)
        missing = [n for n in names if n not in start or n not in bounds]
        if missing:
            raise ValueError(f"give a start value and bounds for {missing}")
        x0 = np.array([float(start[n]) for n in names])
        lower = np.array([float(bounds[n][0]) for n in names])
        upper = np.array([float(bounds[n][1]) for n in names])
        if np.any(lower >= upper) or np.any(x0 < lower) or np.any(x0 > upper):
            raise ValueError(f"start values must lie within lower < upper bounds for {names}")
        return cls(names, x0, lower, upper)

    @property
    def log_scaled(self) -> np.ndarray:
        return np.array([n in LOG_PARAMETERS or n in LOG_EXTRA for n in self.names])
