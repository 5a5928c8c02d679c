"""Step 0 of the loop: the base model, its resolution and its surroundings, from the data.

Before the loop looks for missing effects it decides what the data support as the
base model (docs/continuum.md, "Step 0"):

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
   5 mm free band, the eight surroundings at that radius, the radius again.
3. **The choice** between the two: the models are not nested (neither contains the
   other), so the Bayesian information criterion decides, BIC = chi^2 + k ln m with
   k = 3 for the paper's alphas and k = 2 + 3 for E, nu and the three settings the
   continuum chose (counted as parameters: the continuum pays for its search).
4. **The resolution check** of the chosen continuum: refit on a volume with spans
   ``REFINEMENT`` times smaller and one more layer; when the refit's predicted markers
   differ by a chi^2 distance |W (x_fine - x)|^2 / sigma^2 above the 1-dof quantile
   at the loop's level, the data can see the discretisation: adopt the refined
   volume and check again (at most ``MAX_REFINEMENTS`` times).

On the phantom (data made by the paper's own model, ``make demo``) the paper's energy
is kept; on FE tissue the continuum is. Large strain (real skin in the extensometer)
is not decided here: it keeps its neo-Hookean route (``experiments.realskin``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from experiments.dataset import Dataset
from experiments.fitting import FitSettings, build_model, dataset_loads, problem_on
from experiments.surroundings import marked_lengths, marker_spacing
from solvers.blas import one_thread
from solvers.diagnosis.fit import EffectFit, fit
from solvers.diagnosis.problem import ExtendedProblem
from solvers.diagnosis.stats import residual_test, robust_sigma

MARGINS_MM = (2.5, 5.0, 10.0)
"""Widths of tissue beyond the markers tried [mm]. A wider band costs a larger grid
at the same spans; on FE tissue 20 mm beyond the markers, the 10 mm free band fits
as well (docs/continuum.md, "Step 0"), so 10 mm stands for "10 mm or more"."""

SUPPORTS = ("free", "clamped")
"""How the band's outer faces are held: free, or clamped (the lateral ring of control
points fixed). An elastic support between the two is the loop's surrounding_tissue."""

RADII_MM = (1.5, 2.5, 3.5)
"""Probe radii of the first profile [mm] when the dataset does not declare one
(sigma = r / 2 of the model's Gaussian patch); extended by one step past an edge."""

DEGREES = (2, 2, 2)
"""Degrees of the continuum's volume: quadratic, as the Q2 bricks of FE codes; on the
same spans the factorisation costs half the cubic's and the predicted markers agree
as closely with a fine reference (docs/continuum.md, "Step 0")."""

SPAN_OF_SPACING = 0.5
"""Knot span of the starting volume along the skin, in marker spacings."""

SEARCH_SPAN_OF_SPACING = 2.0 / 3.0
"""Knot span of the volumes of the search over surroundings, in marker spacings: a third
of the cost of ``SPAN_OF_SPACING`` per fit, and the same choices on the tissue data
of docs/continuum.md ("Step 0")."""

REFINEMENT = 1.5
"""Factor by which the resolution check divides the knot span along the skin."""

MAX_REFINEMENTS = 2
"""Most refinements the resolution check makes (the last one adopted unchecked)."""

MAX_CHECK_POINTS = 20000
"""Largest volume (control points) the resolution check refits on: 53 x 42 x 7 takes
about 20 s to build and factor once; the next step up costs 5x that."""

TOLERANCE = 1e-6
"""Relative tolerance of the family's fits (chi^2 to well below 0.01)."""

PAPER_PARAMETERS = 3
"""k of the paper's base model in the BIC: alpha_u, alpha_v, alpha_w."""


@dataclass(frozen=True)
class Surroundings:
    """What lies beyond the markers, and the probe's size.

    Attributes
    ----------
    margin_mm : float
        Width of the band of tissue beyond the markers [mm].
    support : {"free", "clamped"}
        How the band's outer faces are held.
    radius_mm : float or None
        Probe radius [mm] (None: the dataset's own, declared).
    """

    margin_mm: float
    support: str
    radius_mm: float | None

    def label(self) -> str:
        radius = "declared probe" if self.radius_mm is None else f"probe r {self.radius_mm:.2f} mm"
        return f"{self.margin_mm:g} mm {self.support} band, {radius}"


