"""The design rows of ``make bench`` (the loop-speed issue): ``dvs design`` over 250
candidates and one step of ``dvs design --sequential``, at 27 x 27 x 4; and ``dvs next``
with its defaults (step 0 chooses the model) on a 10-load dataset.

The model is the continuum study's (``experiments.diagnosis.continuumstudy.ContinuumStudy``:
the linear-elastic volume spline, degrees 3 x 3 x 2, 10 mm of tissue beyond the
markers). Each row runs in a fresh process (``experiments.command.isolation.isolated``) and
reports its wall time, its "x floor" (the time over one factorisation of the same K,
timed in the same process, so that a loaded machine scales both) and the process's
peak memory (``ru_maxrss``).

Targets: the search <= 60 s; a 10-press sequential run <= 15 minutes, i.e. about
100 s for each of its 9 steps (from 2 presses to 10). A full run is too long for
``make bench``: the row is the first step (2 presses, nothing named yet; later
steps diagnose more presses and refit named effects), and the 10-press run is
measured once in docs/results/sequential-loop.md.
"""

from __future__ import annotations

import time

from experiments.command.isolation import factorisation_seconds, peak_mb

SEARCH_TARGET_S = 60.0
"""``dvs design`` over 250 candidates at 27 x 27 x 4 [s]."""

RUN_TARGET_S = 900.0
"""One 10-press ``dvs design --sequential`` run at 27 x 27 x 4 [s]."""

STEP_TARGET_S = RUN_TARGET_S / 9
"""A step's share of the run: 9 steps from the paper's 2 presses to 10 [s]."""

NEXT_TARGET_S = 60.0
"""``dvs next`` on a 10-load dataset, step 0 included [s] (the adaptive-experiments issue)."""


def timed_search(path: str, study) -> dict:
    """``plan`` (the work of ``dvs design PATH --energy linear-elastic``: base fit,
    information of the dataset's presses and 250 candidates, search for 10) at the
    study's model, timed, with one factorisation of its K and the peak memory. Meant
    for a fresh process."""
    from experiments.data.dataset import load_dataset
    from experiments.design.plan import DesignSettings, plan
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem

    settings = base_settings(study.grid, "linear-elastic", study.degrees, study.margin)
    dataset = load_dataset(path)
    begin = time.perf_counter()
    document = plan(dataset, DesignSettings(), log=lambda _: None, base=settings).document
    wall = time.perf_counter() - begin
    stiffness = build_problem(dataset, settings).model.stiffness_matrix()
    return {
        "wall_s": wall,
        "factorisation_s": factorisation_seconds(stiffness),
        "peak_mb": peak_mb(),
        "candidates": document["candidates"]["count"],
        "score": document["search"]["score"],
        "presses": [(p["uv"], p["force_N"]) for p in document["presses"]],
    }


def timed_step(scenario: str, study) -> dict:
    """The first step of the sequential loop on ``scenario`` (the paper's 2 presses:
    diagnosis, questions, information of 45 candidates, the next press) at the study's
    model, timed, with one factorisation of its K and the peak memory. The lab's FE
    data are made before the clock starts. Meant for a fresh process."""
    from experiments.design.lab import ContinuumLab
    from experiments.design.sequential import SequentialSettings, step
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem

    settings = SequentialSettings(
        energy="linear-elastic", grid=study.grid, degrees=study.degrees, margin=study.margin
    )
    dataset = ContinuumLab(scenario).start(settings.start)
    begin = time.perf_counter()
    row = step(dataset, settings, settings.budget - dataset.n_loads, log=lambda _: None)
    wall = time.perf_counter() - begin
    base = base_settings(study.grid, "linear-elastic", study.degrees, study.margin)
    stiffness = build_problem(dataset, base).model.stiffness_matrix()
    return {
        "wall_s": wall,
        "diagnosis_s": row["diagnosis_s"],
        "factorisation_s": factorisation_seconds(stiffness),
        "peak_mb": peak_mb(),
        "press": row["press"],
        "selected": row["selected"],
    }


def _verdict(value: float, target: float) -> str:
    return "met" if value <= target else "MISSED"


