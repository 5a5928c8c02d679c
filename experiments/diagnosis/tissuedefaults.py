"""Default ``dvs diagnose`` on tissue the model was not tuned on: docs/results/tissue-defaults.md.

The datasets come from ``experiments.phantom.tissue`` (Q2 hexahedra, another generator
than the model was tuned on): eight patches (``ROWS``) that differ in how far the
tissue goes on beyond the markers and how it is held there, curvature, thickness, nu,
marker grid, design (2, 8 or 10 loads), probe shape and radius (never declared), and a
bilayer. ``injected_scenarios`` adds one departure to row A's patch. Each is diagnosed with the
defaults (``--energy auto``: step 0 of ``experiments.basemodel``, then the loop).

``print_table()`` prints the table of docs/results/tissue-defaults.md ("The eight rows,
no effect injected"), ``print_table(injected=True)`` its injected-effect rows;
``defaults_benchmark`` is its row in ``make bench`` (target: 2 minutes per dataset).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

FLAT_4030 = dict(marked=(40.0, 30.0))
ROWS = {  # name: (TissuePatch fields, design, markers, probe, radius [mm])
    "A": (
        dict(FLAT_4030, extent_mm=5.0, thickness=5.0, poisson=0.45, support="clamped"),
        "diagnosis",
        (11, 8),
        "disc",
        2.5,
    ),
    "B": (
        dict(marked=(40.0, 40.0), extent_mm=2.0, thickness=6.0, poisson=0.49, support="clamped"),
        "diagnosis",
        (9, 9),
        "gauss",
        4.0,
    ),
    "C": (
        dict(marked=(40.0, 40.0), extent_mm=20.0, thickness=4.0, poisson=0.40, support="free"),
        "paper",
        (9, 9),
        "disc",
        1.5,
    ),
    "D": (
        dict(
            FLAT_4030,
            extent_mm=5.0,
            thickness=7.0,
            poisson=0.47,
            support="elastic",
            curvature_radii=(60.0, 90.0),
        ),
        "corners",
        (11, 8),
        "disc",
        3.0,
    ),
    "E": (
        dict(
            FLAT_4030,
            extent_mm=10.0,
            thickness=8.0,
            poisson=0.45,
            support="free",
            curvature_radii=(80.0, 80.0),
        ),
        "diagnosis",
        (11, 8),
        "disc",
        2.0,
    ),
    "F": (
        dict(
            FLAT_4030,
            extent_mm=3.0,
            thickness=6.0,
            poisson=0.48,
            support="clamped",
            curvature_radii=(60.0, None),
        ),
        "paper",
        (11, 8),
        "gauss",
        3.5,
    ),
    "G": (
        dict(
            FLAT_4030,
            extent_mm=5.0,
            thickness=6.0,
            poisson=0.45,
            support="clamped",
            skin_mm=1.5,
            skin_ratio=5.0,
        ),
        "diagnosis",
        (11, 8),
        "disc",
        2.5,
    ),
    "H": (
        dict(
            FLAT_4030,
            extent_mm=8.0,
            thickness=7.0,
            poisson=0.47,
            support="elastic",
            curvature_radii=(70.0, 100.0),
            skin_mm=1.5,
            skin_ratio=5.0,
        ),
        "corners",
        (11, 8),
        "disc",
        2.0,
    ),
}
"""The rows of the table: E = 20 kPa, 4 layers of Q2 cells (2.5 mm over the markers,
graded x1.5 beyond), forces 0.17 and 0.25 N, 0.02 mm noise, seed = the row's index."""


def injected_scenarios() -> dict:
    """name -> (TissuePatch changes, ``fe.Departure`` fields, the effect that names it): the
    departures of ``experiments.diagnosis.continuumstudy.SCENARIOS`` but ``none``. The larger
    probe patch (twice the radius) is a departure only from a declared radius: its
    dataset declares 2.5 mm; the others declare none."""
    from experiments.diagnosis.continuumstudy import SCENARIOS

    return {name: value for name, value in SCENARIOS.items() if name != "none"}


def row_dataset(name: str, injected: str | None = None):
    """The dataset of a row (``ROWS``), or of its patch and design with one departure."""
    from experiments.phantom.fe import Departure
    from experiments.phantom.simulate import SimulationSettings
    from experiments.phantom.tissue import TissuePatch, tissue_cases, tissue_dataset

    fields, design, markers, probe, radius = ROWS[name]
    changes, departure, seed = {}, {}, sorted(ROWS).index(name)
    if injected is not None:
        scenarios = injected_scenarios()
        changes, departure, _ = scenarios[injected]
        seed = 11 + sorted(scenarios).index(injected)
    patch = TissuePatch(layers=4, **fields, **changes)
    forces, contacts = tissue_cases(design, patch)
    measurement = SimulationSettings(noise_mm=0.02, seed=seed)
    return tissue_dataset(
        patch,
        forces,
        contacts,
        radius,
        markers,
        probe,
        measurement=measurement,
        departure=Departure(**departure),
        declare_radius=injected == "larger_probe_patch",
    )


