"""The ``dvs`` command.

Every subcommand exits 0 on success and 2 with one line on stderr for bad
input (never a traceback); outputs are written atomically.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.dataset import DatasetError


class UsageError(ValueError):
    """Bad input that a user can fix; printed as one line, exit code 2."""


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (and exit code 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _demo(args: argparse.Namespace) -> int:
    from experiments import demo

    return demo.run(args.out)


def parse_grid(text: str) -> tuple[int, int, int]:
    """'9x9x2' -> (9, 9, 2)."""
    try:
        grid = tuple(int(part) for part in text.lower().split("x"))
    except ValueError:
        grid = ()
    if len(grid) != 3 or min(grid) < 2:
        raise UsageError(f"--grid must look like 9x9x2 (three integers >= 2), got {text!r}")
    return grid


def parse_names(text: str) -> tuple[str, ...]:
    """'alpha_u,alpha_v' -> ('alpha_u', 'alpha_v'), checked against the known names."""
    from symbolic.model import PARAMETERS

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PARAMETERS]
    if not names or unknown:
        raise UsageError(
            f"--params takes a comma list from {', '.join(PARAMETERS)}; unknown: {unknown}"
        )
    return names


def _simulate(args: argparse.Namespace) -> int:
    from experiments.dataset import save_dataset
    from experiments.diagnose import parse_effect_specs, simulate_with_effects

    if args.noise < 0:
        raise UsageError(f"--noise must be >= 0 mm, got {args.noise}")
    if args.out.suffix != ".npz":
        raise UsageError(f"--out must name a .npz file, got {args.out}")
    dataset = simulate_with_effects(
        parse_effect_specs(args.effect), noise_mm=args.noise, seed=args.seed
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_dataset(args.out, dataset)
    print(
        f"wrote {args.out}: {dataset.n_loads} load cases, "
        f"{dataset.outer_rest.shape[0]}x{dataset.outer_rest.shape[1]} markers, "
        f"noise {args.noise} mm, seed {args.seed}"
    )
    return 0


def _fit(args: argparse.Namespace) -> int:
    from experiments.dataset import load_dataset
    from experiments.fitting import FitSettings, fit_dataset, write_fit_outputs

    dataset = load_dataset(args.dataset)
    objective = "control_points" if args.method == "paper" else "markers"
    settings = FitSettings(
        names=parse_names(args.params) if args.params else FitSettings().names,
        grid=parse_grid(args.grid),
        objective=args.objective or objective,
    )
    print(f"fitting {args.dataset} ({dataset.n_loads} load cases) with the {args.method} method")
    problem, result, report, document = fit_dataset(dataset, settings, args.method)
    write_fit_outputs(args.out, problem, result, document)
    for line in report.summary_lines():
        print("  " + line)
    print(
        f"  rms {document['rms_mm'] * 1e3:.2f} um; {result.status}; {result.iterations} "
        f"iterations, {result.forward_solves} forward solves -> {args.out / 'result.json'}"
    )
    return 0


def _compare(args: argparse.Namespace) -> int:
    from experiments import compare
    from experiments.dataset import load_dataset

    dataset = load_dataset(args.dataset)
    if args.starts < 1 or args.paper_starts < 0:
        raise UsageError("--starts must be >= 1 and --paper-starts >= 0")
    rows = compare.run(dataset, args.out, args.starts, args.paper_starts)
    print(compare.table(rows))
    return 0


def _transient(args: argparse.Namespace) -> int:
    from experiments import transient

    summary = transient.run(args.out)
    print(
        f"relative distance to equilibrium {summary['relative_distance_to_equilibrium']:.2e}, "
        f"settling time {summary['settling_time_s']:.3g} s -> {args.out / 'transient.json'}"
    )
    return 0


def _reconstruct(args: argparse.Namespace) -> int:
    from experiments.stereo import reconstruct

    return reconstruct.main([str(args.folder), "--out", str(args.out)])


def _diagnose(args: argparse.Namespace) -> int:
    from experiments import diagnose

    diagnose.run(args.dataset, args.out)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = OneLineParser(
        prog="dvs",
        description="Dynamic volume spline models of soft tissue: forward and inverse solutions.",
    )
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=OneLineParser
    )
    demo = commands.add_parser("demo", help="run the main job on the embedded forehead phantom")
    demo.add_argument("--out", type=Path, default=Path("demo-output"), help="output directory")
    demo.set_defaults(handler=_demo)

    sim = commands.add_parser("simulate", help="write a synthetic dataset from the phantom")
    sim.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[=VALUE]",
        help="an effect the dataset does not declare (repeatable)",
    )
    sim.add_argument("--noise", type=float, default=0.02, help="marker noise [mm]")
    sim.add_argument("--seed", type=int, default=0, help="random seed")
    sim.add_argument("--out", type=Path, required=True, help="output .npz file")
    sim.set_defaults(handler=_simulate)

    fit = commands.add_parser("fit", help="estimate parameters from a dataset")
    fit.add_argument("dataset", type=Path, help="dataset v1 (.npz)")
    fit.add_argument(
        "--method", choices=("simultaneous", "nested", "paper"), default="simultaneous"
    )
    fit.add_argument(
        "--params", default="", help="comma list, default alpha_u,alpha_v,alpha_w,mu,gamma"
    )
    fit.add_argument("--grid", default="9x9x2", help="control grid MxNxL")
    fit.add_argument(
        "--objective",
        choices=("markers", "control_points"),
        default=None,
        help="default markers (control_points for --method paper)",
    )
    fit.add_argument("--out", type=Path, required=True, help="output directory")
    fit.set_defaults(handler=_fit)

    cmp_ = commands.add_parser("compare", help="simultaneous vs nested vs paper-faithful")
    cmp_.add_argument("dataset", type=Path, help="dataset v1 (.npz)")
    cmp_.add_argument("--starts", type=int, default=20, help="multi-start points")
    cmp_.add_argument(
        "--paper-starts",
        type=int,
        default=3,
        help="multi-start points for the (slow) paper-faithful method",
    )
    cmp_.add_argument("--out", type=Path, required=True, help="output directory")
    cmp_.set_defaults(handler=_compare)

    tr = commands.add_parser("transient", help="transient from rest against the equilibrium")
    tr.add_argument("--out", type=Path, default=Path("transient-output"), help="output directory")
    tr.set_defaults(handler=_transient)

    rec = commands.add_parser("reconstruct", help="images of the marked skin -> dataset v1")
    rec.add_argument("folder", type=Path, help="experiment folder (see docs/stereo.md)")
    rec.add_argument("--out", type=Path, required=True, help="output .npz file")
    rec.set_defaults(handler=_reconstruct)

    diag = commands.add_parser("diagnose", help="find the effect the model lacks")
    diag.add_argument("dataset", type=Path, help="dataset v1 (.npz)")
    diag.add_argument("--out", type=Path, required=True, help="output directory")
    diag.set_defaults(handler=_diagnose)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dvs`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (UsageError, DatasetError, ValueError, FileNotFoundError) as error:
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"dvs {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dvs {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
