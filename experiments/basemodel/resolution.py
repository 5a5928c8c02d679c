"""Step 0's resolution check: the chosen continuum refitted, to first order, on finer
volumes until the data cannot see the change of its predicted markers
(docs/stepzero.md, "What it compares")."""

from __future__ import annotations

import math
import time

import numpy as np
from scipy import stats

from experiments.basemodel.family import Family, span_settings
from solvers.diagnosis.extended import ExtendedProblem

REFINEMENT = 1.5
"""Factor by which the resolution check divides the knot span along the skin."""

MAX_REFINEMENTS = 2
"""Most refinements the resolution check makes (the last one adopted unchecked)."""

MAX_CHECK_POINTS = 20000
"""Largest volume (control points) the resolution check refits on: 53 x 42 x 7 takes
about 20 s to build and factor once, the next step up 5x that (docs/stepzero.md)."""


def checked_resolution(dataset, family, trial, sigma, level, log):
    """The chosen continuum checked on finer volumes until the data cannot see the change
    of its predicted markers (``REFINEMENT``, at most ``MAX_REFINEMENTS`` refinements):
    the trial kept (its ``family`` at the kept resolution) and the checks' records.

    The refit on the finer volume is linearised: one Gauss-Newton step from the coarse
    estimate (one factorisation of the finer K; the two parameters move little, so the
    step is the refit to first order). A refinement the data can see is adopted and
    fitted in full.
    """
    limit = float(stats.chi2.isf(level, 1))
    records = []
    for _ in range(MAX_REFINEMENTS):
        begin = time.perf_counter()
        finer = Family(dataset, family.span / REFINEMENT, family.layers + 1, sigma, quiet)
        key = trial.surroundings
        settings = span_settings(dataset, key.margin_mm, key.support, finer.span, finer.layers)
        if math.prod(settings.grid) > MAX_CHECK_POINTS:
            grid = "x".join(map(str, settings.grid))
            records.append(
                {
                    "grid": list(trial.settings.grid),
                    "refined_grid": list(settings.grid),
                    "verdict": "not checked",
                    "reason": f"the check's volume {grid} "
                    f"exceeds {MAX_CHECK_POINTS} control points",
                }
            )
            log(f"resolution: {records[-1]['reason']}; not checked")
            break
        settings, problem = finer.problem(key)
        predicted, estimate = linearised_refit(problem, trial.fit.p)
        change = trial.fit.whitened - predicted
        distance = float(change @ change / sigma**2)
        converged = distance <= limit
        records.append(
            {
                "grid": list(trial.settings.grid),
                "refined_grid": list(settings.grid),
                "prediction_chi2": distance,
                "limit": limit,
                "parameters": dict(zip(("E", "nu"), map(float, trial.fit.p))),
                "refined_parameters": dict(zip(("E", "nu"), map(float, estimate))),
                "verdict": "converged" if converged else "refined",
                "seconds": time.perf_counter() - begin,
            }
        )
        log(
            f"resolution: {'x'.join(map(str, trial.settings.grid))} -> "
            f"{'x'.join(map(str, settings.grid))} moves the predicted markers by "
            f"chi2 {distance:.1f} (limit {limit:.1f}): {records[-1]['verdict']} "
            f"({records[-1]['seconds']:.1f} s)"
        )
        if converged:
            break
        trial, family = finer.trial_at(key, estimate), finer
        records[-1]["refined_chi2"] = trial.chi2
    return trial, records


def linearised_refit(problem: ExtendedProblem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The whitened residual and the estimate after one Gauss-Newton step from ``p``."""
    r, jacobian, _ = problem.evaluate(p)
    rho, slope = problem.whiten(r), problem.whiten(jacobian)
    step = np.linalg.lstsq(slope, -rho, rcond=None)[0]
    estimate = np.clip(p + step, problem.lower, problem.upper)
    return rho + slope @ (estimate - p), estimate


def quiet(*_) -> None:
    """A log that prints nothing."""