def timed_default_diagnosis(path: str) -> dict:
    """``dvs diagnose PATH`` with the defaults, timed whole (step 0, loop, figure and
    outputs), with the process's CPU time (what other jobs on a shared machine change
    least) and peak memory. Meant for a fresh process."""
    from experiments.basemodel.family import Surroundings
    from experiments.command.isolation import peak_mb
    from experiments.diagnosis.diagnose import run
    from solvers.diagnosis.report import presents_as_cause

    with tempfile.TemporaryDirectory() as out:
        begin, cpu = time.perf_counter(), time.process_time()
        document = run(path, Path(out), log=lambda *_: None)
        wall, cpu = time.perf_counter() - begin, time.process_time() - cpu
    choice = document["base_choice"]
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "step0_s": choice["seconds"],
        "peak_mb": peak_mb(),
        "base": choice["chosen"],
        "surroundings": choice["surroundings"],
        "revisits": [
            Surroundings(**r["after"]).label() for r in choice.get("revisits", []) if r["changed"]
        ],
        "grid": (choice["continuum"] or {}).get("grid") if choice["chosen"] != "dnurbs" else None,
        "resolution": [check["verdict"] for check in choice["resolution"]],
        "selected": list(document["selected"]),
        "rivals": document["rivals"],
        "unexplained": bool(document["unexplained"]),
        "base_p_value": document["steps"][0]["residual_p_value"],
        "presented_as_cause": presents_as_cause(document),
        "blind_spots": [spot["effect"] for spot in document["blind_spots"]],
        "rms_before_um": 1e3 * document["rms_before_mm"],
        "rms_after_um": 1e3 * document["rms_after_mm"],
        "noise_um": 1e3 * document["noise_rms_mm"],
    }


def timed_row(name: str, injected: str | None = None) -> dict:
    """``timed_default_diagnosis`` on a row's dataset, in a fresh process."""
    from experiments.command.isolation import isolated
    from experiments.data.dataset import save_dataset

    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "data.npz")
        save_dataset(path, row_dataset(name, injected))
        row = isolated(timed_default_diagnosis, path)
    return {"row": name, "injected": injected, **row}


def line(row: dict) -> str:
    """One table line (markdown)."""
    s = row["surroundings"] or {}
    base = row["base"]
    if base != "dnurbs":
        grid = "x".join(map(str, row["grid"]))
        radius, shape = s["probe_radius_mm"], s.get("probe_shape", "gauss")
        probe = f"{shape} declared" if radius is None else f"{shape} r {radius:.2f} mm"
        base += (
            f", {s['margin_mm']:g} mm {s['support']}, {probe}, {grid} "
            f"({', '.join(row['resolution'])})"
        )
    label = row["row"] if row["injected"] is None else f"{row['row']}: {row['injected']}"
    if row.get("revisits"):
        base += "; revisited -> " + ", ".join(row["revisits"])
    selected = ", ".join(row["selected"]) or "-"
    if row["rivals"]:
        selected += (
            " (or " + "; ".join(f"{k}: {', '.join(v)}" for k, v in row["rivals"].items()) + ")"
        )
    verdict = "unexplained" if row["unexplained"] else "explained"
    if not row["unexplained"] and row.get("blind_spots"):
        verdict += "; not ruled out: " + ", ".join(row["blind_spots"])
    return (
        f"| {label} | {base} | {row['rms_before_um']:.1f} -> {row['rms_after_um']:.1f} "
        f"| {selected} | {verdict} | {row['wall_s']:.0f} ({row['step0_s']:.0f}) "
        f"| {row['cpu_s']:.0f} |"
    )


HEADER = (
    "| data | base model (step 0) | RMS before -> after [um] (noise 49) | selected | verdict "
    "| time [s] (step 0) | CPU [s] |\n|---|---|---|---|---|---|---|"
)

TARGET_S = 120.0
"""The time target per dataset on the two-core machine [s]
(docs/results/tissue-defaults-speed.md)."""


def defaults_benchmark(rows=("A", "G"), log=print) -> list[dict]:
    """The defaults-on-tissue rows of ``make bench``: default ``dvs diagnose`` on rows
    A (monolayer) and G (bilayer), each in a fresh process; target 2 minutes."""
    out = []
    for name in rows:
        row = timed_row(name)
        met = "met" if row["wall_s"] <= TARGET_S else "MISSED"
        log(
            f"default diagnose, tissue row {name}: {row['wall_s']:.1f} s, CPU "
            f"{row['cpu_s']:.1f} s (step 0 "
            f"{row['step0_s']:.1f} s; target {TARGET_S:.0f} s, {met}), peak "
            f"{row['peak_mb']:.0f} MB; base {row['base']}, selected {row['selected']}, "
            f"{'unexplained' if row['unexplained'] else 'explained'}"
        )
        out.append(row)
    return out


def print_table(names=(), injected: bool = False, row: str = "A") -> list[dict]:
    """Print the table for the rows named (default all), or ``row``'s patch and design
    with each departure (``injected``; A: 10 loads, D: 8, C: the paper's 2), one line as
    each row finishes; returns the rows."""
    print(HEADER, flush=True)
    if injected:
        jobs = [(row, n) for n in names or injected_scenarios()]
    else:
        jobs = [(n, None) for n in names or ROWS]
    rows = []
    for name, departure in jobs:
        rows.append(timed_row(name, departure))
        print(line(rows[-1]), flush=True)
    return rows
