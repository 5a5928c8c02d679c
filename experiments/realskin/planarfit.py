"""The least-squares fit of the planar extensometer models (``experiments.realskin.planar``).

One trust-region fit on z (ln p where a parameter is positive, p itself for nu) with the
exact Jacobian from direct sensitivities; a parameter set without equilibrium gives NaN
residuals, so scipy's trust region shrinks. Used by the authors' reproduction
(``reproduce``) and by the stiffening study (``stiffening``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from experiments.realskin.planar import EquilibriumFailed, Solution

NU_BOUNDS = (-0.9, 0.499)
"""Bounds of Poisson's ratio in every planar fit (2D: nu > -1, below incompressibility)."""


@dataclass
class Fit:
    """A fitted (E, nu) with its cost and errors."""

    x: np.ndarray
    measures: dict
    solution: Solution
    evaluations: int
    seconds: float
    success: bool
    message: str


def least_squares_fit(
    solve_at,
    problem,
    start,
    log,
    measures,
    failures,
    ftol: float,
    max_evaluations: int,
    upper: dict | None = None,
    x_scale="jac",
) -> Fit:
    """Trust-region least squares of ``problem.residuals`` on z (ln p where ``log``, p
    elsewhere; nu, the second entry, within ``NU_BOUNDS``) with the exact Jacobian.

    ``solve_at(p, previous)`` solves every frame (``previous``: the last solution that
    had an equilibrium, a continuation start); a parameter set where it raises one of
    ``failures`` has no equilibrium and gives NaN residuals, so the trust region shrinks.
    ``measures(solution)`` gives the fit's record. ``upper`` caps entries of p by index
    (e.g. {3: k2_max}); ``x_scale`` is scipy's. Raises ``EquilibriumFailed`` when the
    start has no equilibrium.
    """
    began = time.perf_counter()
    log = np.asarray(log, dtype=bool)
    cache: dict = {"z": None, "solution": None, "good": None}

    def to_p(z):
        return np.where(log, np.exp(np.where(log, z, 0.0)), z)

    def solve(z) -> Solution | None:
        if cache["z"] is None or not np.array_equal(cache["z"], z):
            try:
                solution = solve_at(to_p(z), cache["good"])
            except failures:
                solution = None
            cache["z"], cache["solution"] = np.array(z), solution
            cache["good"] = solution or cache["good"]
        return cache["solution"]

    def residuals(z):
        solution = solve(z)
        if solution is None:
            return np.full(len(problem.residuals(cache["good"])), np.nan)
        return problem.residuals(solution)

    def jacobian(z):
        return problem.jacobian(solve(z)) * np.where(log, to_p(z), 1.0)  # dp/dz

    start = np.asarray(start, dtype=float)
    z0 = np.where(log, np.log(np.where(log, start, 1.0)), start)
    if solve(z0) is None:
        raise EquilibriumFailed(f"no equilibrium at the start values {tuple(start)}")
    low, high = np.full(len(z0), -np.inf), np.full(len(z0), np.inf)
    low[1], high[1] = NU_BOUNDS
    for index, bound in (upper or {}).items():
        high[index] = np.log(bound) if log[index] else bound
    result = least_squares(
        residuals, z0, jac=jacobian, bounds=(low, high), method="trf", x_scale=x_scale,
        xtol=1e-8, ftol=ftol, gtol=1e-10, max_nfev=max_evaluations,
    )  # fmt: skip
    solution = solve(result.x)
    return Fit(
        to_p(result.x), measures(solution), solution, int(result.nfev),
        time.perf_counter() - began, bool(result.status > 0), str(result.message),
    )  # fmt: skip
