"""The named parameters every model shares: defaults, units, meaning and their checks.

``PARAMETERS`` lists what the inverse can estimate (the paper's eq. 13, 16, 18 and 1;
the continua's E and nu, eq. C1; the exponential stiffening's k1 and k2, eq. C10; the
fibre family's kf1, kf2 and angle, eq. C13, all in docs/); ``check_parameters`` merges
values over the defaults and refuses unknown names and bad numbers with one line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ParameterInfo:
    """A named model parameter: default (the paper's start value), unit, meaning."""

    default: float
    unit: str
    meaning: str


PARAMETERS: dict[str, ParameterInfo] = {
    "mu": ParameterInfo(1e-4, "t", "mass density per unit parameter volume (eq. 13)"),
    "gamma": ParameterInfo(15.0, "N s/mm", "damping density per unit parameter volume (eq. 16)"),
    "alpha_u": ParameterInfo(0.5, "N/mm", "tension along u (eq. 18)"),
    "alpha_v": ParameterInfo(0.5, "N/mm", "tension along v (eq. 18)"),
    "alpha_w": ParameterInfo(0.5, "N/mm", "tension through the thickness, w (eq. 18)"),
    "beta": ParameterInfo(0.0, "N/mm", "rigidity, common factor of the six beta_ij (eq. 18)"),
    "k0": ParameterInfo(0.0, "1", "stiffening in s(eps) = 1 + k0 eps^2 (eq. 1)"),
    "E": ParameterInfo(10.0, "kPa", "Young's modulus of the linear-elastic model (eq. C1)"),
    "nu": ParameterInfo(0.45, "1", "Poisson's ratio of the linear-elastic model (eq. C1)"),
    "k1": ParameterInfo(0.0, "kPa", "strain stiffening of the exponential energy (eq. C10)"),
    "k2": ParameterInfo(10.0, "1", "exponent of the exponential energy (eq. C10)"),
    "kf1": ParameterInfo(0.0, "kPa", "stiffness of the fibre family (eq. C13)"),
    "kf2": ParameterInfo(10.0, "1", "exponent of the fibre family (eq. C13)"),
    "fibre_angle": ParameterInfo(0.0, "deg", "fibre direction from x in the x-y plane (eq. C13)"),
}
"""Every parameter the inverse can estimate, with the paper's start values."""
SIGNED = frozenset({"k0", "fibre_angle"})
"""Parameters that may be negative."""


def check_parameters(values: dict[str, float]) -> dict[str, float]:
    """Merge values over the defaults, rejecting unknown names and bad numbers."""
    unknown = set(values) - set(PARAMETERS)
    if unknown:
        raise ValueError(f"unknown parameters {sorted(unknown)}; known: {list(PARAMETERS)}")
    merged = {name: info.default for name, info in PARAMETERS.items()}
    merged.update({k: float(v) for k, v in values.items()})
    for name, value in merged.items():
        if not np.isfinite(value):
            raise ValueError(f"parameter {name} must be finite, got {value}")
        if name not in SIGNED and value < 0:
            raise ValueError(f"parameter {name} must be >= 0, got {value}")
    if merged["nu"] >= 0.5:
        raise ValueError(f"Poisson's ratio nu must be < 0.5, got {merged['nu']}")
    return merged
