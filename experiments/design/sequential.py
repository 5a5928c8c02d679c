"""The sequential loop: press, diagnose, choose the next press (``dvs design --sequential``).

Against a lab (``experiments.design.lab.ContinuumLab``: FE continuum data made by
scikit-fem, one capture per press), starting from the paper's two loads at the centre:

1. diagnose the data so far (``solvers.diagnosis.loop``, the linear-elastic base model);
2. pose the questions the diagnosis leaves (``solvers.design.discrimination``): separate
   each named effect from every other library effect (T-optimality, eq. D6), and detect
   every effect not named at its realistic magnitude (eq. D2);
3. stop when the verdict is "explained" and no question the remaining budget could
   answer is open, or when the budget is spent;
4. otherwise make the press that makes the most progress over every unanswered
   question (eq. D7; the candidates of ``dvs design``: contacts over the marked area,
   the normal and tilted directions, the safe forces), and go to 1.

The path records, per step, the press made and why, the diagnosis (named effects,
rivals, the leading score tests, the RMS against the noise) and each question's value.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from experiments.design.plan import (
    DesignSettings,
    add_with_candidates,
    dataset_presses,
    press_document,
)
from experiments.fit.stepzero import AUTO, model_record
from solvers.design.discrimination import Discrimination, questions, standings
from solvers.design.pool import InformationPool
from solvers.design.search import search
from solvers.diagnosis.record import DiagnosisSettings
from symbolic.effects.library import effect_library

SCHEMA = "dvs-sequential/1"
DIAGNOSIS = DiagnosisSettings()
"""The loop's settings (rival margin 3.84, the default library; the level is the
candidates' ``level``)."""


@dataclass(frozen=True)
class SequentialSettings:
    """Choices of the sequential loop.

    Attributes
    ----------
    budget : int
        Presses in all, the starting design's included (10 in docs/design.md).
    start : str
        The starting design (``experiments.phantom.fe.design_cases``: ``paper``).
    energy : str
        ``auto`` (the default): before each diagnosis step 0 chooses the base model, its
        resolution and surroundings and the probe's radius from the data so far, as
        ``dvs diagnose`` does (``experiments.fit.stepzero``); ``linear-elastic``: the volume
        of ``grid``, ``degrees`` and ``margin``.
    grid, degrees : tuple of int
        The control grid and spline degrees of ``energy="linear-elastic"``.
    margin : float
        That model's tissue beyond the markers [mm].
    goal : float
        The power, and the probability of separation (eq. D6'), that answer a question.
    rivals : int or None
        How many effects are in play besides the named ones: the leading score tests
        of the diagnosis's final round; None: every effect of the library (each costs
        an equilibrium per candidate press).
    candidates : DesignSettings
        The candidate presses (``contacts``, ``tilt_deg``, ``azimuths``, ``force_range``,
        ``levels``) and the significance ``level``.
    """

    budget: int = 10
    start: str = "paper"
    energy: str = AUTO
    grid: tuple[int, int, int] = (15, 15, 3)
    degrees: tuple[int, int, int] = (3, 3, 2)
    margin: float = 10.0
    goal: float = 0.9
    rivals: int | None = None
    candidates: DesignSettings = DesignSettings(contacts=3, levels=1, force_range=(0.25, 0.25))

    def __post_init__(self) -> None:
        if self.budget < 3:
            raise ValueError(
                f"--budget must be at least 3 presses in all (the paper's 2 and one chosen), "
                f"got {self.budget}"
            )
        if self.energy not in (AUTO, "linear-elastic"):
            raise ValueError(f"energy must be auto or linear-elastic, got {self.energy!r}")
        if not 0.5 <= self.goal < 1:
            raise ValueError(f"the goal must lie in [0.5, 1), got {self.goal}")


