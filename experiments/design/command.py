"""``dvs design``: which presses to make, with the figures that say why.

    dvs design DATASET --budget N --target alpha|EFFECT[=MAG][,EFFECT...]
               [--criterion d|a|power|maximin] [--energy auto|E --grid G --degrees D
               --margin MM] --out DIR
    dvs design --sequential SCENARIO [--budget N] [--energy auto|linear-elastic --grid G
               --degrees D --margin MM] --out DIR

Writes ``design.json`` (schema ``dvs-design/1``, docs/formats.md), ``design_map.png``
(the information one more press would add, per contact, with the chosen presses) and
``report.md``. ``dvs simulate --design DIR/design.json`` makes data for the design.
``--sequential`` runs the loop of ``experiments.design.sequential`` against FE continuum
data of a scenario instead: ``sequential.json``, ``path.png`` and ``report.md``.

With no model option (``--energy auto``) the design is for the base model step 0 chooses
(``experiments.basemodel``, as ``dvs fit`` and ``dvs diagnose``): its fit is the design's
point, its probe radius the candidates'; ``--energy dnurbs`` is the paper's model.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.design.options import given
from experiments.design.plan import DesignSettings, plan, require_noise
from experiments.fit.stepzero import AUTO, add_model_arguments, chosen_base

GAIN_LABELS = {
    "d": "gain in log det(F)^(1/p)",
    "a": "gain in -sum of squared relative standard errors",
    "power": "gain in -log(1 - power)",
    "maximin": "gain in min over effects of -log(1 - power)",
}


def parse_target(text: str) -> dict:
    """``alpha`` or ``EFFECT[=MAG][,EFFECT...]`` -> {name: magnitude or None}."""
    from experiments.phantom.simulate import parse_effect_specs
    from symbolic.effects.library import make_effect

    names = [t.strip() for t in str(text).split(",") if t.strip()]
    if names == ["alpha"]:
        return {"alpha": None}
    if not names or "alpha" in names:
        raise ValueError("--target: give alpha alone, or a comma list of effects NAME[=MAG]")
    try:
        effects = parse_effect_specs(names, 1)
    except ValueError as error:
        raise ValueError(f"--target: {error}".replace("--effect ", "")) from None
    for name in effects:
        if make_effect(name).per_case:
            raise ValueError(
                f"--target: {name} has one parameter per capture, so no choice of press "
                "changes its power; choose another effect"
            )
    return effects


def contact_gains(chosen) -> np.ndarray:
    """Per contact of a ``Plan``, the largest gain of the criterion by one more press
    there, added to the dataset's own design."""
    pool, criterion, contacts = chosen.pool, chosen.criterion, chosen.contacts
    base = pool.totals(chosen.own)
    reference = criterion.score(base.matrix())
    gains = np.full(len(contacts), -np.inf)
    for k in chosen.candidates:
        press = pool.presses[k]
        where = int(np.argmin(np.linalg.norm(contacts - press.uv, axis=1)))
        value = criterion.score((base + pool.blocks[k]).matrix()) - reference
        gains[where] = max(gains[where], value)
    return gains


