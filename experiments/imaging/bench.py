"""``dvs bench image``: fit time of stiffness imaging against the field size N, three methods.

One run, side by side: for each model grid and each N (a square field over the skin,
sqrt(N) nodes a side), the same regularised problem (eq. I8, H1, one fixed weight) is
solved by the simultaneous NLP (IPOPT), nested Gauss-Newton with adjoint products
(matrix-free CG) and nested Gauss-Newton with the implicit-function sensitivities
(J formed). Data: the scikit-fem slab with a stiff disc on the 10-load design, 0.02 mm
noise. A method whose run exceeds ``--budget`` seconds is not run at larger N.
Prints the table (and writes ``imagebench.json`` and ``imagebench.md`` with ``--out``).
"""

from __future__ import annotations

import time

import numpy as np

from experiments.command.options import (
    Command,
    UsageError,
    check_output_dir,
    make_parser,
    parse_degrees,
    parse_grid,
    parse_numbers,
    path_argument,
)

METHODS = ("simultaneous", "nested-adjoint", "nested-sensitivity")
WEIGHT_MM2 = 1000.0
"""beta of every run [mm^2]: the same problem for every method."""

MARGIN_MM = 10.0
"""Tissue beyond the markers in the model (docs/continuum.md: without it the field
absorbs the free sides' model error, and the methods stop at different maps)."""


def bench_data():
    """The scikit-fem slab with a stiff disc (E x 2, 10 mm) on the 10-load design."""
    from experiments.phantom.fe import ReferenceSlab, design_cases, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    slab = ReferenceSlab(elements=(12, 12, 2), inclusion=(6.0, -5.0, 10.0, 2.0))
    forces, contacts = design_cases("diagnosis", slab)
    return reference_dataset(
        slab, forces, contacts, 4.0, (9, 9), SimulationSettings(noise_mm=0.02, seed=3)
    )


def run(grids, sizes, methods=METHODS, budget: float = 900.0, log=print) -> list[dict]:
    """Rows {grid, N, method, seconds, iterations, success, max_diff_log_E}.

    The data are made once, the model once per grid; only the field changes with N.
    """
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem
    from solvers.imaging.estimate import SOLVERS
    from solvers.imaging.fieldproblem import FieldProblem
    from solvers.imaging.regularization import Tikhonov
    from symbolic.field import StiffnessField, tissue_lengths

    data = bench_data()
    rows, over_budget = [], set()
    for grid in grids:
        problem = build_problem(data, base_settings(grid, "linear-elastic", margin=MARGIN_MM))
        lengths = tissue_lengths(problem.model)
        for size in sizes:
            side = int(round(np.sqrt(size)))
            field = StiffnessField((side, side))
            fp, regularizer = FieldProblem(problem, field), Tikhonov(field, lengths)
            maps = {}
            for method in methods:
                if (grid, method) in over_budget:
                    log(f"  {'x'.join(map(str, grid))} N={fp.size} {method}: skipped (budget)")
                    continue
                begin = time.perf_counter()
                estimate = SOLVERS[method](fp, regularizer).solve(WEIGHT_MM2)
                seconds = time.perf_counter() - begin
                maps[method] = estimate.coefficients
                if seconds > budget:
                    over_budget.add((grid, method))
                rows.append(
                    {
                        "grid": "x".join(map(str, grid)),
                        "N": fp.size,
                        "method": method,
                        "seconds": seconds,
                        "iterations": estimate.iterations,
                        "success": estimate.success,
                    }
                )
                log(
                    f"  {rows[-1]['grid']} N={fp.size} {method}: {seconds:.1f} s, "
                    f"{estimate.iterations} iterations, {estimate.message}"
                )
            if maps:
                reference = next(iter(maps.values()))
                for row in rows[-len(maps) :]:
                    row["max_diff_log_E"] = float(np.abs(maps[row["method"]] - reference).max())
    return rows


IMAGING_GRID, IMAGING_DEGREES, IMAGING_FIELD = "27x27x4", "3x3x2", "16x16"
"""The imaging benchmark case: ``dvs image --grid 27x27x4 --degrees 3x3x2
--margin 10 --field 16x16`` (Morozov weight)."""


def timed_imaging(path: str) -> dict:
    """``dvs image`` on a saved dataset at ``IMAGING_GRID``, timed whole (build, fits,
    weight, Laplace, figures and outputs), with one factorisation of the model's K timed
    in the same process (the "x floor" unit) and the process's peak memory. Meant for a
    fresh process (``experiments.command.isolation.isolated``).
    """
    import contextlib
    import io
    import json
    import tempfile
    from pathlib import Path

    from experiments.command.isolation import factorisation_seconds, peak_mb
    from experiments.data.dataset import load_dataset
    from experiments.imaging.command import main
    from experiments.problem.fitting import FitSettings, build_problem

    with tempfile.TemporaryDirectory() as out:
        arguments = [path, "--energy", "linear-elastic", "--grid", IMAGING_GRID]
        arguments += ["--degrees", IMAGING_DEGREES]
        arguments += ["--margin", "10", "--field", IMAGING_FIELD, "--weight", "morozov"]
        arguments += ["--out", out]
        begin = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(arguments)
        wall = time.perf_counter() - begin
        record = json.loads((Path(out) / "image.json").read_text()) if code == 0 else {}
    grid, degrees = parse_grid(IMAGING_GRID), parse_degrees(IMAGING_DEGREES)
    settings = FitSettings(
        names=("E", "nu"), energy="linear-elastic", grid=grid, degrees=degrees, margin=10.0
    )
    stiffness = build_problem(load_dataset(path), settings).model.stiffness_matrix()
    return {
        "wall_s": wall,
        "exit": code,
        "factorisation_s": factorisation_seconds(stiffness),
        "peak_mb": peak_mb(),
        "beta_mm2": record.get("weight", {}).get("beta_mm2"),
        "chi2_over_n": record.get("residual", {}).get("chi2_over_n"),
        "stiffness_nonzeros": int(stiffness.nnz),
    }


