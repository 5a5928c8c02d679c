"""``dvs realskin fit``: the real skin's two-pad extensometer through the shared loop.

For each case of ``skin-extensometer`` (healthy skin, a keloid scar) the base problem of
``experiments.realskin.setup`` (the isotropic slab, alpha_u and alpha_w) goes through
``solvers.diagnosis.diagnose`` with the real skin's candidates: the same selection rule
as every dataset (docs/diagnosis.md, "The loop and its selection rule"), its folds the
fitted frames. Writes ``DIR/<case>/diagnosis.json`` (schema ``dvs-diagnosis/1``, with
the observations and the stiffer region's overlap with the keloid's outline),
``DIR/<case>/report.md`` and figures, and ``DIR/summary.json``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from experiments.command.options import Command, UsageError, check_output_dir, make_parser
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.realskin.figures import case_figures
from experiments.realskin.geometry import points_in_polygon
from experiments.realskin.setup import CANDIDATES, RealSkinSettings, Setup, build
from solvers.diagnosis.loop import diagnose
from solvers.diagnosis.record import DiagnosisSettings
from solvers.diagnosis.report import report, verdict

CASES = ("healthy", "keloid")
REGION = "stiffer_region"
LOCATED = 0.5
"""IoU with the keloid's outline from which a stiffer region counts as located."""


def overlap(rect_mm, polygon: np.ndarray, step: float = 0.1) -> dict:
    """IoU, the fraction of a rectangle (x0, x1, y0, y1) [mm] inside a polygon, the
    fraction of the polygon covered (recall), on a ``step`` [mm] grid."""
    x0, x1, y0, y1 = rect_mm
    lo, hi = np.minimum(polygon.min(axis=0), (x0, y0)), np.maximum(polygon.max(axis=0), (x1, y1))
    x, y = np.meshgrid(np.arange(lo[0], hi[0], step), np.arange(lo[1], hi[1], step))
    points = np.column_stack([x.ravel(), y.ravel()])
    inside = points_in_polygon(points, polygon)
    box = (points[:, 0] >= x0) & (points[:, 0] <= x1) & (points[:, 1] >= y0) & (points[:, 1] <= y1)
    both = float(np.sum(inside & box))
    return {
        "iou": both / max(float(np.sum(inside | box)), 1.0),
        "inside_fraction": both / max(float(box.sum()), 1.0),
        "recall": both / max(float(inside.sum()), 1.0),
    }


def region_record(setup: Setup, document: dict) -> dict | None:
    """The stiffer region the loop named, or the best one its score tests found: its
    rectangle [mm], score, overlap with the keloid's outline and whether it is named.
    None when the region was not a candidate."""
    steps = document["steps"]
    named = [k for k, s in enumerate(steps) if s["effect"] == REGION]
    rounds = [k - 1 for k in named] or range(len(steps))
    tests = [
        t
        for k in rounds
        for t in steps[k]["score_tests"]
        if t["effect"] == REGION and t.get("detail", {}).get("rect_uv")
    ]
    if not tests:
        return None
    test = max(tests, key=lambda t: t["statistic"])
    u0, u1, v0, v1 = test["detail"]["rect_uv"]
    area = setup.case.geometry.region
    rect = (area.x0 + u0 * area.width, area.x0 + u1 * area.width)
    rect += (area.y0 + v0 * area.height, area.y0 + v1 * area.height)
    record = {"named": bool(named), "rect_mm": list(rect), "statistic": test["statistic"]}
    outline = setup.case.geometry.keloid
    if outline is not None:
        record.update(overlap(rect, outline))
    stood = [s["reason"] for s in document["stand_ins"] if s["effect"] == REGION]
    record["reason"] = stood[-1] if stood else None
    return record


def region_verdict(record: dict | None) -> str:
    """Whether the loop named a stiffer region and, against the keloid's outline, whether
    it located it; if not named, why."""
    if record is None:
        return "the stiffer region was not a candidate"
    x0, x1, y0, y1 = record["rect_mm"]
    where = f"x {x0:.1f}-{x1:.1f}, y {y0:.1f}-{y1:.1f} mm"
    if "iou" in record:
        where += f", IoU {record['iou']:.2f}"
    if record["named"]:
        if "iou" not in record:
            return f"a stiffer region is named ({where}); no outline to compare with"
        located = "located" if record["iou"] >= LOCATED else "named off the outline"
        return f"a stiffer region is named ({where}): {located}"
    why = record["reason"] or "its score test was not significant"
    return f"no stiffer region is named; the best rectangle ({where}) is not: {why}"