def plot_map(path: Path, dataset, chosen, gains) -> None:
    """The gain per contact, the markers, the dataset's presses and the chosen ones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig
    from solvers.design.candidates import contact_point

    model, document, contacts = chosen.pool.model, chosen.document, chosen.contacts
    points = np.array([contact_point(model, uv) for uv in contacts])
    rest = dataset.outer_rest.reshape(-1, 3)
    fig, ax = plt.subplots(figsize=(7.5, 6.2), layout="constrained")
    ax.scatter(rest[:, 0], rest[:, 1], s=6, color="0.75", label="markers")
    shown = np.where(np.isfinite(gains), gains, np.nan)
    image = ax.scatter(points[:, 0], points[:, 1], c=shown, s=260, marker="s", cmap="viridis")
    fig.colorbar(image, ax=ax, label=GAIN_LABELS[document["criterion"]])
    for press in document["dataset_design"]["presses"]:
        ax.plot(*press["contact_mm"][:2], "kx", ms=9, mew=2)
    chosen: dict = {}
    for press in document["presses"]:
        key = tuple(np.round(press["contact_mm"], 3))
        chosen.setdefault(key, []).append(press["force_N"])
    tangential = [np.hypot(*f[:2]) for p in document["presses"] for f in [p["force_N"]]]
    reach = 0.5 * float(np.min(np.ptp(points[:, :2], axis=0))) / max(len(contacts) ** 0.5, 1)
    scale = reach / max(max(tangential), 1e-12)  # the longest arrow: half a contact spacing
    for (x, y, _), forces in chosen.items():
        for force in forces:
            f = np.asarray(force)
            ax.annotate(
                "",
                (x + scale * f[0], y + scale * f[1]),
                (x, y),
                arrowprops={"arrowstyle": "->", "color": "crimson", "lw": 1.5},
            )
        ax.plot(x, y, "o", color="crimson", ms=7)
        ax.annotate(
            f"x{len(forces)}",
            (x, y),
            (5, 5),
            textcoords="offset points",
            color="crimson",
            fontsize=9,
        )
    ax.plot([], [], "kx", label="dataset's presses")
    ax.plot([], [], "o", color="crimson", label="chosen presses (arrow: tangential force)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(
        f"{document['criterion']}-design for {', '.join(document['target'])}: "
        "what one more press adds"
    )
    ax.legend(loc="upper left", fontsize=8, framealpha=0.8)
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def build_parser(prog: str = "python -m experiments.design.command"):
    """The options of ``dvs design``."""
    from experiments.command.options import add_dataset_argument, make_parser, path_argument
    from experiments.design.options import add_candidate_arguments
    from experiments.diagnosis.diagnose import BASE_ENERGIES

    parser = make_parser(prog, "Choose where, in which direction and how hard to press.")
    add_dataset_argument(
        parser, ": geometry, markers and noise level (none with --sequential)", nargs="?"
    )
    parser.add_argument(
        "--sequential",
        metavar="SCENARIO",
        default=None,
        help="press, diagnose and choose again against FE continuum data of a scenario "
        "(stiffness_gradient, compliant_base, contact_offset, ...; needs scikit-fem)",
    )
    parser.add_argument(
        "--budget",
        type=int,
        default=10,
        help="new presses (at least 1); with --sequential the presses in all (at least 3)",
    )
    parser.add_argument(
        "--target",
        default=None,
        help="alpha (the base parameters), or "
        "a comma list of effects NAME[=MAGNITUDE] (realistic magnitude by default)",
    )
    parser.add_argument(
        "--criterion",
        choices=("d", "a", "power", "maximin"),
        default=None,
        help="default: d for alpha, power for one effect, maximin for several",
    )
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    add_candidate_arguments(
        parser,
        contacts="5, 3 with --sequential",
        force_range="0.17 0.25; 0.25 0.25 with --sequential",
        levels="2, 1 with --sequential",
    )
    parser.add_argument(
        "--augment",
        action="store_true",
        help="keep the dataset's presses and add the budget to them",
    )
    add_model_arguments(
        parser,
        BASE_ENERGIES,
        "base model, as dvs diagnose: auto (step 0 chooses between the paper's energy "
        "and the linear-elastic continuum with its surroundings, docs/continuum.md), dnurbs, "
        "linear-elastic or neo-hookean; --sequential takes auto (step 0 before every "
        "diagnosis) or linear-elastic",
        grid="up to 9x9x2 (15x15x3 with --sequential --energy linear-elastic)",
        degrees="3x3x1; 3x3x2 with --sequential",
        margin="0; 10 with --sequential --energy linear-elastic",
    )
    return parser


def work(args) -> int:
    """``dvs design FILE.npz --out DIR``; exit 0, or 2 with one line for bad input."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.data.dataset import load_dataset, require_indentation
    from experiments.design.options import SEQUENTIAL_MODEL
    from experiments.design.report import report_text
    from experiments.diagnosis.diagnose import base_from_options
    from experiments.fit.stepzero import model_options, refuse_model_options
    from experiments.output.atomic import atomic_write_json, atomic_write_text

    sequential = args.sequential is not None
    if sequential and args.dataset is not None:
        raise UsageError("--sequential starts from the simulator's paper design: give no DATASET")
    if not sequential and args.dataset is None:
        raise UsageError("give a DATASET (.npz), or --sequential SCENARIO")
    if sequential and (args.target or args.criterion or args.augment):
        raise UsageError("--target, --criterion and --augment do not apply to --sequential")
    settings = DesignSettings(
        target=parse_target(args.target or "alpha"),
        criterion=args.criterion,
        budget=max(args.budget, 1) if sequential else args.budget,
        contacts=given(args.contacts, 3 if sequential else 5),
        tilt_deg=args.tilt,
        azimuths=args.azimuths,
        force_range=tuple(given(args.force_range, (0.25, 0.25) if sequential else (0.17, 0.25))),
        levels=given(args.levels, 1 if sequential else 2),
        level=args.level,
        augment=args.augment,
    )
    if sequential:
        if args.energy not in (AUTO, "linear-elastic"):
            raise UsageError(
                f"--energy {args.energy}: --sequential diagnoses with the base step 0 "
                "chooses (auto) or with linear-elastic on --grid"
            )
        model = model_options(args, SEQUENTIAL_MODEL)
        if args.energy == AUTO:
            degrees = None if args.degrees is None else model["degrees"]
            refuse_model_options(
                model["grid"], degrees, args.margin or 0.0, "--energy linear-elastic"
            )
        model["energy"] = args.energy
        return run_sequential(args.sequential, settings, args.budget, model, args.out)
    base = base_from_options(args)
    out = check_output_dir(args.out)
    dataset = require_noise(require_indentation(load_dataset(args.dataset), args.prog))
    fit, base_choice = None, None
    if base == AUTO:
        base, fit, dataset, base_choice = chosen_base(
            dataset, settings.level, lambda line: print(line, flush=True)
        )
    chosen = plan(dataset, settings, log=print, base=base, fit=fit)
    document = chosen.document
    document["dataset"] = str(args.dataset)
    if base_choice is not None:
        document["base_choice"] = base_choice
    out.mkdir(parents=True, exist_ok=True)
    plot_map(out / "design_map.png", dataset, chosen, contact_gains(chosen))
    atomic_write_text(out / "report.md", report_text(document))
    atomic_write_json(out / "design.json", document)
    print(
        f"{len(document['presses'])} presses ({document['criterion']}-design for "
        f"{', '.join(document['target'])}) -> {out / 'design.json'}",
        file=sys.stdout,
    )
    return 0