def imaging_benchmark(log=print) -> dict:
    """The imaging row of the loop-speed benchmark (``make bench``, --diagnose):
    ``timed_imaging`` in a fresh process on the disc dataset of the weight study
    (``experiments.imaging.weightstudy.inclusion_datasets(7)``: scikit-fem slab with a
    stiff disc, 10 loads, 9 x 9 markers, 0.02 mm noise). Target: <= 120 s.
    """
    import tempfile
    from pathlib import Path

    from experiments.command.isolation import isolated
    from experiments.data.dataset import save_dataset
    from experiments.imaging.weightstudy import inclusion_datasets

    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "disc.npz")
        save_dataset(path, inclusion_datasets(7)[0])
        row = isolated(timed_imaging, path)
    floor = row["wall_s"] / row["factorisation_s"]
    log(
        f"image, scikit-fem slab with a stiff disc, 10 loads, {IMAGING_GRID} "
        f"({IMAGING_DEGREES}, 10 mm margin; K {row['stiffness_nonzeros'] / 1e6:.2f} M "
        f"nonzeros), --field {IMAGING_FIELD}, Morozov: {row['wall_s']:.1f} s (target 120 s, "
        f"{'met' if row['wall_s'] <= 120 and row['exit'] == 0 else 'MISSED'}), one "
        f"factorisation {row['factorisation_s']:.2f} s, x floor {floor:.0f}, peak "
        f"{row['peak_mb']:.0f} MB; beta {row['beta_mm2']:.3g} mm^2, chi2/n "
        f"{row['chi2_over_n']:.3f}"
    )
    return row


def table(rows: list[dict]) -> str:
    """Markdown: one line per grid and N, seconds per method, the fastest named."""
    methods = sorted({r["method"] for r in rows}, key=lambda m: METHODS.index(m))
    lines = [
        "| grid | N | " + " | ".join(methods) + " | fastest | max diff in log E |",
        "|---|---|" + "---|" * len(methods) + "---|---|",
    ]
    keys = sorted({(r["grid"], r["N"]) for r in rows}, key=lambda k: (k[0], k[1]))
    for grid, size in keys:
        chosen = {r["method"]: r for r in rows if (r["grid"], r["N"]) == (grid, size)}
        cells = [
            f"{chosen[m]['seconds']:.1f} s" + ("" if chosen[m]["success"] else " (failed)")
            if m in chosen
            else "-"
            for m in methods
        ]
        fastest = min(chosen.values(), key=lambda r: r["seconds"])["method"]
        spread = max(r["max_diff_log_E"] for r in chosen.values())
        lines.append(f"| {grid} | {size} | " + " | ".join(cells) + f" | {fastest} | {spread:.1e} |")
    return "\n".join(lines)


def build_parser(prog: str = "python -m experiments.imaging.bench"):
    """The options of ``dvs bench image`` (docs/cli.md)."""
    parser = make_parser(prog, "Stiffness imaging: fit time against N for three methods.")
    parser.add_argument("--grids", default="9x9x2,17x17x3", help="model grids, comma list")
    parser.add_argument("--sizes", default="16,64,256,1024", help="field sizes N (squares)")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma list")
    parser.add_argument("--budget", type=float, default=900.0, help="seconds; no larger N after")
    parser.add_argument("--out", type=path_argument, default=None, help="output directory")
    return parser


def work(args) -> int:
    """``dvs bench image``: exit 0, or 2 with one line for bad input."""
    grids = [parse_grid(g, "--grids") for g in args.grids.split(",") if g.strip()]
    if not grids:
        raise UsageError("--grids needs at least one grid, e.g. 9x9x2")
    sizes = parse_numbers(args.sizes, "--sizes", int)
    if any(n < 4 or n > 4096 or round(np.sqrt(n)) ** 2 != n for n in sizes):
        raise UsageError(f"--sizes must be squares in 4-4096, got {args.sizes!r}")
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise UsageError(f"--methods: unknown {', '.join(unknown)}; use {', '.join(METHODS)}")
    if not args.budget > 0:
        raise UsageError(f"--budget must be positive seconds, got {args.budget}")
    if args.out is not None:
        check_output_dir(args.out)
    from experiments.phantom.fe import require_skfem

    require_skfem()
    rows = run(grids, sizes, methods, args.budget, log=lambda line: print(line, flush=True))
    text = table(rows)
    print(text)
    if args.out is not None:
        from experiments.output.atomic import atomic_write_json, atomic_write_text

        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out / "imagebench.json", rows)
        atomic_write_text(args.out / "imagebench.md", text + "\n")
    return 0


main = Command("experiments.imaging.bench", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
