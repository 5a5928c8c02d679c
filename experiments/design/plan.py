"""Choose the presses of an experiment for a dataset's tissue (``dvs design``).

The dataset supplies the geometry (rest markers and inner surface), the markers the
cameras see, the noise level and, through the loop's base fit, the point x at which
the design is judged. The candidates are ``solvers.design.candidates`` presses on a
grid over the marked area; each loses the markers the probe hides by the dataset's
own rule (``occlusion_radius``). The search is ``solvers.design.search``. The result
is compared, figure for figure, with the dataset's own design.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from experiments.data.designfile import SCHEMA
from solvers.design.candidates import (
    Press,
    candidate_presses,
    check_force_range,
    contact_grid,
    contact_point,
    hidden_markers,
    occlusion_radius,
)
from solvers.design.criteria import Criterion, design_figures
from solvers.design.pool import InformationPool
from solvers.design.search import search
from solvers.diagnosis.stats import needed_noncentrality

POWER_GOAL = 0.9
"""The power a design for an effect should reach (docs/design.md)."""


@dataclass(frozen=True)
class DesignSettings:
    """The question asked of ``dvs design``.

    Attributes
    ----------
    target : dict
        ``{"alpha": None}`` for the base parameters, or effect name -> magnitude.
    criterion : str
        d, a, power or maximin (default: d for alpha, power for one effect, maximin
        for several).
    budget : int
        New presses.
    contacts : int
        Contacts per side of the candidate grid.
    tilt_deg, azimuths : float, int
        Tilted directions of the candidates (eq. D4).
    force_range : tuple of float
        Safe force range [N].
    levels : int
        Force magnitudes over the range.
    level : float
        Significance level of the score tests.
    augment : bool
        Keep the dataset's presses and add the budget to them.
    """

    target: dict = field(default_factory=lambda: {"alpha": None})
    criterion: str | None = None
    budget: int = 10
    contacts: int = 5
    tilt_deg: float = 20.0
    azimuths: int = 4
    force_range: tuple = (0.17, 0.25)
    levels: int = 2
    level: float = 0.01
    augment: bool = False

    def __post_init__(self) -> None:
        if self.budget < 1:
            raise ValueError(f"--budget must be at least 1 press, got {self.budget}")
        if not 2 <= self.contacts <= 15:
            raise ValueError(f"--contacts must lie in 2-15, got {self.contacts}")
        if not 0 <= self.azimuths <= 12:
            raise ValueError(f"--azimuths must lie in 0-12, got {self.azimuths}")
        if not 1 <= self.levels <= 5:
            raise ValueError(f"--levels must lie in 1-5, got {self.levels}")
        if not 0 < self.level < 0.5:
            raise ValueError(f"--level must lie in (0, 0.5), got {self.level}")
        criterion, alpha = self.criterion, "alpha" in self.target
        if criterion in ("d", "a") and not alpha:
            raise ValueError(f"--criterion {criterion} is for --target alpha")
        if criterion in ("power", "maximin") and alpha:
            raise ValueError(f"--criterion {criterion} needs effects as the --target")
        if criterion == "power" and len(self.target) > 1:
            raise ValueError("--criterion power takes one effect; use maximin for several")
        try:
            check_force_range(*self.force_range)
        except ValueError as error:
            raise ValueError(f"--force-range: {error}") from None

    @property
    def chosen_criterion(self) -> str:
        """The criterion given, or the target's default."""
        if self.criterion:
            return self.criterion
        if "alpha" in self.target:
            return "d"
        return "power" if len(self.target) == 1 else "maximin"

    def forces(self) -> np.ndarray:
        """The candidate force magnitudes [N]."""
        low, high = self.force_range
        return np.linspace(low, high, self.levels) if self.levels > 1 else np.array([high])


