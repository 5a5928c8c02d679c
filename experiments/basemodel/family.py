"""The continuum's family of surroundings: trials of the base model over margins,
supports and probe radii, each on a volume whose knot spans follow the markers.

Used by step 0 (``experiments.basemodel.choice``): every member has the same two
estimated parameters (E, nu), so their chi^2 compare directly (a profile likelihood
over the settings).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from experiments.data.dataset import Dataset
from experiments.problem.fitting import FitSettings, build_model, dataset_loads, problem_on
from experiments.problem.surroundings import marked_lengths, marker_spacing
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import EffectFit, fit
from solvers.diagnosis.stats import residual_test

MARGINS_MM = (2.5, 5.0, 10.0)
"""Widths of tissue beyond the markers tried [mm]. A wider band costs a larger grid
at the same spans; on FE tissue reaching 20 mm beyond the markers, the 10 mm free band fits
as well (docs/results/continuum-fe-slab.md), so 10 mm stands for "10 mm or more"."""

SUPPORTS = ("free", "clamped")
"""How the band's outer faces are held: free, or clamped (the lateral ring of control
points fixed). An elastic support between the two is the loop's surrounding_tissue."""

RADII_MM = (1.5, 2.5, 3.5)
"""Probe radii of the first profile [mm] when the dataset does not declare one
(sigma = r / 2 of the model's Gaussian patch); extended by one step past an edge."""

DEGREES = (2, 2, 2)
"""Degrees of the continuum's volume: quadratic, as the Q2 bricks of FE codes; on the
same spans the factorisation costs half the cubic's and the predicted markers agree
as closely with a fine reference (docs/stepzero.md, "What it compares")."""

MIN_RADIUS_MM = 1.0
"""Smallest probe radius tried [mm]: a patch narrower than the finest knot span step 0
builds is a point force to the volume, whose predicted markers never converge under
refinement (on fuzzed data a 0.5 mm patch moved them by chi^2 17510 from 32 x 32 x 5 to
47 x 47 x 6)."""

MAX_RADIUS_OF_MARKED = 0.25
"""Largest probe radius tried, as a fraction of the shorter side of the marked area: a
patch wider than that is no probe but a load over the area the markers measure (the
default phantom, a point force, drove the profile of ``dvs image``'s search out to 10
mm when it had no cap)."""

SPAN_OF_SPACING = 0.5
"""Knot span of the starting volume along the skin, in marker spacings."""

SEARCH_SPAN_OF_SPACING = 2.0 / 3.0
"""Knot span of the volumes of the search over surroundings, in marker spacings: a third
of the cost of ``SPAN_OF_SPACING`` per fit, and the same choices on the tissue data
of docs/stepzero.md ("What it compares")."""

