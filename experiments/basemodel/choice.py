"""Step 0 of the loop: the base model, its resolution and its surroundings, from the data.

Before the loop looks for missing effects it decides what the data support as the
base model (docs/stepzero.md):

1. **The paper's energy** (eq. 18, alpha_u, alpha_v, alpha_w) on the paper's volume:
   the auto grid up to 9x9x2, ending at the markers, the loads as declared.
2. **The linear-elastic continuum** (E, nu) on a volume whose resolution follows the
   markers (knot spans of half the marker spacing, ``starting_resolution``) and whose
   surroundings are estimated, not assumed: how far the tissue goes on beyond the
   markers (``MARGINS_MM``), whether it is free or clamped there (``SUPPORTS``), and,
   when the dataset does not declare it (or declares point forces, which a continuum
   cannot carry: its displacement under a point is unbounded), the probe's radius (a
   profile over
   ``RADII_MM``, refined by a parabola through the best three). Each member of this
   family has the same two estimated parameters, so the family's chi^2 values compare
   directly (a profile likelihood); the search is coordinate-wise: the radius at a
   5 mm free band, the eight surroundings at that radius, the radius again (with the
   model's default Gaussian probe; its shape is decided in 5).
3. **The choice** between the two. When the paper's energy already fits at the noise
   level (its residual test not significant at the loop's level) nothing is replaced
   and the continuum is not tried. Otherwise: the models are not nested (neither
   contains the other), so the Bayesian information criterion decides, BIC = chi^2 + k ln m with
   k = 3 for the paper's alphas and k = 2 + 4 for E, nu and the four settings the
   continuum chose (counted as parameters: the continuum pays for its search).
4. **The resolution check** of the chosen continuum: refit on a volume with spans
   ``REFINEMENT`` times smaller and one more layer; when the refit's predicted markers
   differ by a chi^2 distance |W (x_fine - x)|^2 / sigma^2 above the 1-dof quantile
   at the loop's level, the data can see the discretisation: adopt the refined
   volume and check again (at most ``MAX_REFINEMENTS`` times).
5. **The probe's shape** on the checked volume (``checked_shape``): the other shape
   (``symbolic.loads.PROBE_SHAPES``: a Gaussian or a uniform disc), its radius
   profiled, replaces the Gaussian when it fits better by more than the 1-dof quantile.

On the phantom (data made by the paper's own model, ``make demo``) the paper's energy
is kept; on FE tissue the continuum is. Large strain (real skin in the extensometer)
is not decided here: it keeps its neo-Hookean route (``experiments.realskin``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

from scipy import stats

from experiments.basemodel.family import (
    MARGINS_MM,
    SEARCH_SPAN_OF_SPACING,
    SUPPORTS,
    Family,
    Trial,
    profile,
    starting_resolution,
    with_radius,
)
from experiments.basemodel.resolution import (
    REFINEMENT,
    checked_resolution,
    linearised_refit,
    quiet,
)
from experiments.data.dataset import Dataset
from experiments.problem.fitting import FitSettings, dataset_loads
from solvers.diagnosis.discretisation import remaining_error
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import EffectFit, fit
from solvers.diagnosis.stats import residual_test, robust_sigma
from solvers.linalg.blas import one_thread
from symbolic.loads import PROBE_SHAPES

PAPER_PARAMETERS = 3
"""k of the paper's base model in the BIC: alpha_u, alpha_v, alpha_w."""