@dataclass
class Trial:
    """One fitted base model."""

    settings: FitSettings
    surroundings: Surroundings | None
    fit: EffectFit
    chi2: float
    dof: int
    parameters: int
    seconds: float

    @property
    def bic(self) -> float:
        """chi^2 + k ln m, k counting the settings chosen by the search."""
        return self.chi2 + self.parameters * math.log(self.fit.whitened.size)

    def record(self) -> dict:
        rms, _ = self.fit.rms()
        names = self.fit.problem.labels
        return {
            "energy": self.settings.energy,
            "grid": None if self.settings.grid is None else list(self.settings.grid),
            "degrees": list(self.settings.degrees),
            "margin_mm": self.settings.margin,
            "support": "clamped" if self.settings.fix_lateral else "free",
            "probe_radius_mm": None if self.surroundings is None else self.surroundings.radius_mm,
            "parameters": dict(zip(names, map(float, self.fit.p))),
            "chi2": self.chi2,
            "dof": self.dof,
            "k": self.parameters,
            "bic": self.bic,
            "rms_mm": rms,
            "seconds": self.seconds,
        }


def starting_resolution(dataset: Dataset, spacings: float = SPAN_OF_SPACING) -> tuple[float, int]:
    """Knot span along the skin [mm] and layers through the thickness of a volume.

    ``spacings`` is the span in marker spacings: ``SPAN_OF_SPACING`` for the start of
    the resolution check, ``SEARCH_SPAN_OF_SPACING`` for the search of the surroundings.

    The span is ``SPAN_OF_SPACING`` marker spacings (two cubic spans between markers:
    the displacement between markers is what the markers do not show, and a probe's
    near field is about its radius, of the order of the spacing). Through the thickness
    the spans are as long as along the skin, at least two.
    """
    span = spacings * marker_spacing(dataset.outer_rest)
    thickness = float(np.median(np.linalg.norm(dataset.outer_rest - dataset.inner_rest, axis=-1)))
    return span, DEGREES[2] + max(2, math.ceil(thickness / span))


def span_settings(dataset: Dataset, margin: float, support: str, span: float, layers: int):
    """``FitSettings`` of the continuum with knot spans about ``span`` [mm] over the band."""
    lengths = marked_lengths(dataset.outer_rest)
    grid = tuple(math.ceil((length + 2.0 * margin) / span) + DEGREES[0] for length in lengths)
    return FitSettings(
        names=("E", "nu"),
        grid=(*grid, layers),
        degrees=DEGREES,
        energy="linear-elastic",
        margin=margin,
        fix_lateral=support == "clamped",
    )


def with_radius(dataset: Dataset, radius: float | None) -> Dataset:
    """The dataset with every load's probe radius set (None keeps the declared one)."""
    if radius is None:
        return dataset
    return replace(dataset, probe_radius=np.full(dataset.n_loads, float(radius)))