def design_search_benchmark(scenario: str = "tilted_force", log=print) -> dict:
    """The "design search" row: ``timed_search`` on the 10-load scikit-fem dataset of
    ``scenario`` (the diagnosis row's data) at 27 x 27 x 4."""
    from experiments.diagnosis.continuumstudy import ContinuumStudy, timed_on_scenario

    row = timed_on_scenario(timed_search, scenario, ContinuumStudy())
    log(
        f"design search, {row['candidates']} candidates, 10 presses, scikit-fem slab with "
        f"{scenario}, 27x27x4 (3x3x2, 10 mm margin): {row['wall_s']:.1f} s (target "
        f"{SEARCH_TARGET_S:.0f} s, {_verdict(row['wall_s'], SEARCH_TARGET_S)}), one "
        f"factorisation {row['factorisation_s']:.2f} s, x floor "
        f"{row['wall_s'] / row['factorisation_s']:.0f}, peak {row['peak_mb']:.0f} MB"
    )
    return row


def sequential_step_benchmark(scenario: str = "stiffness_gradient", log=print) -> dict:
    """The "one sequential step" row: ``timed_step`` on ``scenario`` at 27 x 27 x 4."""
    from experiments.command.isolation import isolated
    from experiments.diagnosis.continuumstudy import ContinuumStudy

    row = isolated(timed_step, scenario, ContinuumStudy())
    row["scenario"] = scenario
    press = row["press"]
    chosen = f"press for '{press['answers']}'" if press else "stopped"
    log(
        f"one sequential step, {scenario}, the paper's 2 presses, 45 candidates, 27x27x4 "
        f"(3x3x2, 10 mm margin): {row['wall_s']:.1f} s (diagnosis {row['diagnosis_s']:.1f} s; "
        f"target {STEP_TARGET_S:.0f} s, a 10-press run's 15 minutes over its 9 steps, "
        f"{_verdict(row['wall_s'], STEP_TARGET_S)}), one factorisation "
        f"{row['factorisation_s']:.2f} s, x floor {row['wall_s'] / row['factorisation_s']:.0f}, "
        f"peak {row['peak_mb']:.0f} MB; {chosen}"
    )
    return row


def timed_next(path: str, study) -> dict:
    """The work of ``dvs next PATH --budget 5`` with its defaults (step 0, the diagnosis,
    the questions, 45 candidates), timed, with one factorisation of the K of the volume
    step 0 chose and the peak memory. Meant for a fresh process, which it sets up as the
    ``dvs`` console script does (``experiments.command.process``)."""
    import contextlib
    import io
    import json
    import tempfile
    from pathlib import Path

    from experiments.command.process import configure
    from experiments.data.dataset import load_dataset
    from experiments.design.nextpress import main
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem

    configure()
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "next"
        begin = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = main([path, "--budget", "5", "--out", str(out)])
        wall = time.perf_counter() - begin
        if code != 0:
            raise RuntimeError(f"dvs next exited {code}")
        document = json.loads((out / "next.json").read_text())
    model = document["model"]
    settings = base_settings(model["grid"], "linear-elastic", model["degrees"], model["margin_mm"])
    stiffness = build_problem(load_dataset(path), settings).model.stiffness_matrix()
    return {
        "wall_s": wall,
        "factorisation_s": factorisation_seconds(stiffness),
        "peak_mb": peak_mb(),
        "model": model,
        "stop": document["stop"],
        "presses": document["presses"],
    }


def next_benchmark(scenario: str = "none", log=print) -> dict:
    """The "dvs next" row: ``timed_next`` on the 10-load scikit-fem dataset of ``scenario``."""
    from experiments.diagnosis.continuumstudy import ContinuumStudy, timed_on_scenario

    row = timed_on_scenario(timed_next, scenario, ContinuumStudy())
    grid = "x".join(map(str, row["model"]["grid"]))
    answer = f"stop: {row['stop']}" if row["stop"] else "a press proposed"
    log(
        f"dvs next, 10 presses of the scikit-fem slab ({scenario}), defaults (step 0 chose "
        f"{grid}): {row['wall_s']:.1f} s (target {NEXT_TARGET_S:.0f} s, "
        f"{_verdict(row['wall_s'], NEXT_TARGET_S)}), one factorisation of its K "
        f"{row['factorisation_s']:.2f} s, x floor {row['wall_s'] / row['factorisation_s']:.0f}, "
        f"peak {row['peak_mb']:.0f} MB; {answer}"
    )
    return row