def in_play(
    diagnosis, settings: SequentialSettings, energy: str = "linear-elastic"
) -> tuple[list[str], list]:
    """The named effects and the effects in play, each with its theta (named: fitted)
    or realistic magnitude: the named first, then the final round's score tests from
    the highest, then the rest of the library of the base ``energy`` (``settings.rivals``
    of the unnamed)."""
    library = effect_library(DIAGNOSIS.candidates, energy)
    # no press changes what one capture shows of a per-capture effect
    named = [n for n in diagnosis.selected if not library[n].per_case]
    ranked = [t.effect for t in sorted(final_scores(diagnosis), key=lambda t: t.log_p)]
    ranked += [n for n in library if n not in ranked]
    others = [n for n in ranked if n not in named and not library[n].per_case]
    final = diagnosis.steps[-1].fit
    effects = [(library[n], final.p[final.problem.slice_of(n)]) for n in named]
    effects += [(library[n], library[n].default_magnitude) for n in others[: settings.rivals]]
    return named, effects


def diagnosis_base(dataset, settings: SequentialSettings, log=None):
    """The diagnosis's base model (``FitSettings``), its fit when step 0 made one (the
    diagnosis starts from it), the dataset as it reads it (step 0's probe radius and
    shape) and step 0's record (None for the fixed volume)."""
    from experiments.diagnosis.diagnose import base_settings
    from experiments.fit.stepzero import chosen_base

    if settings.energy == AUTO:
        return chosen_base(dataset, settings.candidates.level, log or (lambda _: None))
    base = base_settings(settings.grid, "linear-elastic", settings.degrees, settings.margin)
    return base, None, dataset, None


def step(dataset, settings: SequentialSettings, remaining: int, log=print, progress=None) -> dict:
    """Diagnose ``dataset`` and choose the next press; the path's row (``press`` None when
    the loop stops: ``stop`` says why). ``progress`` receives step 0's and the
    diagnosis's lines."""
    from experiments.diagnosis.diagnose import diagnose_dataset
    from solvers.diagnosis.loop import diagnose

    begin = time.perf_counter()
    base, fitted, dataset, choice = diagnosis_base(dataset, settings, progress)
    loop = replace(DIAGNOSIS, level=settings.candidates.level)
    if fitted is None:
        diagnosis = diagnose_dataset(dataset, loop, log=progress, base=base)
    else:  # step 0's fit of the base model is the loop's start
        problem = fitted.problem
        diagnosis = diagnose(problem.base, problem.loads, loop, progress, fitted)
    document = diagnosis.document()
    diagnosed = time.perf_counter() - begin
    fit, sigma = diagnosis.steps[0].fit, float(dataset.noise_mm)
    model = fit.problem.model
    named, effects = in_play(diagnosis, settings, base.energy)
    family = len(effect_library(DIAGNOSIS.candidates, base.energy))
    marker_uv, _ = model.volume.project_to_outer(dataset.outer_rest.reshape(-1, 3))
    pool = InformationPool(fit, marker_uv, effects)
    own, seen = dataset_presses(dataset, model)
    own_index, candidates, _, _ = add_with_candidates(
        pool, dataset, settings.candidates, own, seen, log=lambda _: None
    )
    asked = questions(
        pool.layout,
        list(range(len(named))),
        loop.level / family,
        settings.goal,
        loop.rival_margin,
    )
    standing = standings(pool, asked, pool.totals(own_index), candidates, sigma, remaining)
    open_ = [s for s in standing if not s.answered and s.reachable]
    if diagnosis.unexplained and not open_:
        open_ = [s for s in standing if not s.answered]
    stop = None
    if not diagnosis.unexplained and not open_:
        stop = "explained"
    elif remaining <= 0:
        stop = "budget spent"
    elif not open_:
        stop = "unexplained, and no press answers a question"
    row = {
        "presses": dataset.n_loads,
        "selected": list(diagnosis.selected),
        "rivals": diagnosis.rivals,
        "unexplained": bool(diagnosis.unexplained),
        "rms_um": 1e3 * document["rms_after_mm"],
        "rms_before_um": 1e3 * document["rms_before_mm"],
        "noise_rms_um": 1e3 * document["noise_rms_mm"],
        "leading": _leading(diagnosis),
        "questions": [
            {
                "question": s.question.label(pool.layout),
                "value": s.value,
                "needed": s.question.needed,
                "answered": s.answered,
                "reachable": s.reachable,
            }
            for s in standing
        ],
        "open": [s.question.label(pool.layout) for s in open_],
        "stop": stop,
        "press": None,
        "diagnosis_s": diagnosed,
        "model": model_record(model, base.margin, dataset),
        "base_choice": choice,
    }
    if stop is None:
        unanswered = tuple(s.question for s in standing if not s.answered)
        criterion = Discrimination(unanswered, pool.layout, sigma)
        result = search(pool, criterion, 1, own_index, candidates)
        k = result.chosen[0]
        after = pool.totals(own_index + [k]).matrix()
        weakest = min(open_, key=lambda s: s.ratio)
        row["press"] = {
            **press_document(model, pool.presses[k]),
            "answers": weakest.question.label(pool.layout),
            "ratio_before": weakest.ratio,
            "ratio_after": weakest.question.value(after, pool.layout, sigma)
            / weakest.question.needed,
            "progress": result.score - criterion.score(pool.totals(own_index).matrix()),
        }
    row["wall_s"] = time.perf_counter() - begin
    return row


