"""``dvs next``: the next press of a real experiment, from the data so far.

    dvs next DATASET [NEW.npz ...] --budget N [--energy auto|linear-elastic]
             [--grid G --degrees D --margin MM] [--contacts C --tilt DEG --azimuths A
             --force-range LOW HIGH --levels L] --out DIR

One step of the sequential loop (``experiments.design.sequential.step``, docs/design.md)
on measured data instead of the simulator: diagnose the presses so far, pose the
questions the diagnosis leaves (separate each named effect from its rivals, detect each
effect not named at its realistic magnitude), and propose the press that makes the most
progress over them (eq. D7), or say why to stop.

The datasets given are one session: the first holds the session's rest capture, the
others are presses reconstructed since (``dvs reconstruct`` on the new images), appended
in order (``experiments.data.captures.merge_captures``); the merged data are written to
``DIR/dataset.npz``, the DATASET of the next round.

Writes ``next.json`` (schema ``dvs-design/1``, docs/formats.md; ``presses`` holds the
proposed press, or is empty when the loop stops), ``next.png`` (the skin with the presses
so far and the proposed one; the questions before and after it) and ``report.md``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.fit.stepzero import AUTO


def build_parser(prog: str = "python -m experiments.design.nextpress"):
    """The options of ``dvs next``."""
    from experiments.command.options import make_parser, path_argument
    from experiments.design.options import add_candidate_arguments
    from experiments.fit.stepzero import add_model_arguments

    parser = make_parser(prog, "Propose the next press of an experiment from the data so far.")
    parser.add_argument(
        "datasets",
        type=path_argument,
        nargs="+",
        metavar="DATASET",
        help="dataset v1 (.npz) of the session so far, then any presses made since, in order",
    )
    parser.add_argument(
        "--budget",
        type=int,
        required=True,
        help="presses still allowed in this session, the proposed one included (at least 1)",
    )
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    add_model_arguments(
        parser,
        (AUTO, "linear-elastic"),
        "base model of the diagnosis: auto (step 0 chooses the model, its resolution "
        "and surroundings, as dvs diagnose) or linear-elastic on --grid",
        grid="15x15x3",
        degrees="3x3x2",
        margin="10",
    )
    parser.add_argument(
        "--target",
        choices=("effects", "field"),
        default="effects",
        help="effects: the questions the diagnosis leaves (docs/design.md); field: an "
        "inclusion anywhere over the marked area, for the stiffness map (docs/imaging.md)",
    )
    parser.add_argument(
        "--inclusion", type=float, default=8.0, help="with --target field: its diameter [mm]"
    )
    parser.add_argument(
        "--ratio", type=float, default=2.0, help="with --target field: its stiffness ratio"
    )
    add_candidate_arguments(
        parser, contacts="3, 7 with --target field", force_range="0.25 0.25", levels="1"
    )
    return parser


def work(args) -> int:
    """Check every input, then diagnose, choose and write the outputs."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.data.captures import merge_captures
    from experiments.data.dataset import load_dataset, require_indentation, save_dataset
    from experiments.design.options import SEQUENTIAL_MODEL, given
    from experiments.design.plan import DesignSettings, require_noise
    from experiments.design.sequential import SequentialSettings, step
    from experiments.fit.stepzero import model_options, refuse_model_options
    from experiments.output.atomic import atomic_write_json, atomic_write_text

    begin = time.perf_counter()
    if args.budget < 1:
        raise UsageError(f"--budget must be at least 1 (the proposed press), got {args.budget}")
    field = args.target == "field"
    contacts = args.contacts or (7 if field else 3)
    candidates = DesignSettings(
        budget=1,
        contacts=contacts,
        tilt_deg=args.tilt,
        azimuths=args.azimuths,
        force_range=tuple(given(args.force_range, (0.25, 0.25))),
        levels=given(args.levels, 1),
        level=args.level,
    )
    model = model_options(args, SEQUENTIAL_MODEL)
    if args.energy == AUTO:
        degrees = None if args.degrees is None else model["degrees"]
        refuse_model_options(model["grid"], degrees, args.margin or 0.0, "--energy linear-elastic")
    if field:
        from experiments.design import nextfield

        if args.energy != AUTO:
            raise UsageError(
                "--target field maps on the continuum step 0 chooses, as dvs image: drop --energy"
            )
        target = nextfield.FieldTarget(
            args.inclusion, args.ratio, contacts=contacts, force_n=candidates.force_range[1]
        )
    out = check_output_dir(args.out)
    parts = [
        require_noise(require_indentation(load_dataset(path), args.prog)) for path in args.datasets
    ]
    dataset = merge_captures(parts, [str(p) for p in args.datasets])
    print(f"{dataset.n_loads} presses so far, {args.budget} allowed from here", flush=True)
    if field:
        row = nextfield.field_step(dataset, target, args.budget, log=print)
        document = nextfield.field_document(row, target, args)
        plot = lambda path, headline: nextfield.plot_field(path, document, dataset, headline)  # noqa: E731
        report = lambda headline: nextfield.field_report(document, headline)  # noqa: E731
    else:
        settings = SequentialSettings(
            energy=args.energy,
            grid=model["grid"] or SequentialSettings.grid,
            degrees=model["degrees"],
            margin=model["margin"],
            candidates=candidates,
        )
        print("diagnosing the presses so far; the questions; the candidates ...", flush=True)
        row = step(dataset, settings, args.budget, progress=lambda line: print(line, flush=True))
        document = next_document(row, candidates, args)
        plot = lambda path, _: plot_next(path, document, dataset)  # noqa: E731
        report = lambda _: report_text(document)  # noqa: E731
    document["wall_time_s"] = time.perf_counter() - begin
    headline = summary(document)
    out.mkdir(parents=True, exist_ok=True)
    if len(parts) > 1:
        save_dataset(out / "dataset.npz", dataset)
    plot(out / "next.png", headline)
    atomic_write_text(out / "report.md", report(headline))
    atomic_write_json(out / "next.json", document)
    print(headline + f" -> {out / 'next.json'}", flush=True)
    return 0