class _Family:
    """Fits of the continuum over surroundings, each model built once (cached)."""

    def __init__(self, dataset: Dataset, span: float, layers: int, sigma: float, log):
        self.dataset, self.span, self.layers, self.log = dataset, span, layers, log
        self.sigma = sigma
        self.models: dict = {}
        self.trials: dict[Surroundings, Trial] = {}
        radius = dataset.probe_radius
        self.declared = radius is not None and bool(np.all(np.asarray(radius) > 0))

    def key(self, margin: float, support: str, radius: float | None) -> Surroundings:
        return Surroundings(margin, support, None if self.declared else round(radius, 2))

    def problem(self, key: Surroundings) -> tuple[FitSettings, ExtendedProblem]:
        """The settings and base problem of a member of the family (model built once)."""
        settings = span_settings(self.dataset, key.margin_mm, key.support, self.span, self.layers)
        if (key.margin_mm, key.support) not in self.models:
            self.models[(key.margin_mm, key.support)] = build_model(self.dataset, settings)
        model, uv = self.models[(key.margin_mm, key.support)]
        data = with_radius(self.dataset, key.radius_mm)
        problem = problem_on(model, uv, data, settings)
        return settings, ExtendedProblem(problem, dataset_loads(data, model.volume), [])

    def trial(self, margin: float, support: str, radius: float | None, start=None) -> Trial:
        key = self.key(margin, support, radius)
        if key in self.trials:
            return self.trials[key]
        begin = time.perf_counter()
        settings, extended = self.problem(key)
        fitted = fit(extended, self._start() if start is None else start, tolerance=TOLERANCE)
        test = residual_test(fitted, self.sigma)
        chosen = 0 if self.declared else 1
        trial = Trial(
            settings, key, fitted, test.statistic, test.dof, 2 + 2 + chosen,
            time.perf_counter() - begin,
        )  # fmt: skip
        self.trials[key] = trial
        self.log(
            f"continuum, {key.label()}: chi2 {trial.chi2:.0f}/{trial.dof}, "
            f"E {fitted.p[0]:.3g} kPa, nu {fitted.p[1]:.3f} ({trial.seconds:.1f} s, "
            f"{fitted.evaluations} evaluations)"
        )
        return trial

    def _start(self):
        """The best trial's estimate (fewer iterations), or the default start."""
        if not self.trials:
            return None
        return self.best().fit.p

    def best(self) -> Trial:
        return min(self.trials.values(), key=lambda t: t.chi2)

    def radius_profile(self, margin: float, support: str, around: float | None = None):
        """The radius minimising chi^2 at fixed surroundings: a coarse profile, one step
        past an edge minimum, then the vertex of the parabola through the best three."""
        if self.declared:
            return self.trial(margin, support, None)
        step = RADII_MM[1] - RADII_MM[0]
        radii = list(RADII_MM) if around is None else [around - step / 2, around, around + step / 2]
        radii = [r for r in radii if r > 0]
        for _ in range(3):
            values = [self.trial(margin, support, r).chi2 for r in radii]
            low = int(np.argmin(values))
            if 0 < low < len(radii) - 1 or (low == 0 and radii[0] <= step / 2):
                break
            radii.append(radii[-1] + step) if low == len(radii) - 1 else radii.insert(
                0, max(radii[0] - step, step / 2)
            )
        values = [self.trial(margin, support, r).chi2 for r in radii]
        order = np.argsort(radii)
        radii, values = np.asarray(radii)[order], np.asarray(values)[order]
        low = int(np.argmin(values))
        if 0 < low < len(radii) - 1:
            x, y = radii[low - 1 : low + 2], values[low - 1 : low + 2]
            a, b, _ = np.polyfit(x, y, 2)
            if a > 0:
                vertex = float(np.clip(-b / (2 * a), x[0], x[-1]))
                self.trial(margin, support, vertex)
        candidates = [
            t for s, t in self.trials.items() if (s.margin_mm, s.support) == (margin, support)
        ]
        return min(candidates, key=lambda t: t.chi2)


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
    sigma: float = float("nan")
    seconds: float = 0.0

    @property
    def settings(self) -> FitSettings:
        """The base model's ``FitSettings`` for the loop."""
        return self.chosen.settings

    def fit_settings(self) -> FitSettings:
        """The ``FitSettings`` of ``dvs fit`` on the chosen model: the paper's estimates
        mu and gamma too (as ``dvs fit --energy dnurbs``), the continuum E and nu."""
        from experiments.fitting import ENERGY_NAMES

        return replace(self.settings, names=ENERGY_NAMES[self.settings.energy])

    def dataset(self, dataset: Dataset) -> Dataset:
        """The dataset the loop runs on: with the estimated probe radius, if any."""
        surroundings = self.chosen.surroundings
        return with_radius(dataset, None if surroundings is None else surroundings.radius_mm)

    def finding(self) -> str:
        """The first thing the paper's model lacks (or that it lacks nothing), in words."""
        paper, other = self.paper, self.continuum
        if other is None:
            return "the paper's energy (no continuum tried)"
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
        for name, same in (
            ("margin", lambda t: t.surroundings.margin_mm != s.margin_mm),
            ("support", lambda t: t.surroundings.support != s.support),
        ):
            rivals = [t for t in others if same(t)]
            if rivals:
                rival = min(rivals, key=lambda t: t.chi2)
                label = (
                    rival.surroundings.margin_mm if name == "margin" else rival.surroundings.support
                )
                parts.append(f"{name}: next best {label} by chi2 +{rival.chi2 - best.chi2:.0f}")
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
            },
            "trials": [t.record() for t in self.trials],
            "resolution": self.resolution,
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
        span, layers = starting_resolution(dataset, SEARCH_SPAN_OF_SPACING)
        family = _Family(dataset, span, layers, sigma, log)
        best = family.radius_profile(MARGINS_MM[1], SUPPORTS[0])
        radius = best.surroundings.radius_mm
        for margin in MARGINS_MM:
            for support in SUPPORTS:
                family.trial(margin, support, radius)
        best = family.best()
        if radius is not None:
            best = family.radius_profile(
                best.surroundings.margin_mm, best.surroundings.support, radius
            )
        trials = list(family.trials.values())
        continuum = best
        chosen = paper if paper.bic <= continuum.bic else continuum
        resolution = []
        if chosen is continuum:
            span, layers = starting_resolution(dataset)
            start = _Family(dataset, span, layers, sigma, _quiet)
            key = best.surroundings
            begun = start.trial(key.margin_mm, key.support, key.radius_mm, best.fit.p)
            chosen, resolution = _checked_resolution(dataset, start, begun, sigma, level, log)
            continuum = chosen
    choice = BaseChoice(chosen, paper, continuum, trials, resolution, sigma)
    choice.seconds = time.perf_counter() - begin
    return choice