def final_scores(diagnosis) -> list:
    """The score tests of the last round of the loop that has them."""
    return next((s.scores for s in reversed(diagnosis.steps) if s.scores), [])


def _leading(diagnosis, count: int = 3) -> list[dict]:
    """The final round's highest score tests (the explanations still in play)."""
    scores = sorted(final_scores(diagnosis), key=lambda t: t.log_p)[:count]
    return [{"effect": t.effect, "statistic": t.statistic, "dof": t.dof} for t in scores]


def run(lab, settings: SequentialSettings | None = None, log=print) -> dict:
    """Run the loop against ``lab`` (``ContinuumLab``) from ``settings.start``; the path."""
    settings = settings or SequentialSettings()
    begin = time.perf_counter()
    dataset = lab.start(settings.start)
    path = []
    while True:
        log(f"diagnosing {dataset.n_loads} presses; the questions; the next press ...")
        row = step(dataset, settings, settings.budget - dataset.n_loads, log)
        path.append(row)
        named = ", ".join(row["selected"]) or "nothing"
        model = row["model"]
        log(
            f"{row['presses']} presses ({model['energy']} "
            f"{'x'.join(map(str, model['grid']))}, {model['margin_mm']:g} mm {model['support']} "
            f"band): {named} named, RMS {row['rms_um']:.1f} um "
            f"(noise {row['noise_rms_um']:.1f}), "
            f"{'unexplained' if row['unexplained'] else 'explained'}; "
            f"{len(row['open'])} open question(s) ({row['wall_s']:.0f} s)"
        )
        if row["press"] is None:
            log(f"stop: {row['stop']}")
            break
        press = row["press"]
        log(
            f"  press at ({press['contact_mm'][0]:.1f}, {press['contact_mm'][1]:.1f}) mm, "
            f"tilt {press['tilt_deg']:.0f} deg, |F| {np.linalg.norm(press['force_N']):.2f} N, "
            f"for '{press['answers']}'"
        )
        dataset = lab.press(press["contact_mm"], press["force_N"])
    last = path[-1]
    return {
        "schema": SCHEMA,
        "scenario": lab.scenario,
        "hidden_effect": lab.hidden,
        "start": settings.start,
        "budget": settings.budget,
        "energy": settings.energy,
        "grid": None if settings.energy == AUTO else list(settings.grid),
        "goal": settings.goal,
        "verdict": last["stop"],
        "presses": last["presses"],
        "named": last["selected"],
        "hidden_named": (lab.hidden in last["selected"]) if lab.hidden else None,
        "path": path,
        "wall_time_s": time.perf_counter() - begin,
    }
