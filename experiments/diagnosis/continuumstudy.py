"""The loop on continuum data (``dvs study continuum``): scikit-fem slabs with one hidden effect.

Data: ``experiments.phantom.fe``, quadratic tetrahedra on a 60 x 60 x 5 mm slab (the
tissue goes on 10 mm beyond the 40 x 40 mm marked area, fixed at its base and far
faces), E = 20 kPa, nu = 0.45, 9 x 9 markers, probes of 4 mm radius, 0.02 mm noise.
Each scenario hides one departure from what the dataset declares (``SCENARIOS``); the
loop runs on the linear-elastic base model (``symbolic.continuum_model``) at the grid
given. A row records what the loop selected, the RMS before and after against the
noise level, whether the hidden effect was selected, and which other effects were
added (stand-ins; ``surrounding_tissue`` is physics every slab has, not a stand-in).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.output.tables import table_lines, with_rivals
from experiments.phantom.fe import Departure, ReferenceSlab, design_cases

SCENARIOS = {
    "none": ({}, {}, None),
    "stiffness_gradient": ({"gradient": 0.6}, {}, "heterogeneity"),
    "compliant_base": ({"base_spring": 0.01}, {}, "base_compliance"),
    "contact_offset": ({}, {"contact_offset_mm": (1.2, 1.6)}, "contact_offset"),
    "larger_probe_patch": ({}, {"radius_factor": 2.0}, "contact_patch"),
    "tilted_force": ({}, {"tangential": (0.24, 0.18)}, "force_direction"),
    "rigid_motion": ({}, {"rigid_mm": 0.1}, "rigid_motion"),
}
"""name -> (slab changes, load or measurement departure, the effect that names it).

Magnitudes: E x 0.4..1.6 across the patch (the study's gradient); a foundation of
0.01 N/mm^3 (5 mm of 50 kPa muscle); the library's realistic 2 mm offset, a probe
patch twice the declared radius, 0.3 tangential force per unit force and 0.1 mm
rigid motion per capture (``symbolic.effects``)."""

PHYSICS_OF_EVERY_SLAB = ("surrounding_tissue",)
"""Effects every slab has (its tissue goes on beyond the marked area)."""


@dataclass(frozen=True)
class ContinuumStudy:
    """What the study runs (lengths in mm)."""

    design: str = "diagnosis"
    grid: tuple[int, int, int] = (27, 27, 4)
    degrees: tuple[int, int, int] = (3, 3, 2)
    margin: float = 10.0
    radius: float = 4.0
    noise_mm: float = 0.02
    seed: int = 1
    slab: ReferenceSlab = ReferenceSlab(elements=(24, 24, 4))


def scenario_dataset(name: str, study: ContinuumStudy, solvers: dict | None = None):
    """The dataset of one scenario (``solvers`` caches the FE factorisation per slab)."""
    from experiments.phantom.fe import SlabSolution, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    slab_changes, departure, _ = SCENARIOS[name]
    slab = replace(study.slab, **slab_changes)
    solvers = {} if solvers is None else solvers
    if slab not in solvers:
        solvers[slab] = SlabSolution(slab)
    forces, contacts = design_cases(study.design, slab)
    measurement = SimulationSettings(noise_mm=study.noise_mm, seed=study.seed)
    return reference_dataset(
        slab,
        forces,
        contacts,
        study.radius,
        (9, 9),
        measurement,
        Departure(**departure),
        solvers[slab],
    )


def timed_diagnosis(path: str, study: ContinuumStudy) -> dict:
    """``dvs diagnose`` on a saved dataset at the study's grid, timed whole (build, loop,
    figure and outputs), with one factorisation of its K timed in the same process (the
    "x floor" unit) and the process's peak memory. Meant for a fresh process
    (``experiments.command.isolation.isolated``).
    """
    import tempfile

    from experiments.command.isolation import factorisation_seconds, peak_mb
    from experiments.data.dataset import load_dataset
    from experiments.diagnosis.diagnose import base_settings, run
    from experiments.problem.fitting import build_problem

    settings = base_settings(study.grid, "linear-elastic", study.degrees, study.margin)
    with tempfile.TemporaryDirectory() as out:
        begin = time.perf_counter()
        document = run(path, Path(out), log=lambda *_: None, base=settings)
        wall = time.perf_counter() - begin
    stiffness = build_problem(load_dataset(path), settings).model.stiffness_matrix()
    return {
        "wall_s": wall,
        "factorisation_s": factorisation_seconds(stiffness),
        "peak_mb": peak_mb(),
        "selected": list(document["selected"]),
        "unexplained": bool(document["unexplained"]),
        "stiffness_nonzeros": int(stiffness.nnz),
    }


def timed_on_scenario(timed, scenario: str, study: ContinuumStudy) -> dict:
    """``timed(path, study)`` in a fresh process (``experiments.command.isolation.isolated``) on
    the scenario's dataset saved to a temporary file; the row gains its ``scenario``."""
    import tempfile

    from experiments.command.isolation import isolated
    from experiments.data.dataset import save_dataset

    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / f"{scenario}.npz")
        save_dataset(path, scenario_dataset(scenario, study))
        row = isolated(timed, path, study)
    row["scenario"] = scenario
    return row