@dataclass(frozen=True)
class Plan:
    """A design and what it was chosen from.

    Attributes
    ----------
    document : dict
        The ``design.json`` document (schema ``dvs-design/1``).
    pool : InformationPool
        The dataset's presses and the candidates, with their information.
    criterion : Criterion
    own : list of int
        Pool indices of the dataset's presses.
    candidates : list of int
        Pool indices of the candidates.
    contacts : numpy.ndarray
        The candidate contacts (u, v), (n, 2).
    """

    document: dict
    pool: InformationPool
    criterion: Criterion
    own: list
    candidates: list
    contacts: np.ndarray


def press_document(model, press: Press) -> dict:
    """``{"contact_mm", "force_N", "uv", "tilt_deg", "probe_radius_mm", "probe_shape"}`` of
    one press."""
    return {
        "contact_mm": [float(v) for v in contact_point(model, press.uv)],
        "force_N": [float(v) for v in press.force],
        "uv": [float(v) for v in press.uv],
        "tilt_deg": float(press.tilt_deg),
        "probe_radius_mm": float(press.probe_radius),
        "probe_shape": press.probe_shape,
    }


def dataset_presses(dataset, model) -> tuple[list[Press], list[np.ndarray]]:
    """The dataset's own presses (with its declared probe radius) and the markers each
    capture sees."""
    from experiments.problem.fitting import dataset_loads

    loads = dataset_loads(dataset, model.volume)
    presses = [
        Press(
            np.asarray(ld.uv, float),
            np.asarray(ld.force, float),
            0.0,
            getattr(ld, "radius", 0.0),
            getattr(ld, "shape", "gauss"),
        )
        for ld in loads
    ]
    seen = [np.all(np.isfinite(c.reshape(-1, 3)), axis=1) for c in dataset.outer_loaded]
    return presses, seen


def candidate_set(pool: InformationPool, dataset, settings, own, seen):
    """The candidate presses of ``settings`` (``contacts``, ``forces()``, ``tilt_deg``,
    ``azimuths``) for ``pool``, with the dataset's probe radius and occlusion rule.

    ``own`` and ``seen`` are the dataset's presses and the markers each capture sees
    (``dataset_presses``). Returns the presses, the markers each sees, the contacts
    (u, v) and the occlusion radius [mm].
    """
    model = pool.model
    rest = dataset.outer_rest.reshape(-1, 3)
    radius = occlusion_radius(rest, dataset.contacts, np.array(seen))
    probe = float(np.median([p.probe_radius for p in own]))  # the candidates use the dataset's
    shape = own[0].probe_shape if own else "gauss"
    contacts = contact_grid(pool.marker_uv, settings.contacts)
    presses, visible = [], []
    for uv in contacts:
        batch = candidate_presses(
            model, uv[None], settings.forces(), settings.tilt_deg, settings.azimuths, probe, shape
        )
        presses += batch
        visible += [~hidden_markers(rest, contact_point(model, uv), radius)] * len(batch)
    return presses, visible, contacts, radius


def add_with_candidates(pool: InformationPool, dataset, settings, own, seen, log=print):
    """Add the dataset's presses and the candidates of ``settings`` (``candidate_set``)
    to ``pool`` in one evaluation (one factorisation per parameter value for all).

    Returns the pool indices of the dataset's presses and of the candidates, the
    contacts (u, v) and the occlusion radius [mm].
    """
    begin = time.perf_counter()
    presses, visible, contacts, radius = candidate_set(pool, dataset, settings, own, seen)
    indices = pool.add(list(own) + presses, list(seen) + visible)
    log(
        f"  information of {len(own)} dataset presses and {len(presses)} candidate presses "
        f"({len(contacts)} contacts, {time.perf_counter() - begin:.1f} s)"
    )
    return indices[: len(own)], indices[len(own) :], contacts, radius


def require_noise(dataset):
    """The dataset, when it declares its noise level (a design needs it); else exit 2."""
    if not dataset.noise_mm:
        raise ValueError("the dataset declares no noise_mm; a design needs the noise level")
    return dataset


