"""``dvs diagnose``: find what the base model is missing, on a dataset.

``run(dataset_or_path, out)`` fits the base model (alpha_u, alpha_v, alpha_w), runs
the discrepancy loop of ``solvers.diagnosis.loop`` and writes ``diagnosis.json``,
``report.md`` and residual maps before and after. Synthetic data with hidden effects
come from ``experiments.phantom.simulate``; the study of every effect over seeds is
``experiments.diagnosis.study`` (``dvs study diagnosis``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from experiments.command.options import Command, plural
from experiments.data.dataset import Dataset, load_dataset, require_indentation
from experiments.data.plausibility import dataset_warnings
from experiments.diagnosis.design import design_note
from solvers.diagnosis.report import report, verdict
from symbolic.effects.library import EFFECT_NAMES

BASE_NAMES = ("alpha_u", "alpha_v", "alpha_w")
"""The paper's base model's estimated parameters (static data cannot see mu and gamma)."""


def base_settings(grid=None, energy: str = "dnurbs", degrees=None, margin: float = 0.0):
    """The ``FitSettings`` of the loop's base model: the energy's default parameters."""
    from experiments.problem.fitting import ENERGY_NAMES, FitSettings

    names = BASE_NAMES if energy == "dnurbs" else ENERGY_NAMES[energy]
    extra = {} if degrees is None else {"degrees": tuple(degrees)}
    return FitSettings(names=names, grid=grid, energy=energy, margin=margin, **extra)


AUTO = "auto"
"""``base`` of ``diagnose_dataset`` and ``run``: step 0 chooses the base model."""

BASE_ENERGIES = (AUTO, "dnurbs", "linear-elastic", "neo-hookean")
"""``--energy``'s choices of ``dvs diagnose`` and ``dvs design``."""


def base_from_options(args):
    """The base model's ``FitSettings`` from ``--energy``, ``--grid``, ``--degrees`` and
    ``--margin`` (checked: exit 2 with one line when bad); ``AUTO`` (``--energy auto``, the
    default): step 0 chooses it, and the other three are refused (exit 2), as by fit."""
    from experiments.fit.stepzero import model_options, refuse_model_options

    model = model_options(args, {"grid": None, "degrees": base_settings().degrees, "margin": 0.0})
    degrees = None if args.degrees is None else model["degrees"]
    if args.energy == AUTO:
        refuse_model_options(model["grid"], degrees, model["margin"])
        return AUTO
    return base_settings(model["grid"], args.energy, degrees, model["margin"])


def diagnose_dataset(dataset: Dataset, settings=None, log=None, grid=None, base=AUTO):
    """Choose the base model (step 0), build its problem and run the loop; the Diagnosis.

    ``base`` is the base model's ``FitSettings``, or ``AUTO`` (the default): step 0
    (``experiments.basemodel.choose_base``) fits the paper's energy and the continuum
    family and keeps what the data support; the choice is recorded as
    ``Diagnosis.base_choice``. A ``grid`` (M, N, L) without ``base`` is the paper's
    energy on that grid.
    """
    from experiments.problem.fitting import build_problem, dataset_loads
    from solvers.diagnosis.loop import diagnose
    from solvers.diagnosis.record import DiagnosisSettings

    settings = settings or DiagnosisSettings()
    log = log or (lambda *_: None)
    if base == AUTO and grid is None:
        from experiments.basemodel import choose_base

        choice = choose_base(dataset, lambda line: log("step 0: " + line), settings.level)
        log(choice.line())
        start = choice.chosen.fit
        problem = start.problem
        revisit = None
        if choice.chosen is choice.continuum:
            from experiments.basemodel.revisit import Revisit

            revisit = Revisit(choice, lambda line: log("step 0 revisited: " + line), settings.level)
        record = choice.record()
        bound = record["discretisation"]["chi2"]  # eq. D1: what step 0's checks left
        diagnosis = diagnose(
            problem.base, problem.loads, settings, log, start, revisit, None, bound
        )
        diagnosis.base_choice = record
        if revisit is not None:
            diagnosis.base_choice["revisits"] = revisit.records
        return diagnosis
    from experiments.diagnosis.refinement import Survival

    chosen = base_settings(grid) if base == AUTO else base
    problem = build_problem(dataset, chosen)
    loads = dataset_loads(dataset, problem.model.volume)
    refine = Survival(dataset, chosen) if Survival.applies(dataset, chosen) else None
    return diagnose(problem, loads, settings, log, refine=refine)


def _only_out(settings, grid, base, check_refinement, what: str) -> None:
    """Refuse model options on a measured experiment with its own set-up."""
    from experiments.command.options import UsageError
    from solvers.diagnosis.record import DiagnosisSettings

    given = settings not in (None, DiagnosisSettings()) or grid is not None
    if given or base != AUTO or not check_refinement:
        raise UsageError(f"{what} runs its own set-up (docs/experiments.md); give only --out")