def diagnosis_benchmark(scenario: str = "tilted_force", log=print) -> dict:
    """The loop-speed row of ``make bench``: ``timed_diagnosis`` at 27 x 27 x 4 (degrees
    3 x 3 x 2, 10 mm margin) on a 10-load scikit-fem dataset with one hidden effect.

    Targets (the loop-speed issue): <= 60 s, <= 40 factorisations' worth, <= 3 GB.
    """
    study = ContinuumStudy()
    row = timed_on_scenario(timed_diagnosis, scenario, study)
    floor = row["wall_s"] / row["factorisation_s"]
    log(
        f"diagnose, scikit-fem slab with {scenario}, 10 loads, 27x27x4 (3x3x2, 10 mm margin; "
        f"K {row['stiffness_nonzeros'] / 1e6:.2f} M nonzeros): {row['wall_s']:.1f} s "
        f"(target 60 s, {'met' if row['wall_s'] <= 60 else 'MISSED'}), one factorisation "
        f"{row['factorisation_s']:.2f} s, x floor {floor:.0f} (target 40, "
        f"{'met' if floor <= 40 else 'MISSED'}), peak {row['peak_mb']:.0f} MB (target 3072, "
        f"{'met' if row['peak_mb'] <= 3072 else 'MISSED'}); selected {row['selected']}"
    )
    return row


def run_scenario(name: str, study: ContinuumStudy, solvers=None, log=None) -> dict:
    """Diagnose one scenario; the row of the table."""
    from experiments.diagnosis.diagnose import base_settings, diagnose_dataset

    dataset = scenario_dataset(name, study, solvers)
    begin = time.perf_counter()
    base = base_settings(study.grid, "linear-elastic", study.degrees, study.margin)
    document = diagnose_dataset(dataset, log=log, base=base).document()
    hidden = SCENARIOS[name][2]
    selected = list(document["selected"])
    allowed = set(PHYSICS_OF_EVERY_SLAB) | ({hidden} if hidden else set())
    rivals = document.get("rivals", {})
    noise = document["noise_rms_mm"]
    return {
        "scenario": name,
        "design": study.design,
        "hidden_effect": hidden,
        "selected": selected,
        "hidden_selected": hidden in selected if hidden else None,
        # an effect the data cannot tell from the hidden one is reported as "X or
        # hidden", not as a cause: ambiguous, not a stand-in
        "stand_ins": [e for e in selected if e not in allowed and hidden not in rivals.get(e, [])],
        "rivals": rivals,
        "hidden_among_rivals": bool(hidden) and any(hidden in r for r in rivals.values()),
        "rms_before_um": 1e3 * document["rms_before_mm"],
        "rms_after_um": 1e3 * document["rms_after_mm"],
        "noise_rms_um": 1e3 * noise,
        "within_1_1_noise": document["rms_after_mm"] <= 1.1 * noise,
        "unexplained": document["unexplained"],
        "estimates": {
            k: v["value"] for k, v in document["steps"][-1].get("parameters", {}).items()
        },
        "wall_s": time.perf_counter() - begin,
    }


