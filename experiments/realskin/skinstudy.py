"""Real in vivo skin in a two-pad extensometer: fit the volume spline model, close the loop.

For each case of ``skin-extensometer`` (healthy skin, a keloid scar):

1. fit the linear model (isotropic tension alpha, foundation alpha_w) to the DIC markers
   (x, y) and the moving pad's force of several frames jointly;
2. show what is left: the residual displacement field and the force curve;
3. find what the model lacks with score tests of the candidate extensions at the fit:
   stiffening k0 (eq. 1) and, where the geometry has a keloid outline, a second
   material inside it (stiffness ratio 1 + theta); add the best candidate while it is
   significant and worth it, and refit;
4. report the errors before and after, the estimates with standard errors, and a
   comparison with the original authors' 2D neo-Hookean fit;
5. map the stiffness cell by cell with its uncertainty (``cellmap.py``) and compare the
   map with the keloid outline and the model-free axial strain.

Run ``python -m experiments.realskin --out DIR``; see ``docs/realskin.md``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, astuple
from pathlib import Path

import numpy as np

from experiments.command.options import (
    Command,
    UsageError,
    check_output_dir,
    make_parser,
    parse_grid,
    parse_numbers,
    path_argument,
)
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.realskin.cellmap import map_report
from experiments.realskin.figures import case_figures, stage_summary
from experiments.realskin.scan import (
    SCAN,
    CellTerms,
    ScanResult,
    overlap,
    rect_indicator,
    with_region,
)
from experiments.realskin.setup import STIFFENING, RealSkinSettings, Setup, build
from experiments.realskin.skinloop import (
    NULL,
    close_the_loop,
    fit_base,
    fit_from_starts,
    likelihood_ratio,
)
from experiments.realskin.skintables import report
from experiments.realskin.stages import LABELS, StageFit
from experiments.realskin.strain import figure as strain_figure
from symbolic.skin_slab import REGION_RATIO

AUTHORS = {
    "healthy": {"E": (0.027, 0.031), "nu": (0.14, 0.22)},
    "keloid": {"E": (0.07, 0.14), "nu": (0.35, 0.42)},
}
"""The original authors' 2D neo-Hookean fits (README of the data; units probably N/mm)."""


# ------------------------------------------------------------------------ per-case run
def run_case(name: str, settings: RealSkinSettings, out: Path, log=print) -> dict:
    """Close the loop on one case and write its figures; returns its summary."""
    begin = time.perf_counter()
    setup = build(name, settings)
    with_dic = sum(d is not None for d in setup.data.displacement_mm)
    log(
        f"{name}: {len(setup.cases)} frames ({with_dic} with DIC), "
        f"{len(setup.data.reference_mm)} DIC points, force weight "
        f"{setup.weight:.1f} mm/N, DIC noise {setup.noise_mm:.4f} mm"
    )
    base_model = setup.model
    loop = close_the_loop(setup, settings, log)
    stages = loop["stages"]
    found = loop["found"]
    summary = {
        "dic_noise_mm": setup.noise_mm,
        "force_weight_mm_per_N": setup.weight,
        "frames": setup.data.labels,
        "pads_mm": [asdict(r) for r in setup.pad_rects],
        "stages": [stage_summary(setup, s) for s in stages],
        "rounds": [
            {
                "chosen": r["chosen"],
                "scores": {k: asdict(v) for k, v in r["scores"].items()},
                "scan_rect_mm": asdict(r["scan"].rect) if "scan" in r else None,
                "scan_candidates": r["scan"].n_candidates if "scan" in r else None,
            }
            for r in loop["rounds"]
        ],
        "diagnostics": {k: asdict(v) for k, v in loop["diagnostics"].items()},
        "likelihood_ratio": [likelihood_ratio(a, b) for a, b in zip(stages, stages[1:])],
        "authors": AUTHORS[name],
    }
    summary["heterogeneity"] = _heterogeneity(setup, found, stages)
    summary["map"] = _cell_map(setup, base_model, loop, settings, out / f"map_{name}.png")
    summary["variants"] = _variants(name, settings, stages, found, log)
    paths = case_figures(out, name, setup, stages, found)
    strain_path = out / f"strain_{name}.png"
    frames = [f for f in setup.data.frames if f is not None]
    strain_figure(setup.case, frames, strain_path, pads=setup.pad_rects)
    summary["figures"] = [p.name for p in [*paths, strain_path]] + [f"map_{name}.png"]
    setup.model = base_model
    summary["seconds"] = time.perf_counter() - begin
    first, last = stages[0], stages[-1]
    log(
        f"{name}: RMS displacement {first.rms_displacement_mm:.4f} -> "
        f"{last.rms_displacement_mm:.4f} mm (DIC noise {setup.noise_mm:.4f} mm), RMS force "
        f"{first.rms_force_n:.4f} -> {last.rms_force_n:.4f} N ({summary['seconds']:.0f} s)"
    )
    return summary


def _heterogeneity(setup: Setup, found: ScanResult | None, stages: list[StageFit]) -> dict | None:
    """The scanned region, its fitted ratio and, where there is one, its overlap with
    the keloid outline of ``geometry.geo`` (which the scan never saw)."""
    if found is None:
        return None
    ratio = stages[-1].as_dict().get(REGION_RATIO)
    out = {
        "rect_mm": asdict(found.rect),
        "cells": list(found.box),
        "candidates": found.n_candidates,
        "score": asdict(found.score),
        "ratio": ratio,
        "cell_statistic": found.cell_statistic.tolist(),
    }
    keloid = setup.case.geometry.keloid
    if keloid is not None:
        out["overlap"] = overlap(found.rect, keloid, setup.case.geometry.region)
    return out