def run_case(
    name: str, settings: RealSkinSettings, out: Path, log=print, case=None, folder=None
) -> dict:
    """Diagnose one case; write its diagnosis.json, report.md and figures.

    Parameters
    ----------
    name : str
        The case's name (the shared data's case when ``case`` is None).
    settings : RealSkinSettings
        The study's choices.
    out : Path
        Output folder; the case writes into ``out / name`` unless ``folder`` is given.
    log : callable
        Receives the progress lines.
    case : SkinCase, optional
        The measurement (``dvs diagnose`` on an imported case); default ``load_case(name)``.
    folder : Path, optional
        Where the case's files go (``dvs diagnose``: its ``--out``).
    """
    begin = time.perf_counter()
    setup = build(name, settings, case)
    dic = sum(d is not None for d in setup.data.displacement_mm)
    log(
        f"{name}: {len(setup.loads)} frames ({dic} with DIC), DIC noise "
        f"{setup.noise_mm:.4f} mm, force weight {setup.weight:.1f} mm/N"
    )
    chosen = DiagnosisSettings(candidates=settings.candidates, max_effects=settings.max_effects)
    diagnosis = diagnose(setup.base, setup.loads, chosen, lambda line: log(f"  {line}"))
    document = diagnosis.document()
    problem = diagnosis.steps[0].fit.problem
    for step, record in zip(diagnosis.steps, document["steps"]):
        record["force_rms_N"] = problem.force_rms(step.fit.residual)
    document["observations"] = {
        "frames": list(setup.data.labels),
        "dic_noise_mm": setup.noise_mm,
        "force_weight_mm_per_N": setup.weight,
        "force_noise_N": setup.noise_mm / setup.weight,
        "pads_mm": [[r.x0, r.y0, r.x1, r.y1] for r in setup.pad_rects],
    }
    region = region_record(setup, document)
    document["region"] = region
    document["region_iou"] = region["iou"] if region and region["named"] else None
    document["region_verdict"] = region_verdict(region)
    document["wall_time_s"] = time.perf_counter() - begin
    folder = out / name if folder is None else Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figures = case_figures(setup, diagnosis, region, folder)
    atomic_write_json(folder / "diagnosis.json", document)
    atomic_write_text(folder / "report.md", case_report(name, setup, diagnosis, document, figures))
    log(f"{name}: {verdict(document)}; {document['region_verdict']}")
    return document


def case_report(name: str, setup: Setup, diagnosis, document: dict, figures: list) -> str:
    """report.md of one case: the set-up, the shared report, the region, the figures."""
    first, last = document["steps"][0], document["steps"][-1]
    head = [
        f"# Real skin, {name}: the extensometer through the shared loop",
        "",
        f"- frames: {', '.join(document['observations']['frames'])}",
        f"- DIC noise {setup.noise_mm * 1e3:.1f} um per component; force weight "
        f"{setup.weight:.1f} mm/N (an implied force noise of "
        f"{document['observations']['force_noise_N']:.2g} N)",
        f"- RMS force {first['force_rms_N']:.4f} -> {last['force_rms_N']:.4f} N",
        f"- stiffer region: {document['region_verdict']}",
        "",
    ]
    body = report(diagnosis, document).split("\n", 1)[1]
    pictures = [f"![{p.stem}]({p.name})" for p in figures]
    return "\n".join(head) + body + "\n## Figures\n\n" + "\n\n".join(pictures) + "\n"


def _printed(line: str) -> None:
    """A case's progress from its own process, flushed."""
    print(line, flush=True)


def run(out: Path, settings: RealSkinSettings, cases=CASES, log=print) -> dict:
    """Every case, each in a process of its own when the machine has the cores (the two
    cases share nothing); ``DIR/summary.json`` holds each case's verdicts and times."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    begin = time.perf_counter()
    summary = {}
    workers = min(len(cases), os.cpu_count() or 1)
    if workers > 1:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            jobs = [pool.submit(run_case, name, settings, out, _printed) for name in cases]
            documents = [job.result() for job in jobs]
    else:
        documents = [run_case(name, settings, out, log) for name in cases]
    for name, document in zip(cases, documents):
        summary[name] = {
            key: document[key]
            for key in ("selected", "unexplained", "model_error_mm", "region_verdict")
        }
        summary[name]["stand_ins"] = [s["effect"] for s in document["stand_ins"]]
        summary[name]["times_noise"] = document["model_error"]["times_noise"]
        summary[name]["seconds"] = document["wall_time_s"]
    summary["seconds"] = time.perf_counter() - begin
    atomic_write_json(out / "summary.json", summary)
    return summary


def build_parser(prog: str = "python -m experiments.realskin.skinfit"):
    """The options of ``dvs realskin fit``."""
    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--case", choices=CASES, default=None, help="one case (default: both)")
    parser.add_argument(
        "--candidates",
        default=",".join(CANDIDATES),
        help="comma list of the effects the loop may add",
    )
    return parser


def work(args) -> int:
    """``dvs realskin fit --out DIR [--case healthy] [--candidates a,b]``."""
    from symbolic.effects.library import ALL_EFFECT_NAMES

    names = tuple(n for n in args.candidates.split(",") if n)
    unknown = sorted(set(names) - set(ALL_EFFECT_NAMES))
    if not names or unknown:
        raise UsageError(f"--candidates: unknown {unknown or 'empty'}; use {ALL_EFFECT_NAMES}")
    check_output_dir(args.out, "--out")
    settings = replace(RealSkinSettings(), candidates=names)
    run(args.out, settings, (args.case,) if args.case else CASES)
    return 0


main = Command("experiments.realskin.skinfit", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