MODEL_ERROR_CASES = (
    (60.0, 0.0, (15, 15, 3)),
    (60.0, 0.0, (27, 27, 3)),
    (60.0, 0.0, (27, 27, 4)),
    (60.0, 10.0, (19, 19, 4)),
    (60.0, 10.0, (27, 27, 3)),
    (60.0, 10.0, (27, 27, 4)),
    (60.0, 10.0, (33, 33, 4)),
    (60.0, 5.0, (27, 27, 4)),
    (60.0, 15.0, (27, 27, 4)),
    (80.0, 10.0, (27, 27, 4)),
)
"""(slab extent [mm], model margin [mm], grid) of ``model_error_rows``: the volume ending
at the markers on any grid, then margins, grids, and a slab whose tissue goes on 20 mm
beyond the markers while the model's margin stays 10 mm."""


def model_error_rows(study: ContinuumStudy, cases=MODEL_ERROR_CASES, log=print) -> list[dict]:
    """Noise-free base fits (no loop): the model error of the base model itself.

    The slab's cells keep their size (2.5 mm) whatever its extent; the scenario is
    ``none``; ``study`` gives the design, the degrees and the probe.
    """
    from experiments.phantom.fe import reference_dataset
    from experiments.phantom.simulate import SimulationSettings
    from experiments.problem.fitting import build_problem, solve

    from .diagnose import base_settings

    clean = SimulationSettings(noise_mm=1e-6, seed=study.seed)
    datasets, rows = {}, []
    for extent, margin, grid in cases:
        if extent not in datasets:
            cells = int(round(study.slab.elements[0] * extent / study.slab.lengths[0]))
            slab = replace(study.slab, lengths=(extent, extent, study.slab.lengths[2]))
            slab = replace(slab, elements=(cells, cells, study.slab.elements[2]))
            forces, contacts = design_cases(study.design, slab)
            datasets[extent] = reference_dataset(
                slab, forces, contacts, study.radius, (9, 9), clean, Departure()
            )
        begin = time.perf_counter()
        problem = build_problem(
            datasets[extent], base_settings(grid, "linear-elastic", study.degrees, margin)
        )
        result = solve(problem, "nested")
        observed = sum(case.n_observations for case in problem.cases)
        rows.append(
            {
                "slab_extent_mm": extent,
                "tissue_beyond_markers_mm": (extent - study.slab.marked[0]) / 2,
                "margin_mm": margin,
                "grid": list(grid),
                "model_error_um": 1e3 * float(np.sqrt(2 * result.cost / observed)),
                **{k: float(v) for k, v in result.as_dict().items()},
                "wall_s": time.perf_counter() - begin,
            }
        )
        log(
            f"extent {extent:g} mm, margin {margin:g} mm, grid {'x'.join(map(str, grid))}: "
            f"model error {rows[-1]['model_error_um']:.1f} um, E {rows[-1]['E']:.2f} kPa, "
            f"nu {rows[-1]['nu']:.4f}"
        )
    return rows


def model_error_table(rows: list[dict]) -> str:
    """The rows of ``model_error_rows`` as a Markdown table."""
    header = (
        "tissue beyond markers (mm) | margin (mm) | grid | model error (um, 3D RMS) | E (kPa) | nu"
    )
    cells = [
        (
            f"{row['tissue_beyond_markers_mm']:g}",
            f"{row['margin_mm']:g}",
            "x".join(map(str, row["grid"])),
            f"{row['model_error_um']:.1f}",
            f"{row['E']:.2f}",
            f"{row['nu']:.4f}",
        )
        for row in rows
    ]
    return "\n".join(table_lines(header, cells)) + "\n"