@dataclass
class BaseChoice:
    """Step 0's outcome: the base model the loop starts from, and why.

    Attributes
    ----------
    chosen : Trial
        The kept base model (its settings, surroundings and fit).
    paper : Trial
        The paper's energy on the paper's volume.
    continuum : Trial or None
        The best continuum of the family (None when only the paper's was tried).
    trials : list of Trial
        Every continuum fitted, in order.
    resolution : list of dict
        The resolution checks: grid, refined grid, chi^2 distance of the predictions,
        limit, adopted or not.
    shapes : list of dict
        The probe's shapes compared at the checked resolution (``checked_shape``).
    sigma : float
        Noise level of the chi^2 values [mm].
    seconds : float
        Wall time of step 0 [s].
    """

    chosen: Trial
    paper: Trial
    continuum: Trial | None
    trials: list
    resolution: list = field(default_factory=list)
    shapes: list = field(default_factory=list)
    sigma: float = float("nan")
    seconds: float = 0.0

    @property
    def settings(self) -> FitSettings:
        """The base model's ``FitSettings`` for the loop."""
        return self.chosen.settings

    def fit_settings(self) -> FitSettings:
        """The ``FitSettings`` of ``dvs fit`` on the chosen model: the paper's estimates
        mu and gamma too (as ``dvs fit --energy dnurbs``), the continuum E and nu."""
        from experiments.problem.fitting import ENERGY_NAMES

        names = ENERGY_NAMES[self.settings.energy]
        estimate = dict(zip(self.chosen.fit.problem.names, map(float, self.chosen.fit.p)))
        start = {name: value for name, value in estimate.items() if name in names}
        return replace(self.settings, names=names, start=start)

    def dataset(self, dataset: Dataset) -> Dataset:
        """The dataset the loop runs on: with the estimated probe radius, if any."""
        s = self.chosen.surroundings
        return dataset if s is None else with_radius(dataset, s.radius_mm, s.shape)

    def finding(self) -> str:
        """The first thing the paper's model lacks (or that it lacks nothing), in words."""
        paper, other = self.paper, self.continuum
        if other is None:
            p_value = stats.chi2.sf(paper.chi2, paper.dof)
            return (
                f"the paper's energy is kept: it fits at the noise level (chi2 {paper.chi2:.0f} "
                f"over {paper.dof} dof, p {p_value:.2g}), so the continuum was not tried"
            )
        numbers = (
            f"chi2 {paper.chi2:.0f} -> {other.chi2:.0f} over {paper.dof} dof, "
            f"BIC {paper.bic:.0f} -> {other.bic:.0f}"
        )
        if self.chosen is paper:
            return f"the paper's energy is kept: the continuum does not fit better ({numbers})"
        return (
            "shear coupling and resistance to volume change: the paper's energy replaced by "
            f"isotropic linear elasticity on a volume with {other.surroundings.label()} ({numbers})"
        )

    def preference(self) -> str:
        """How strongly the data preferred the chosen surroundings over the runner-up of
        each setting (chi^2 differences at the same number of parameters, on the search's
        volumes)."""
        if self.continuum is None:
            return ""
        best = min(self.trials, key=lambda t: t.chi2)  # the search's volumes, one resolution
        parts = []
        s = best.surroundings
        others = [t for t in self.trials if t is not best]
        for name, field_name in (("margin", "margin_mm"), ("support", "support")):
            rivals = [
                t for t in others if getattr(t.surroundings, field_name) != getattr(s, field_name)
            ]
            if rivals:
                rival = min(rivals, key=lambda t: t.chi2)
                label = getattr(rival.surroundings, field_name)
                parts.append(f"{name}: next best {label} by chi2 +{rival.chi2 - best.chi2:.0f}")
        if len(self.shapes) > 1:  # the continuum's, on its checked volume (``checked_shape``)
            kept = next(r for r in self.shapes if r["shape"] == self.continuum.surroundings.shape)
            other = min((r for r in self.shapes if r is not kept), key=lambda r: r["chi2"])
            difference = other["chi2"] - kept["chi2"]
            parts.append(f"probe shape: next best {other['shape']} by chi2 {difference:+.0f}")
        return "; ".join(parts)

    def record(self) -> dict:
        """The ``base_choice`` record of diagnosis.json and result.json."""
        surroundings = None if self.continuum is None else self.continuum.surroundings
        return {
            "chosen": self.chosen.settings.energy,
            "finding": self.finding(),
            "preference": self.preference(),
            "sigma_mm": self.sigma,
            "paper": self.paper.record(),
            "continuum": None if self.continuum is None else self.continuum.record(),
            "surroundings": None
            if surroundings is None
            else {
                "margin_mm": surroundings.margin_mm,
                "support": surroundings.support,
                "probe_radius_mm": surroundings.radius_mm,
                "probe_radius_estimated": surroundings.radius_mm is not None,
                "probe_shape": surroundings.shape,
            },
            "trials": [t.record() for t in self.trials],
            "resolution": self.resolution,
            "discretisation": remaining_error(self.resolution, REFINEMENT),
            "shapes": self.shapes,
            "seconds": self.seconds,
        }

    def line(self) -> str:
        """One line for the command's log."""
        chosen = self.chosen.settings
        grid = "auto" if chosen.grid is None else "x".join(map(str, chosen.grid))
        degrees = "x".join(map(str, chosen.degrees))
        text = f"base model: {chosen.energy}, grid {grid}, degrees {degrees}"
        if self.chosen.surroundings is not None:
            text += f", {self.chosen.surroundings.label()}"
        return text


