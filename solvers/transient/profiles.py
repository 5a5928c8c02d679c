"""Loads in time, F_B(t) = profile(t) F (docs/transient.md, "Loads"): step, ramp, any callable."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np


def _one(t):
    return 1.0


@dataclass(frozen=True)
class Load:
    """F_B(t) = profile(t) F on the free points (eq. 20), F of shape (n_free, 3) [N].

    ``profile`` maps t [s] to a scale; written with casadi operations (``ca.fmin``,
    ``ca.if_else``) it also works symbolically, as ``integrate_casadi`` needs.
    """

    force: np.ndarray
    profile: Callable = _one

    def __call__(self, t: float) -> np.ndarray:
        return float(self.profile(t)) * np.asarray(self.force, dtype=float)


@dataclass(frozen=True)
class _Ramp:
    duration: float

    def __call__(self, t):
        return ca.fmin(t / self.duration, 1.0)


def step_load(force: np.ndarray) -> Load:
    """F applied in full at t = 0 [N]."""
    return Load(np.asarray(force, dtype=float))


def ramp_load(force: np.ndarray, duration: float) -> Load:
    """F rising linearly from 0 to F over ``duration`` [s], then held."""
    if duration <= 0:
        raise ValueError(f"ramp duration must be positive, got {duration}")
    return Load(np.asarray(force, dtype=float), _Ramp(float(duration)))


def as_load(load) -> Callable[[float], np.ndarray]:
    """An array is a step load; a Load or any callable t -> (n_free, 3) array is used as is."""
    return step_load(load) if isinstance(load, np.ndarray) else load