def plan(dataset, settings: DesignSettings, grid=None, log=print, base=None, fit=None) -> Plan:
    """The design of ``settings`` for ``dataset`` (``Plan``); ``base`` is the base model's
    ``FitSettings`` (default ``base_settings(grid)``, as ``dvs diagnose``) and ``fit`` its
    fit when already made (step 0's, ``solvers.diagnosis.fit.EffectFit``)."""
    from experiments.design.predictions import base_fit
    from experiments.fit.stepzero import model_record
    from symbolic.effects.library import make_effect

    begin = time.perf_counter()
    sigma = float(require_noise(dataset).noise_mm)
    if fit is None:
        log(f"fitting the base model to {dataset.n_loads} load case(s)")
        fit = base_fit(dataset, grid, base)
    model = fit.problem.model
    rest = dataset.outer_rest.reshape(-1, 3)
    marker_uv, _ = model.volume.project_to_outer(rest)
    effects = [(make_effect(n), float(m)) for n, m in settings.target.items() if n != "alpha"]
    pool = InformationPool(fit, marker_uv, effects)
    own, seen = dataset_presses(dataset, model)
    own_index, candidates, contacts, radius = add_with_candidates(
        pool, dataset, settings, own, seen, log
    )
    criterion = Criterion(settings.chosen_criterion, pool.layout, sigma, settings.level)
    start = own_index if settings.augment else []
    searched = time.perf_counter()
    result = search(
        pool, criterion, settings.budget, start, candidates, progress=lambda line: log("  " + line)
    )
    search_seconds = time.perf_counter() - searched
    chosen = list(start) + result.chosen
    figures = design_figures(pool.totals(chosen).matrix(), pool.layout, sigma, settings.level)
    reference = design_figures(pool.totals(own_index).matrix(), pool.layout, sigma, settings.level)
    document = {
        "schema": SCHEMA,
        "criterion": criterion.name,
        "target": list(settings.target),
        "magnitudes": {e.name: m for e, m in effects},
        "budget": settings.budget,
        "augment": settings.augment,
        "level": settings.level,
        "noise_mm": sigma,
        "model": model_record(model, 0.0 if base is None else base.margin, dataset),
        "presses": [press_document(model, pool.presses[k]) for k in chosen],
        "predicted": figures.document(),
        "dataset_design": {
            "presses": [press_document(model, p) for p in own],
            "predicted": reference.document(),
        },
        "det_root_ratio": figures.det_root / reference.det_root if reference.det_root else None,
        "power_goal": _power_goal(figures, settings),
        "candidates": {
            "count": len(candidates),
            "contacts": len(contacts),
            "tilt_deg": settings.tilt_deg,
            "azimuths": settings.azimuths,
            "forces_N": [float(f) for f in settings.forces()],
            "occlusion_radius_mm": radius,
        },
        "search": {
            "greedy_score": result.greedy_score,
            "score": result.score,
            "swaps": result.swaps,
            "evaluations": result.evaluations,
            "seconds": search_seconds,
        },
    }
    document["wall_time_s"] = time.perf_counter() - begin
    return Plan(document, pool, criterion, own_index, candidates, contacts)


def _power_goal(figures, settings: DesignSettings) -> dict:
    """Per effect: does the design reach ``POWER_GOAL``, and if not, about how many
    presses of the same kind would (lambda grows with the presses, roughly linearly)."""
    out = {}
    for p in figures.powers:
        needed = needed_noncentrality(max(p.dof, 1), p.level, p.one_sided, POWER_GOAL)
        enough = p.power >= POWER_GOAL
        estimate = None
        if not enough and p.noncentrality > 0:
            estimate = int(np.ceil(settings.budget * needed / p.noncentrality))
        out[p.name] = {
            "reached": bool(enough),
            "noncentrality_needed": needed,
            "presses_needed_estimate": estimate,
        }
    return out
