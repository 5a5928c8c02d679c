"""What every inverse method returns, in one shape, so that methods can be compared."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class InverseResult:
    """The outcome of one inverse solve.

    Attributes
    ----------
    method : str
        "simultaneous", "nested" or "paper".
    names : tuple of str
        Estimated parameters.
    x : numpy.ndarray
        Estimates in natural units.
    cost : float
        1/2 sum of squared weighted residuals [mm^2].
    states : list of numpy.ndarray
        Equilibrium state s of every load case at the estimate.
    success : bool
        The method's own convergence verdict.
    status : str
        The method's status text.
    iterations : int
        Optimiser iterations.
    forward_solves : int
        Equilibrium solves (nested) or 0 (simultaneous: equilibrium is a constraint).
    build_time_s, solve_time_s : float
        Wall time to build the method's functions and to solve [s].
    """

    method: str
    names: tuple[str, ...]
    x: np.ndarray
    cost: float
    states: list[np.ndarray]
    success: bool
    status: str
    iterations: int
    forward_solves: int
    build_time_s: float
    solve_time_s: float
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        """Estimates by name."""
        return dict(zip(self.names, map(float, self.x)))