def run_sequential(scenario: str, candidates, budget: int, model: dict, out: Path) -> int:
    """``dvs design --sequential SCENARIO``: the loop against FE continuum data; writes
    sequential.json, report.md and path.png. ``model`` is ``model_options``'s (grid None:
    the loop's default)."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.design.lab import ContinuumLab
    from experiments.design.pathreport import plot_path, report_text
    from experiments.design.sequential import SequentialSettings, run
    from experiments.diagnosis.continuumstudy import SCENARIOS
    from experiments.output.atomic import atomic_write_json, atomic_write_text
    from experiments.phantom.fe import require_skfem

    if scenario not in SCENARIOS:
        raise UsageError(
            f"--sequential: unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}"
        )
    settings = SequentialSettings(
        budget=budget,
        energy=model["energy"],
        candidates=candidates,
        degrees=model["degrees"],
        margin=model["margin"],
    )
    if model["grid"] is not None:
        settings = replace(settings, grid=model["grid"])
    out = check_output_dir(out)
    require_skfem()
    print(f"{scenario}: FE continuum data (scikit-fem), starting from the paper's design")
    lab = ContinuumLab(scenario)
    document = run(lab, settings, log=lambda line: print(line, flush=True))
    out.mkdir(parents=True, exist_ok=True)
    plot_path(out / "path.png", document, lab.dataset)
    atomic_write_text(out / "report.md", report_text(document))
    atomic_write_json(out / "sequential.json", document)
    print(f"{document['verdict']} after {document['presses']} presses -> {out / 'sequential.json'}")
    return 0


main = Command("experiments.design.command", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