def next_document(row: dict, candidates, args) -> dict:
    """``next.json``: the ``dvs-design/1`` keys a design file has (``presses`` the proposal,
    or empty), the diagnosis of the data so far, every question and why this press."""
    from experiments.design.nextjson import next_header, next_why

    return {
        **next_header(row, args, "effects"),
        "why": next_why(row["press"], "ratio"),
        "diagnosis": {
            key: row[key]
            for key in ("selected", "rivals", "unexplained", "rms_um", "rms_before_um")
        }
        | {"noise_rms_um": row["noise_rms_um"], "leading": row["leading"]},
        "questions": row["questions"],
        "open": row["open"],
        "level": args.level,
        "model": row["model"],
        "base_choice": row["base_choice"],
        "candidates": {
            "contacts": candidates.contacts,
            "tilt_deg": candidates.tilt_deg,
            "azimuths": candidates.azimuths,
            "forces_N": [float(f) for f in candidates.forces()],
        },
        "diagnosis_s": row["diagnosis_s"],
    }


def summary(document: dict) -> str:
    """One line: the proposed press and the question it answers, or why to stop."""
    if not document["presses"]:
        return f"stop: {document['stop']} after {document['presses_so_far']} presses"
    press = document["presses"][0]
    x, y, _ = press["contact_mm"]
    return (
        f"next press at ({x:.1f}, {y:.1f}) mm, tilt {press['tilt_deg']:.0f} deg, "
        f"{np.linalg.norm(press['force_N']):.2f} N, for '{document['why']['question']}'"
    )


def report_text(document: dict) -> str:
    """report.md: the proposal and why, the diagnosis so far, every question."""
    from experiments.design.pathreport import question_rows

    diagnosis = document["diagnosis"]
    named = ", ".join(diagnosis["selected"]) or "nothing"
    verdict = "unexplained" if diagnosis["unexplained"] else "explained"
    lines = [
        "# The next press (`dvs next`)",
        "",
        f"**{summary(document)}.**",
        "",
        f"Data so far: {document['presses_so_far']} presses, {document['budget']} allowed "
        f"from here. Diagnosis ({document['model']['energy']} base): {named} named, RMS "
        f"{diagnosis['rms_um']:.1f} um against the noise's {diagnosis['noise_rms_um']:.1f} um, "
        f"{verdict}.",
        "",
    ]
    if document["why"] is not None:
        why = document["why"]
        lines += [
            f"Why: it answers '{why['question']}', the open question it moves most: its value "
            f"rises from {why['ratio_before']:.2f} to {why['ratio_after']:.2f} of what answers "
            f"it (predicted), and the progress over all unanswered questions (eq. D7) rises by "
            f"{why['progress']:.3g}.",
            "",
        ]
    lines += question_rows(document["questions"], "reachable within the budget")
    return "\n".join(lines) + "\n"


def plot_next(path: Path, document: dict, dataset) -> None:
    """Left: the markers, the presses so far (crosses) and the proposed press (arrow: its
    tangential force). Right: each question's value over its need, now and after the
    proposed press (the one it answers)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5.2), layout="constrained")
    rest = dataset.outer_rest.reshape(-1, 3)
    left.scatter(rest[:, 0], rest[:, 1], s=6, color="0.75", label="markers")
    left.plot(*dataset.contacts[:, :2].T, "kx", ms=9, mew=2, label="presses so far")
    span = float(np.ptp(rest[:, 0]))
    for press in document["presses"]:
        x, y, _ = press["contact_mm"]
        fx, fy, _ = press["force_N"]
        size, tangential = float(np.linalg.norm(press["force_N"])), float(np.hypot(fx, fy))
        label = f"next press, {size:.2f} N, tilt {press['tilt_deg']:.0f} deg"
        left.plot(x, y, "o", color="crimson", ms=8, label=label)
        if tangential > 1e-9 * size:  # the arrow: the tangential force's direction
            reach = 0.15 * span / tangential
            left.annotate(
                "",
                (x + reach * fx, y + reach * fy),
                (x, y),
                arrowprops={"arrowstyle": "-|>", "color": "crimson", "lw": 2},
            )
    left.set_aspect("equal")
    left.set_xlabel("x [mm]")
    left.set_ylabel("y [mm]")
    left.legend(loc="upper left", fontsize=8, framealpha=0.8)
    left.set_title(summary(document), fontsize=9)
    questions = document["questions"]
    ratios = [min(q["value"] / q["needed"], 2.0) if q["needed"] > 0 else 2.0 for q in questions]
    positions = np.arange(len(questions))
    right.barh(positions, ratios, color=["0.6" if q["answered"] else "C0" for q in questions])
    why = document["why"]
    if why is not None:
        k = [q["question"] for q in questions].index(why["question"])
        right.plot(min(why["ratio_after"], 2.0), k, "D", color="crimson", label="after the press")
        right.legend(fontsize=8, loc="lower right")
    right.axvline(1.0, color="k", ls=":")
    right.set_yticks(positions, [q["question"] for q in questions], fontsize=7)
    right.set_xlabel("value / needed (1: answered; grey: answered already)")
    right.set_title("the questions the diagnosis leaves", fontsize=9)
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


main = Command("experiments.design.nextpress", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
