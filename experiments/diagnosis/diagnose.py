"""``dvs diagnose``: find what the base model is missing, on a dataset.

``run(dataset_or_path, out)`` fits the base model (alpha_u, alpha_v, alpha_w), runs
the discrepancy loop of ``solvers.diagnosis.loop`` and writes ``diagnosis.json``,
``report.md`` and residual maps before and after. Synthetic data with hidden effects
come from ``experiments.phantom.simulate``; the study of every effect over seeds is
``experiments.diagnosis.study`` (``dvs study``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from experiments.dataset import Dataset, load_dataset
from experiments.diagnosis.design import design_note
from experiments.options import plural
from experiments.plausibility import dataset_warnings
from solvers.diagnosis.report import report, verdict

BASE_NAMES = ("alpha_u", "alpha_v", "alpha_w")
"""The base model's estimated parameters (static data cannot see mu and gamma)."""


def diagnose_dataset(dataset: Dataset, settings=None, log=None, grid=None):
    """Build the base problem of a dataset and run the loop; returns the Diagnosis.

    ``grid`` is the control grid (M, N, L); None follows the data (``control_grid``).
    """
    from experiments.fitting import FitSettings, build_problem, dataset_loads
    from solvers.diagnosis.loop import diagnose

    base = build_problem(dataset, FitSettings(names=BASE_NAMES, grid=grid))
    loads = dataset_loads(dataset, base.model.volume)
    return diagnose(base, loads, settings, log)


def run(dataset_or_path, out: Path, log=print, settings=None, grid=None) -> dict:
    """Diagnose a dataset (object or ``.npz`` path); write diagnosis.json, report.md, figures.

    Returns
    -------
    dict
        The diagnosis.json document (schema ``dvs-diagnosis/1``).
    """
    from experiments.atomic import atomic_write_json, atomic_write_text

    dataset = dataset_or_path
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset_or_path)
    for line in dataset_warnings(dataset):
        print(f"dvs diagnose: warning: {line}", file=sys.stderr)
    out = Path(out)
    log(
        f"diagnosing {plural(dataset.n_loads, 'load case')}, {dataset.outer_rest.shape[0]}x"
        f"{dataset.outer_rest.shape[1]} markers"
    )
    begin = time.perf_counter()
    diagnosis = diagnose_dataset(dataset, settings, lambda line: log("  " + line), grid)
    document = diagnosis.document()
    document["wall_time_s"] = time.perf_counter() - begin
    document["design"] = design_note(dataset)
    out.mkdir(parents=True, exist_ok=True)
    plot_residuals(diagnosis, out / "residuals.png")
    atomic_write_json(out / "diagnosis.json", document)
    text = report(diagnosis, document) + f"\n## The design\n\n{_design_text(document)}\n"
    atomic_write_text(out / "report.md", text)
    log(
        f"rms {document['rms_before_mm'] * 1e3:.1f} -> {document['rms_after_mm'] * 1e3:.1f} um; "
        f"{verdict(document)} -> {out / 'diagnosis.json'}"
    )
    log(f"note: {document['design']['note']}")
    return document


def _design_text(document: dict) -> str:
    design = document["design"]
    return (
        f"{design['loads']} loads at {design['contacts']} distinct contact(s), "
        f"{design['tilted_loads']} tilted from the normal: {design['note']}."
    )


def plot_residuals(diagnosis, path: Path) -> None:
    """Marker residual maps of the base model (left) and the final model (right), per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.atomic import atomic_savefig
    from experiments.plots import residual_panel

    first, last = diagnosis.steps[0].fit, diagnosis.steps[-1].fit
    cases = first.problem.cases
    fig, axes = plt.subplots(
        len(cases), 2, figsize=(10, 4.4 * len(cases)), squeeze=False, layout="constrained"
    )
    maps = [first.problem.point_errors(first.residual), last.problem.point_errors(last.residual)]
    top = max(float(e.max()) for errors in maps for e in errors) * 1e3
    titles = ("base model", " + ".join(diagnosis.selected) or "base model (nothing added)")
    for column, (errors, title) in enumerate(zip(maps, titles)):
        for row, (case, error) in enumerate(zip(cases, errors)):
            image = residual_panel(axes[row, column], case, error, top, title, size=60)
    fig.colorbar(image, ax=axes.ravel().tolist(), label="marker residual [um]")
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def build_parser(prog: str = "python -m experiments.diagnosis.diagnose"):
    """The options of ``dvs diagnose``."""
    from experiments.options import make_parser, path_argument

    parser = make_parser(prog, "Find what the base model is missing (writes diagnosis.json).")
    parser.add_argument("dataset", type=path_argument, help="dataset v1 (.npz)")
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument(
        "--grid", default="auto", help="control grid MxNxL; auto: up to 9x9x2, as the markers allow"
    )
    parser.add_argument("--level", type=float, default=0.01, help="significance level (0-0.5)")
    parser.add_argument("--max-effects", type=int, default=3, help="most effects added (0-11)")
    return parser


def main(argv: list[str] | None = None, prog: str = "python -m experiments.diagnosis.diagnose"):
    """``dvs diagnose FILE.npz --out DIR``; exit 0, or 2 with one line for bad input."""

    from experiments.fitting import FitSettings
    from experiments.options import (
        UsageError,
        check_grid,
        check_output_dir,
        not_converged,
        parse_grid,
        run_guarded,
    )
    from solvers.diagnosis.loop import DiagnosisSettings

    args = build_parser(prog).parse_args(argv)

    def work() -> int:
        if not 0 < args.level <= 0.5 or not 0 <= args.max_effects <= 11:
            raise UsageError("--level must lie in (0, 0.5] and --max-effects in 0-11")
        grid = None
        if args.grid != "auto":
            grid = check_grid(parse_grid(args.grid), FitSettings().degrees, args.grid)
        check_output_dir(args.out)
        settings = DiagnosisSettings(level=args.level, max_effects=args.max_effects)
        document = run(args.dataset, args.out, settings=settings, grid=grid)
        if not document["success"]:
            return not_converged(prog, "a fit of the diagnosis", args.out / "diagnosis.json")
        return 0

    return run_guarded(prog, work)


if __name__ == "__main__":
    raise SystemExit(main())