def _cell_map(setup: Setup, base_model, loop: dict, settings: RealSkinSettings, path) -> dict:
    """The regularised cell map (``cellmap.py``) at the stage where the loop took the
    scanned region (the final stage if it did not), with the model without it."""
    index = next(
        (k for k, r in enumerate(loop["rounds"]) if r["chosen"] == SCAN), len(loop["stages"]) - 1
    )
    if setup.cells is None:
        setup.cells = CellTerms.build(base_model, setup.grid)
    return map_report(setup, base_model, loop["stages"][index], settings.bounds, setup.cells, path)


def _variants(name: str, settings: RealSkinSettings, stages: list[StageFit], found, log) -> dict:
    """The other boundary condition (linear and final effect set, the found region kept)
    and, where they differ from the pad files' (healthy skin: 32 mm gap), the .geo pads'
    linear fit."""
    out = {}
    other = "lateral" if settings.boundary == "inner" else "inner"
    variant = RealSkinSettings(**{**asdict(settings), "boundary": other})
    setup = build(name, variant)
    if found is not None:
        setup.model = with_region(setup.model, rect_indicator(setup.grid.region, found.rect))
    added = [n for n in stages[-1].names if n in NULL]
    linear = fit_base(setup, variant, f"{other} boundary, linear", log)
    out[f"{other}_linear"] = stage_summary(setup, linear)
    if added:
        start = {**linear.as_dict(), **{n: NULL[n] for n in added}}
        final = fit_from_starts(
            setup,
            linear.names + tuple(added),
            start,
            variant,
            f"{other} boundary, + " + ", ".join(LABELS[n] for n in added),
            log,
        )
        out[f"{other}_final"] = stage_summary(setup, final)
    geometry = setup.case.geometry
    shift = np.abs(np.array(astuple(geometry.pad_moving)) - astuple(setup.pad_rects[0]))
    if shift.max() > 0.1:  # the .geo pads differ from the pad files (healthy skin)
        setup = build(name, settings, (geometry.pad_moving, geometry.pad_fixed))
        label = f"geometry.geo pads ({geometry.pad_gap_mm:.0f} mm gap), linear"
        linear = fit_base(setup, settings, label, log)
        out["geo_pads_linear"] = stage_summary(setup, linear)
    return out


# ---------------------------------------------------------------------------- the study
def run(
    out: Path, settings: RealSkinSettings | None = None, cases=("healthy", "keloid"), log=print
) -> dict:
    """Both cases: fits, scores, figures, ``summary.json`` and ``parameters.md`` in ``out``.

    Returns
    -------
    dict
        Per case the summary written to ``summary.json`` (errors before and after,
        estimates with standard errors, scores, variants), plus the settings and runtime.
    """
    settings = settings or RealSkinSettings()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    begin = time.perf_counter()
    summary = {"settings": asdict(settings)}
    for name in cases:
        summary[name] = run_case(name, settings, out, log)
    summary["seconds"] = time.perf_counter() - begin
    atomic_write_json(out / "summary.json", summary)
    atomic_write_text(out / "parameters.md", report(summary))
    log(
        f"wrote {out / 'summary.json'}, {out / 'parameters.md'} and the figures "
        f"({summary['seconds']:.0f} s)"
    )
    return summary


def build_parser(prog: str = "python -m experiments.realskin"):
    """The options of ``dvs realskin fit``."""
    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=path_argument, default=Path("realskin-output"), help="directory"
    )
    parser.add_argument(
        "--boundary", choices=("inner", "lateral"), default="inner", help="what is held fixed"
    )
    parser.add_argument(
        "--stiffening", choices=tuple(STIFFENING), default="exponential", help="s(eps) of eq. 1"
    )
    parser.add_argument(
        "--grid", default="21x11", metavar="MxN", help="control grid of the slab (21x11)"
    )
    parser.add_argument(
        "--case", choices=("healthy", "keloid"), action="append", help="repeatable; default both"
    )
    parser.add_argument(
        "--k0-starts", default="", metavar="LIST", help="start values of k0, e.g. 0,1,3,10"
    )
    return parser


def work(args) -> int:
    """``dvs realskin fit --out DIR [--boundary lateral] [--case keloid]``."""
    low, high = RealSkinSettings().bounds["k0"]
    k0_starts = parse_numbers(args.k0_starts, "--k0-starts")
    if not all(low <= v <= high for v in k0_starts):
        raise UsageError(f"--k0-starts takes numbers in [{low:g}, {high:g}]")
    grid = parse_grid(args.grid, sizes=2)
    if not all(4 <= size <= 101 for size in grid):
        raise UsageError(f"--grid takes MxN with M and N in 4-101, got {args.grid!r}")
    settings = RealSkinSettings(
        boundary=args.boundary,
        stiffening=args.stiffening,
        grid=grid,
        starts={"k0": k0_starts} if k0_starts else {},
    )
    run(check_output_dir(args.out), settings, tuple(args.case or ("healthy", "keloid")))
    return 0


main = Command("experiments.realskin.skinstudy", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