def choose_base(dataset: Dataset, log=None, level: float = 0.01) -> BaseChoice:
    """Step 0: fit the paper's energy and the continuum family; keep what the data support.

    Parameters
    ----------
    dataset : Dataset
        The data (its ``noise_mm``, else a robust estimate from the paper's fit).
    log : callable, optional
        Progress lines.
    level : float
        The loop's significance level (the resolution check's chi^2 quantile).
    """
    log = log or (lambda *_: None)
    begin = time.perf_counter()
    with one_thread():
        paper = _paper_trial(dataset)
        sigma = float(dataset.noise_mm) if dataset.noise_mm else robust_sigma(paper.fit)
        paper.chi2, paper.dof = _chi2(paper.fit, sigma)
        log(f"paper's energy (auto grid, ending at the markers): chi2 {paper.chi2:.0f}/{paper.dof}")
        if stats.chi2.sf(paper.chi2, paper.dof) >= level:  # at the noise: nothing to replace
            choice = BaseChoice(paper, paper, None, [], [], sigma=sigma)
            choice.seconds = time.perf_counter() - begin
            return choice
        span, layers = starting_resolution(dataset, SEARCH_SPAN_OF_SPACING)
        family = Family(dataset, span, layers, sigma, log)
        best = search_surroundings(family, MARGINS_MM[1], SUPPORTS[0])
        trials = list(family.trials.values())
        continuum = best
        chosen = paper if paper.bic <= continuum.bic else continuum
        resolution, shapes = [], []
        if chosen is continuum:
            span, layers = starting_resolution(dataset)
            start = Family(dataset, span, layers, sigma, quiet)
            begun = start.trial_at(best.surroundings, best.fit.p)
            chosen, resolution = checked_resolution(dataset, start, begun, sigma, level, log)
            chosen, shapes = checked_shape(chosen, level, log)
            continuum = chosen
    choice = BaseChoice(chosen, paper, continuum, trials, resolution, shapes, sigma)
    choice.seconds = time.perf_counter() - begin
    return choice


def search_surroundings(
    family: Family, margin: float, support: str, radius=None, shape: str = "gauss"
) -> Trial:
    """The best member of the family, searched coordinate-wise from (margin, support) with
    a probe of ``shape``: the probe radius (a profile: the coarse ``RADII_MM``, or around
    ``radius``), then every margin and support at that radius, then the radius again at
    the best of them (the shape is compared on finer volumes, ``checked_shape``)."""
    best = family.radius_profile(margin, support, radius, shape)
    radius = best.surroundings.radius_mm
    for other_margin in MARGINS_MM:
        for other_support in SUPPORTS:
            family.trial(other_margin, other_support, radius, shape=shape)
    best = family.best()
    if radius is not None:
        s = best.surroundings
        best = family.radius_profile(s.margin_mm, s.support, radius, shape)
    return best