def run(
    dataset_or_path,
    out: Path,
    log=print,
    settings=None,
    grid=None,
    base=AUTO,
    check_refinement: bool = True,
) -> dict:
    """Diagnose a dataset (object or ``.npz`` path); write diagnosis.json, report.md, figures.

    Returns
    -------
    dict
        The diagnosis.json document (schema ``dvs-diagnosis/1``).
    """
    from experiments.output.atomic import atomic_write_json, atomic_write_text

    dataset = dataset_or_path
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset_or_path)
    if "bead_index" in dataset.extra:  # the Truth Cube: its own set-up (docs/truthcube.md)
        from experiments.data.truthcube import cube_from_dataset
        from experiments.truthcube.cubestudy import run_study

        _only_out(settings, grid, base, check_refinement, "a Truth Cube dataset")

        result = run_study(Path(out), cube=cube_from_dataset(dataset), log=log)
        return result["diagnosis"]
    if dataset.kind == "extensometer":  # the skin extensometer: the real-skin study's set-up
        from experiments.realskin.setup import RealSkinSettings
        from experiments.realskin.skindataset import case_from_dataset
        from experiments.realskin.skinfit import run_case

        _only_out(settings, grid, base, check_refinement, "an extensometer dataset")
        case = case_from_dataset(dataset)
        return run_case(case.name, RealSkinSettings(), Path(out), log, case, Path(out))
    if dataset.kind == "plate" and dataset.markers_rest is None:
        # compression curves: the phantom study's models and rule (docs/experiments.md)
        from experiments.phantoms.diagnosis import diagnose_compression

        _only_out(settings, grid, base, check_refinement, "a compression dataset")
        return diagnose_compression(dataset, Path(out), log=log)
    require_indentation(dataset, "dvs diagnose")
    if base == AUTO and grid is not None:
        base = base_settings(grid)
    for line in dataset_warnings(dataset):
        print(f"dvs diagnose: warning: {line}", file=sys.stderr)
    out = Path(out)
    log(
        f"diagnosing {plural(dataset.n_loads, 'load case')}, {dataset.outer_rest.shape[0]}x"
        f"{dataset.outer_rest.shape[1]} markers"
    )
    begin = time.perf_counter()
    diagnosis = diagnose_dataset(dataset, settings, lambda line: log("  " + line), base=base)
    document = diagnosis.document()
    choice = document.get("base_choice")
    if choice is not None:
        energy = choice["chosen"]
        reason = "the base model's resolution is step 0's (base_choice.resolution)"
        if energy == "dnurbs":
            reason = "the paper's energy is defined on its grid (alpha depend on it)"
        document["refinement"] = {"verdict": "not checked", "reason": reason}
    else:
        energy = base.energy
        if check_refinement:
            from experiments.diagnosis.refinement import refinement_check, summary

            document["refinement"] = refinement_check(diagnosis, dataset, base)
            log("  " + summary(document["refinement"]))
    document["wall_time_s"] = time.perf_counter() - begin
    document["design"] = design_note(dataset, energy)
    out.mkdir(parents=True, exist_ok=True)
    plot_residuals(diagnosis, out / "residuals.png")
    atomic_write_json(out / "diagnosis.json", document)
    text = report(diagnosis, document) + f"\n## The design\n\n{_design_text(document)}\n"
    if choice is not None:
        text += f"\n## Step 0: the base model\n\n{step0_text(choice)}\n"
    if "refinement" in document:
        from experiments.diagnosis.refinement import summary

        text += f"\n## Discretisation or physics\n\n{summary(document['refinement'])}.\n"
    atomic_write_text(out / "report.md", text)
    log(
        f"rms {document['rms_before_mm'] * 1e3:.1f} -> {document['rms_after_mm'] * 1e3:.1f} um; "
        f"{verdict(document)} -> {out / 'diagnosis.json'}"
    )
    log(f"note: {document['design']['note']}")
    return document


def step0_text(choice: dict) -> str:
    """Step 0 in words: the finding, the surroundings and resolution chosen."""
    lines = [f"- {choice['finding']}."]
    if choice["surroundings"] is not None and choice["chosen"] != "dnurbs":
        lines.append(f"- surroundings preferred by the data: {choice['preference'] or 'only one'}.")
    for check in choice["resolution"]:
        grid, fine = ("x".join(map(str, check[k])) for k in ("grid", "refined_grid"))
        if "prediction_chi2" not in check:
            lines.append(f"- resolution {grid} not checked: {check['reason']}.")
            continue
        lines.append(
            f"- resolution: {grid} -> {fine} moves the predicted markers by chi2 "
            f"{check['prediction_chi2']:.1f} (limit {check['limit']:.1f}): {check['verdict']}."
        )
    lines.append(f"- step 0 took {choice['seconds']:.0f} s.")
    if choice.get("revisits"):
        from experiments.basemodel.revisit import line

        lines += [f"- revisited: {line(record)}." for record in choice["revisits"]]
    return "\n".join(lines)


def _design_text(document: dict) -> str:
    design = document["design"]
    return (
        f"{design['loads']} loads at {design['contacts']} distinct contact(s), "
        f"{design['tilted_loads']} tilted from the normal: {design['note']}."
    )


PANELS_PER_ROW = 5
"""Cases per row of the residual figure."""