def _chi2(fitted: EffectFit, sigma: float) -> tuple[float, int]:
    test = residual_test(fitted, sigma)
    return test.statistic, test.dof


def _paper_trial(dataset: Dataset) -> Trial:
    """The paper's energy as ``dvs diagnose --energy dnurbs`` poses it."""
    from experiments.fitting import build_problem

    begin = time.perf_counter()
    settings = FitSettings(names=("alpha_u", "alpha_v", "alpha_w"))
    problem = build_problem(dataset, settings)
    fitted = fit(ExtendedProblem(problem, dataset_loads(dataset, problem.model.volume), []))
    return Trial(settings, None, fitted, 0.0, 0, PAPER_PARAMETERS, time.perf_counter() - begin)


def _checked_resolution(dataset, family, trial, sigma, level, log):
    """The chosen continuum checked on finer volumes until the data cannot see the change
    of its predicted markers (``REFINEMENT``, at most ``MAX_REFINEMENTS`` refinements).

    The refit on the finer volume is linearised: one Gauss-Newton step from the coarse
    estimate (one factorisation of the finer K; the two parameters move little, so the
    step is the refit to first order). A refinement the data can see is adopted and
    fitted in full.
    """
    limit = float(stats.chi2.isf(level, 1))
    records = []
    for _ in range(MAX_REFINEMENTS):
        begin = time.perf_counter()
        finer = _Family(dataset, family.span / REFINEMENT, family.layers + 1, sigma, _quiet)
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
        predicted, estimate = _linearised_refit(problem, trial.fit.p)
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
        trial, family = finer.trial(key.margin_mm, key.support, key.radius_mm, estimate), finer
        records[-1]["refined_chi2"] = trial.chi2
    return trial, records


def _linearised_refit(problem: ExtendedProblem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The whitened residual and the estimate after one Gauss-Newton step from ``p``."""
    r, jacobian, _ = problem.evaluate(p)
    rho, slope = problem.whiten(r), problem.whiten(jacobian)
    step = np.linalg.lstsq(slope, -rho, rcond=None)[0]
    estimate = np.clip(p + step, problem.lower, problem.upper)
    return rho + slope @ (estimate - p), estimate


def _quiet(*_) -> None:
    """A log that prints nothing."""
