"""The loop on continuum data (``dvs continuum-loop``): scikit-fem slabs with one hidden effect.

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

Magnitudes: E x 0.4..1.6 across the patch (the issue's gradient); a foundation of
0.01 N/mm^3 (5 mm of 50 kPa muscle); the library's realistic 2 mm offset, a probe
patch twice the declared radius, 0.3 tangential force per unit force and 0.1 mm
rigid motion per capture (``symbolic.effects``)."""

PHYSICS_OF_EVERY_SLAB = ("surrounding_tissue",)
"""Effects every slab has (its tissue goes on beyond the marked area)."""


@dataclass(frozen=True)
class ContinuumStudy:
    """What the study runs (lengths in mm)."""

    design: str = "diagnosis"
    grid: tuple[int, int, int] = (15, 15, 3)
    degrees: tuple[int, int, int] = (3, 3, 2)
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


def run_scenario(name: str, study: ContinuumStudy, solvers=None, log=None) -> dict:
    """Diagnose one scenario; the row of the table."""
    from experiments.diagnosis.diagnose import base_settings, diagnose_dataset

    dataset = scenario_dataset(name, study, solvers)
    begin = time.perf_counter()
    base = base_settings(study.grid, "linear-elastic", study.degrees)
    document = diagnose_dataset(dataset, log=log, base=base).document()
    hidden = SCENARIOS[name][2]
    selected = list(document["selected"])
    allowed = set(PHYSICS_OF_EVERY_SLAB) | ({hidden} if hidden else set())
    noise = document["noise_rms_mm"]
    return {
        "scenario": name,
        "design": study.design,
        "hidden_effect": hidden,
        "selected": selected,
        "hidden_selected": hidden in selected if hidden else None,
        "stand_ins": [e for e in selected if e not in allowed],
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


def table(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = [
        "| design | hidden | selected | RMS before -> after (um) | noise (um) | hidden found "
        "| stand-ins | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        found = "-" if row["hidden_effect"] is None else ("yes" if row["hidden_selected"] else "no")
        verdict = "unexplained" if row["unexplained"] else "explained"
        lines.append(
            f"| {row['design']} | {row['scenario']} | {', '.join(row['selected']) or '-'} | "
            f"{row['rms_before_um']:.1f} -> {row['rms_after_um']:.1f} | "
            f"{row['noise_rms_um']:.1f} | {found} | {', '.join(row['stand_ins']) or '-'} | "
            f"{verdict} |"
        )
    return "\n".join(lines) + "\n"


def build_parser(prog: str = "python -m experiments.diagnosis.continuum"):
    """The options of ``dvs continuum-loop``."""
    from experiments.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument("--design", choices=("paper", "diagnosis"), default="diagnosis")
    parser.add_argument(
        "--scenarios", default=",".join(SCENARIOS), help="comma list (default: all)"
    )
    parser.add_argument("--grid", default="15x15x3", help="control grid MxNxL (15x15x3)")
    parser.add_argument("--degrees", default="3x3x2", help="degrees PxQxR (3x3x2)")
    return parser


def main(argv: list[str] | None = None, prog: str = "python -m experiments.diagnosis.continuum"):
    """``dvs continuum-loop --out DIR``: rows.json and table.md."""
    from experiments.atomic import atomic_write_json, atomic_write_text
    from experiments.options import (
        UsageError,
        check_grid,
        check_output_dir,
        parse_degrees,
        parse_grid,
        run_guarded,
    )
    from experiments.phantom.fe import require_skfem

    args = build_parser(prog).parse_args(argv)

    def work() -> int:
        names = [n.strip() for n in args.scenarios.split(",") if n.strip()]
        unknown = sorted(set(names) - set(SCENARIOS))
        if unknown or not names:
            raise UsageError(f"--scenarios: unknown {unknown}; choose from {', '.join(SCENARIOS)}")
        degrees = parse_degrees(args.degrees)
        grid = check_grid(parse_grid(args.grid), degrees, args.grid)
        check_output_dir(args.out)
        require_skfem()
        study = ContinuumStudy(design=args.design, grid=grid, degrees=degrees)
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

    return run_guarded(prog, work)


if __name__ == "__main__":
    raise SystemExit(main())