def plot_residuals(diagnosis, path: Path) -> None:
    """Marker residual maps of the base model (top block) and the final model (bottom
    block), one small panel per case, at most ``PANELS_PER_ROW`` to a row, one colour
    scale for all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig
    from experiments.output.plots import residual_panel

    first, last = diagnosis.steps[0].fit, diagnosis.steps[-1].fit
    cases = first.problem.cases
    columns = min(len(cases), PANELS_PER_ROW)
    rows = -(-len(cases) // columns)
    fig = plt.figure(figsize=(1.0 + 2.3 * columns, 0.8 + 2 * (0.5 + 2.3 * rows)))
    maps = [first.problem.point_errors(first.residual), last.problem.point_errors(last.residual)]
    top = max(float(e.max()) for errors in maps for e in errors) * 1e3
    titles = ("base model", " + ".join(diagnosis.selected) or "base model (nothing added)")
    for block, model, errors, title in zip(fig.subfigures(2, 1), (first, last), maps, titles):
        axes = block.subplots(rows, columns, squeeze=False, sharex=True, sharey=True)
        for ax in axes.ravel()[len(cases) :]:
            ax.set_visible(False)
        for ax, case, error in zip(axes.ravel(), cases, errors):
            image = residual_panel(ax, case, error, top, size=14, compact=True)
        for ax in axes[:, 0]:
            ax.set_ylabel("y [mm]")
        for ax in axes[-1]:
            ax.set_xlabel("x [mm]")
        rms, _ = model.rms()
        block.suptitle(f"{title}: RMS {rms * 1e3:.1f} um over all cases")
        block.colorbar(image, ax=axes.ravel().tolist(), label="residual [um]", shrink=0.9)
    atomic_savefig(fig, path, dpi=90)
    plt.close(fig)


def parse_candidates(text: str) -> tuple[str, ...]:
    """``--candidates``: effect names, where ``default`` stands for ``EFFECT_NAMES``."""
    from experiments.command.options import UsageError
    from symbolic.effects.library import ALL_EFFECT_NAMES

    names: list[str] = []
    for name in (n.strip() for n in text.split(",")):
        for chosen in EFFECT_NAMES if name == "default" else (name,):
            if chosen and chosen not in names:
                names.append(chosen)
    unknown = [n for n in names if n not in ALL_EFFECT_NAMES]
    if unknown or not names:
        raise UsageError(
            f"--candidates: unknown {', '.join(unknown) or 'empty list'}; choose from "
            f"default, {', '.join(ALL_EFFECT_NAMES)}"
        )
    return tuple(names)


def build_parser(prog: str = "python -m experiments.diagnosis.diagnose"):
    """The options of ``dvs diagnose``."""
    from experiments.command.options import add_dataset_argument, make_parser, path_argument
    from experiments.fit.stepzero import add_model_arguments

    parser = make_parser(prog, "Find what the base model is missing (writes diagnosis.json).")
    add_dataset_argument(parser)
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    add_model_arguments(
        parser,
        BASE_ENERGIES,
        "base model: auto (step 0 chooses between the paper's energy and the "
        "linear-elastic continuum with the tissue beyond the markers and the probe size "
        "estimated, docs/stepzero.md), or dnurbs (eq. 18), linear-elastic or neo-hookean",
        grid="up to 9x9x2, as the markers allow",
        degrees="3x3x1; e.g. 3x3x2",
    )
    parser.add_argument("--level", type=float, default=0.01, help="significance level (0-0.5)")
    parser.add_argument(
        "--max-effects", type=int, default=3, help=f"most effects added (0-{len(EFFECT_NAMES)})"
    )
    parser.add_argument(
        "--candidates",
        default="default",
        help="comma list of effects to search, 'default' (every effect but the opt-in "
        "stiffness_field) or 'default,stiffness_field' (docs/effects.md)",
    )
    parser.add_argument(
        "--no-refinement-check",
        action="store_true",
        help="skip refitting the final model on a refined volume (discretisation or physics)",
    )
    return parser


def work(args) -> int:
    """``dvs diagnose FILE.npz --out DIR``; exit 0, or 2 with one line for bad input."""
    from experiments.command.options import UsageError, check_output_dir, not_converged
    from solvers.diagnosis.record import DiagnosisSettings

    most = len(EFFECT_NAMES)
    if not 0 < args.level <= 0.5 or not 0 <= args.max_effects <= most:
        raise UsageError(f"--level must lie in (0, 0.5] and --max-effects in 0-{most}")
    candidates = parse_candidates(args.candidates)
    base = base_from_options(args)
    check_output_dir(args.out)
    settings = DiagnosisSettings(
        level=args.level,
        max_effects=args.max_effects,
        candidates=candidates,
    )
    document = run(
        args.dataset,
        args.out,
        settings=settings,
        base=base,
        check_refinement=not args.no_refinement_check,
    )
    if not document["success"]:
        return not_converged(args.prog, "a fit of the diagnosis", args.out / "diagnosis.json")
    return 0


main = Command("experiments.diagnosis.diagnose", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