TOLERANCE = 1e-6
"""Relative tolerance of the family's fits (chi^2 to well below 0.01)."""


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
    shape : str
        The probe patch's shape (``symbolic.loads.PROBE_SHAPES``).
    """

    margin_mm: float
    support: str
    radius_mm: float | None
    shape: str = "gauss"

    def label(self) -> str:
        radius = "declared" if self.radius_mm is None else f"r {self.radius_mm:.2f} mm"
        return f"{self.margin_mm:g} mm {self.support} band, {self.shape} probe {radius}"


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
    family: object = None
    """The ``Family`` it belongs to (its resolution and built models), if any."""

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
            "probe_shape": None if self.surroundings is None else self.surroundings.shape,
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


def with_radius(dataset: Dataset, radius: float | None, shape: str | None = None) -> Dataset:
    """The dataset with every load's probe radius set (None keeps the declared one) and
    the probe's shape (None keeps the dataset's)."""
    if shape is not None:
        dataset = replace(dataset, probe_shape=shape)
    if radius is None:
        return dataset
    return replace(dataset, probe_radius=np.full(dataset.n_loads, float(radius)))


class Family:
    """Fits of the continuum over surroundings, each model built once (cached)."""

    def __init__(
        self,
        dataset: Dataset,
        span: float,
        layers: int,
        sigma: float,
        log,
        effects: tuple = (),
        initial: np.ndarray | None = None,
    ):
        self.dataset, self.span, self.layers, self.log = dataset, span, layers, log
        self.sigma = sigma
        self.effects, self.initial = list(effects), initial
        self.models: dict = {}
        self.trials: dict[Surroundings, Trial] = {}
        radius = dataset.probe_radius
        self.declared = radius is not None and bool(np.all(np.asarray(radius) > 0))

    def with_effects(self, effects, initial: np.ndarray, log=None) -> Family:
        """The same family (resolution, built models) with effects active in every member,
        the fits starting from ``initial`` (p of a fit with those effects)."""
        other = Family(
            self.dataset, self.span, self.layers, self.sigma, log or self.log, effects, initial
        )
        other.models = self.models
        return other

    def key(self, margin: float, support: str, radius: float | None, shape="gauss"):
        radius = None if self.declared else round(radius, 2)
        return Surroundings(margin, support, radius, shape)

    def problem(self, key: Surroundings) -> tuple[FitSettings, ExtendedProblem]:
        """The settings and base problem of a member of the family (model built once)."""
        settings = span_settings(self.dataset, key.margin_mm, key.support, self.span, self.layers)
        if (key.margin_mm, key.support) not in self.models:
            self.models[(key.margin_mm, key.support)] = build_model(self.dataset, settings)
        model, uv = self.models[(key.margin_mm, key.support)]
        data = with_radius(self.dataset, key.radius_mm, key.shape)
        problem = problem_on(model, uv, data, settings)
        loads = dataset_loads(data, model.volume)
        return settings, ExtendedProblem(problem, loads, self.effects, sigma=self.sigma)

    def trial(self, margin, support, radius, start=None, shape="gauss") -> Trial:
        """The member at these surroundings, fitted once (``Surroundings``' fields)."""
        key = self.key(margin, support, radius, shape)
        if key in self.trials:
            return self.trials[key]
        begin = time.perf_counter()
        settings, extended = self.problem(key)
        fitted = fit(extended, self._start() if start is None else start, tolerance=TOLERANCE)
        test = residual_test(fitted, self.sigma)
        chosen = 2 if self.declared else 3  # margin, support (, radius)
        trial = Trial(
            settings,
            key,
            fitted,
            test.statistic,
            test.dof,
            2 + chosen + 1,  # + shape
            time.perf_counter() - begin,
        )
        trial.family = self
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
            return self.initial
        return self.best().fit.p

    def best(self) -> Trial:
        return min(self.trials.values(), key=lambda t: t.chi2)

    def max_radius(self) -> float:
        """``MAX_RADIUS_OF_MARKED`` of the shorter marked side [mm]."""
        return MAX_RADIUS_OF_MARKED * float(min(marked_lengths(self.dataset.outer_rest)))

    def trial_at(self, key: Surroundings, start=None) -> Trial:
        """``trial`` at a ``Surroundings``."""
        return self.trial(key.margin_mm, key.support, key.radius_mm, start, key.shape)

    def radius_profile(self, margin, support, around=None, shape="gauss") -> Trial:
        """The member minimising chi^2 over the probe radius at fixed surroundings and
        probe shape (``profile``; the declared radius when the dataset has one)."""

        def trial(radius):
            return self.trial(margin, support, radius, shape=shape)

        if self.declared:
            return trial(None)
        profile(lambda r: trial(r).chi2, around, self.max_radius())
        candidates = [
            t
            for s, t in self.trials.items()
            if (s.margin_mm, s.support, s.shape) == (margin, support, shape)
        ]
        return min(candidates, key=lambda t: t.chi2)


def profile(chi2_at, around: float | None = None, largest: float = math.inf):
    """The probe radius [mm] minimising ``chi2_at(radius)``: a coarse profile (``RADII_MM``,
    or half a step either side of ``around``), one step past an edge minimum (within
    ``MIN_RADIUS_MM`` and ``largest``), then the vertex of the parabola through the best
    three. Radii are rounded to 0.01 mm, each evaluated once; returns the best radius and
    its chi^2."""
    tried: dict[float, float] = {}

    def value(radius: float) -> float:
        radius = round(float(radius), 2)
        if radius not in tried:
            tried[radius] = chi2_at(radius)
        return tried[radius]

    step = RADII_MM[1] - RADII_MM[0]
    radii = list(RADII_MM) if around is None else [around - step / 2, around, around + step / 2]
    radii = sorted({min(r, largest) for r in radii if r >= MIN_RADIUS_MM})
    for _ in range(3):
        values = [value(r) for r in radii]
        low = int(np.argmin(values))
        if 0 < low < len(radii) - 1 or (low == 0 and radii[0] <= MIN_RADIUS_MM):
            break
        if low == len(radii) - 1:
            if radii[-1] >= largest:
                break
            radii.append(min(radii[-1] + step, largest))
        else:
            radii.insert(0, max(radii[0] - step, MIN_RADIUS_MM))
    values = [value(r) for r in radii]
    order = np.argsort(radii)
    radii, values = np.asarray(radii)[order], np.asarray(values)[order]
    low = int(np.argmin(values))
    if 0 < low < len(radii) - 1:
        x, y = radii[low - 1 : low + 2], values[low - 1 : low + 2]
        a, b, _ = np.polyfit(x, y, 2)
        if a > 0:
            value(float(np.clip(-b / (2 * a), x[0], x[-1])))
    radius = min(tried, key=tried.get)
    return radius, tried[radius]