def checked_shape(trial: Trial, level: float, log) -> tuple[Trial, list[dict]]:
    """The probe's shape decided on the trial's own volume (its ``family``): each other
    shape (``PROBE_SHAPES``) with its radius profiled around the trial's (``profile``),
    at the same margin and support; it replaces the trial when its chi^2 is lower by
    more than the 1-dof quantile at ``level``. Returns the trial kept and each shape's
    best, the kept one's first.

    The profile is linearised: at the trial's estimate p the stiffness K(p) does not
    depend on the load, so one factorisation serves every shape and radius, and one
    Gauss-Newton step from p gives each refit (as the resolution check's). Only a shape
    that wins so is fitted in full, and must win again.

    Not on the search's coarser volumes: there a disc's edge is not resolved (on FE
    data with a 2.5 mm disc and a tilted force, the search preferred the Gaussian by
    chi^2 12, the loop's 40x33x6 volume the disc by 99).
    """
    family, s, p = trial.family, trial.surroundings, trial.fit.p
    factor = trial.fit.problem.stiffness_factor(p)
    limit = float(stats.chi2.isf(level, 1))
    best, records = trial, [_shape_record(trial, "fit")]
    for other in PROBE_SHAPES:
        if other == s.shape:
            continue
        estimates: dict = {}

        def chi2_at(radius, other=other, estimates=estimates):
            _, problem = family.problem(family.key(s.margin_mm, s.support, radius, other))
            problem.cache["last_state_jacobian"] = factor  # K(p) is the trial's
            predicted, estimates[radius] = linearised_refit(problem, p)
            return float(predicted @ predicted) / family.sigma**2

        if family.declared:
            radius, chi2 = None, chi2_at(None)
        else:
            radius, chi2 = profile(chi2_at, s.radius_mm, family.max_radius())
        records.append(
            {
                **_shape_record(trial, "linearised"),
                "shape": other,
                "chi2": chi2,
                "probe_radius_mm": radius,
            }
        )
        if chi2 < best.chi2 - limit:
            full = family.trial(s.margin_mm, s.support, radius, estimates[radius], other)
            records[-1] = _shape_record(full, "fit")
            best = full if full.chi2 < best.chi2 - limit else best
    log(
        f"probe shape on {'x'.join(map(str, trial.settings.grid))}: "
        + ", ".join(
            f"{r['shape']} {_radius_text(r['probe_radius_mm'])} chi2 {r['chi2']:.0f} "
            f"({r['method']})"
            for r in records
        )
        + f": {best.surroundings.shape} kept"
    )
    return best, records


def _radius_text(radius) -> str:
    """A trial's probe radius in a log line: the estimate, or "r declared" (None: the
    dataset's own radius is used, not estimated)."""
    return "r declared" if radius is None else f"r {radius:.2f} mm"


def _shape_record(trial: Trial, method: str) -> dict:
    s = trial.surroundings
    return {
        "shape": s.shape,
        "probe_radius_mm": s.radius_mm,
        "chi2": trial.chi2,
        "grid": list(trial.settings.grid),
        "method": method,
    }


def _chi2(fitted: EffectFit, sigma: float) -> tuple[float, int]:
    test = residual_test(fitted, sigma)
    return test.statistic, test.dof


def _paper_trial(dataset: Dataset) -> Trial:
    """The paper's energy as ``dvs diagnose --energy dnurbs`` poses it."""
    from experiments.problem.fitting import build_problem

    begin = time.perf_counter()
    settings = FitSettings(names=("alpha_u", "alpha_v", "alpha_w"))
    problem = build_problem(dataset, settings)
    fitted = fit(ExtendedProblem(problem, dataset_loads(dataset, problem.model.volume), []))
    return Trial(settings, None, fitted, 0.0, 0, PAPER_PARAMETERS, time.perf_counter() - begin)
