"""Discretisation or physics? The loop's final model refitted on a refined volume.

A residual the loop leaves (or explains with an effect) can come from the spline's
resolution rather than from missing physics: a coarse volume cannot follow a probe's
near field. ``refinement_check`` refits the final model (base model and the effects
selected) on a nested refinement of the volume (``refined_grid``: twice the knot
spans along u and v, one more layer and degree up to 2 through the thickness, the
geometry unchanged, ``VolumeSpline.refined``) from the final estimate. The parameters
do not change in number, so a drop of chi^2 is the discretisation's share of the
residual:

- ``discretisation``: chi^2 changes by more than the 1-dof chi^2 quantile at the
  loop's level, or a shared parameter moves by more than one standard error; refine
  (``--grid`` and ``--degrees``) before reading the effects as physics;
- ``converged``: neither; the residual and the estimates are the physics'.

Before that, inside the loop: on a volume whose resolution step 0 did not check (a
``--grid`` given), an effect the loop would accept must still predict left-out data
better than chance on the refined volume (``Survival``, the loop's ``refine``): an
effect that stands in for the coarse volume's discretisation error (a softer base for a
grid too stiff to follow the probe) loses its gain there, one that is physics keeps it.

The check applies to the continuum energies, discretisations of a continuum whose
parameters do not depend on the grid. For the paper's energy the grid is part of the
model (its alpha, fitted on one grid, differ on another: on the phantom, 34 standard
errors from 9x9x2 to 15x15x3), so it is not checked there.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import stats

MAX_REFINED_POINTS = 1600
"""Largest refined grid checked (control points): bigger ones cost more than the loop."""


def refined_grid(grid, degrees) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The nested refinement of a grid: n' = 2 (n - p) + p along u, v; L + 1 layers."""
    (m, n, layers), (p, q, r) = grid, degrees
    depth = min(2, layers)
    return (2 * (m - p) + p, 2 * (n - q) + q, layers + 1), (p, q, max(r, depth))


def refinement_check(diagnosis, dataset, settings) -> dict:
    """Refit the final model on the refined volume; the record of diagnosis.json.

    Parameters
    ----------
    diagnosis : Diagnosis
        The loop's result (``solvers.diagnosis.loop``).
    dataset : Dataset
        The data it ran on.
    settings : FitSettings
        The base model's settings (grid None follows the data).

    The chi^2 limit is the 1-dof quantile at the loop's level (``diagnosis.level``).
    """
    from experiments.problem.fitting import build_problem, dataset_loads, model_grid
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit

    grid, degrees = model_grid(dataset, settings)
    fine_grid, fine_degrees = refined_grid(grid, degrees)
    record = {
        "grid": list(grid),
        "degrees": list(degrees),
        "refined_grid": list(fine_grid),
        "refined_degrees": list(fine_degrees),
    }
    if settings.energy == "dnurbs":
        reason = "the paper's energy is defined on its grid (alpha depend on it)"
        return {**record, "verdict": "not checked", "reason": reason}
    if int(np.prod(fine_grid)) > MAX_REFINED_POINTS:
        return {**record, "verdict": "not checked", "reason": "refined grid too large"}
    final = diagnosis.steps[-1]
    base = build_problem(dataset, replace(settings, grid=fine_grid, degrees=fine_degrees))
    effects = list(diagnosis.steps[-1].fit.problem.effects)
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), effects)
    refit = fit(problem, np.clip(final.fit.p, problem.lower, problem.upper))
    sigma = diagnosis.noise_mm
    chi2 = float(np.sum(final.fit.whitened**2) / sigma**2)
    fine_chi2 = float(np.sum(refit.whitened**2) / sigma**2)
    errors = final.fit.standard_errors(sigma)
    shared = len(problem.names)
    shifts = np.abs(refit.p[:shared] - final.fit.p[:shared]) / errors[:shared]
    drop = chi2 - fine_chi2
    limit = float(stats.chi2.isf(diagnosis.level, 1))
    moved = bool(np.any(shifts > 1.0))
    verdict = "discretisation" if abs(drop) > limit or moved else "converged"
    return {
        **record,
        "verdict": verdict,
        "rms_mm": final.fit.rms()[0],
        "refined_rms_mm": refit.rms()[0],
        "chi2_drop": drop,
        "chi2_limit": limit,
        "parameter_shift_in_std": dict(zip(problem.names, map(float, shifts))),
        "refined_parameters": dict(zip(problem.labels, map(float, refit.p))),
        "success": bool(refit.success),
    }


def summary(record: dict) -> str:
    """One line for logs and reports."""
    if record["verdict"] == "not checked":
        return f"refinement not checked ({record['reason']})"
    shifts = ", ".join(f"{k} {v:.1f}" for k, v in record["parameter_shift_in_std"].items())
    grid = "x".join(map(str, record["refined_grid"]))
    return (
        f"refined to {grid}: rms {record['rms_mm'] * 1e3:.1f} -> "
        f"{record['refined_rms_mm'] * 1e3:.1f} um, chi2 drop {record['chi2_drop']:.1f} "
        f"(limit {record['chi2_limit']:.1f}), shifts in std: {shifts} -> {record['verdict']}"
    )


class Survival:
    """The loop's ``refine``: a fit's effects refitted on the refined volume
    (``refined_grid``) from its estimate, each effect set once.

    Parameters
    ----------
    dataset : Dataset
        The data.
    settings : FitSettings
        The base model's settings (a continuum energy, the grid given).
    """

    def __init__(self, dataset, settings) -> None:
        from experiments.problem.fitting import build_problem, dataset_loads, model_grid

        fine_grid, fine_degrees = refined_grid(*model_grid(dataset, settings))
        self.grid = fine_grid
        self.base = build_problem(dataset, replace(settings, grid=fine_grid, degrees=fine_degrees))
        self.loads = dataset_loads(dataset, self.base.model.volume)
        self.fits: dict = {}

    @classmethod
    def applies(cls, dataset, settings) -> bool:
        """A continuum energy (the paper's is defined on its grid) whose refined volume is
        within ``MAX_REFINED_POINTS``."""
        from experiments.problem.fitting import model_grid

        if settings.energy == "dnurbs":
            return False
        fine_grid, _ = refined_grid(*model_grid(dataset, settings))
        return int(np.prod(fine_grid)) <= MAX_REFINED_POINTS

    def __call__(self, coarse):
        """``coarse``'s model (base and effects) fitted on the refined volume, from its
        estimate (an ``EffectFit``)."""
        from solvers.diagnosis.extended import ExtendedProblem
        from solvers.diagnosis.fit import STATISTICAL_TOLERANCE, fit

        names = tuple(e.name for e in coarse.problem.effects)
        if names not in self.fits:
            problem = ExtendedProblem(self.base, self.loads, list(coarse.problem.effects))
            problem.sigma = coarse.problem.sigma
            start = np.clip(coarse.p, problem.lower, problem.upper)
            self.fits[names] = fit(problem, start, tolerance=STATISTICAL_TOLERANCE)
        return self.fits[names]