def table(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    header = (
        "design | hidden | selected | RMS before -> after (um) | noise (um) "
        "| hidden found | stand-ins | verdict"
    )
    cells = []
    for row in rows:
        found = "-" if row["hidden_effect"] is None else ("yes" if row["hidden_selected"] else "no")
        if row.get("hidden_among_rivals") and not row["hidden_selected"]:
            found = "ambiguous"
        cells.append(
            (
                row["design"],
                row["scenario"],
                with_rivals(row["selected"], row.get("rivals", {})),
                f"{row['rms_before_um']:.1f} -> {row['rms_after_um']:.1f}",
                f"{row['noise_rms_um']:.1f}",
                found,
                ", ".join(row["stand_ins"]) or "-",
                "unexplained" if row["unexplained"] else "explained",
            )
        )
    return "\n".join(table_lines(header, cells)) + "\n"


def build_parser(prog: str = "python -m experiments.diagnosis.continuumstudy"):
    """The options of ``dvs study continuum``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument("--design", choices=("paper", "diagnosis"), default="diagnosis")
    parser.add_argument(
        "--scenarios", default=",".join(SCENARIOS), help="comma list (default: all)"
    )
    parser.add_argument("--grid", default="27x27x4", help="control grid MxNxL (27x27x4)")
    parser.add_argument("--degrees", default="3x3x2", help="degrees PxQxR (3x3x2)")
    parser.add_argument(
        "--margin", type=float, default=10.0, help="tissue beyond the markers [mm] (10)"
    )
    parser.add_argument(
        "--model-error",
        action="store_true",
        help="instead of the loop: noise-free base fits over margins and grids (model_error.md)",
    )
    return parser


def work(args) -> int:
    """``dvs study continuum --out DIR``: rows.json and table.md."""
    from experiments.command.options import (
        UsageError,
        check_grid,
        check_margin,
        check_output_dir,
        parse_degrees,
        parse_grid,
    )
    from experiments.output.atomic import atomic_write_json, atomic_write_text
    from experiments.phantom.fe import require_skfem

    names = [n.strip() for n in args.scenarios.split(",") if n.strip()]
    unknown = sorted(set(names) - set(SCENARIOS))
    if unknown or not names:
        raise UsageError(f"--scenarios: unknown {unknown}; choose from {', '.join(SCENARIOS)}")
    degrees = parse_degrees(args.degrees)
    grid = check_grid(parse_grid(args.grid), degrees, args.grid)
    margin = check_margin(args.margin)
    check_output_dir(args.out)
    require_skfem()
    study = ContinuumStudy(design=args.design, grid=grid, degrees=degrees, margin=margin)
    if args.model_error:
        rows = model_error_rows(study, log=lambda line: print(line, flush=True))
        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_json(Path(args.out) / "model_error.json", rows)
        atomic_write_text(Path(args.out) / "model_error.md", model_error_table(rows))
        print(model_error_table(rows))
        return 0
    rows, solvers = [], {}
    for name in names:
        print(f"{name}: scikit-fem data, {args.design} design; the loop", flush=True)
        rows.append(run_scenario(name, study, solvers, lambda line: print("  " + line)))
        row = rows[-1]
        print(
            f"  -> {row['selected']}, {row['rms_before_um']:.1f} -> "
            f"{row['rms_after_um']:.1f} um (noise {row['noise_rms_um']:.1f}), "
            f"{row['wall_s']:.0f} s",
            flush=True,
        )
    Path(args.out).mkdir(parents=True, exist_ok=True)
    atomic_write_json(Path(args.out) / "rows.json", rows)
    atomic_write_text(Path(args.out) / "table.md", table(rows))
    print(table(rows))
    return 0


main = Command("experiments.diagnosis.continuumstudy", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
