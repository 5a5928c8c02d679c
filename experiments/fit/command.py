"""``dvs fit``: a dataset in, ``result.json`` and two figures out (docs/cli.md)."""

from __future__ import annotations

from experiments.command.options import Command
from experiments.data.plausibility import dataset_warnings
from experiments.problem.fitting import (
    ENERGY_NAMES,
    FitSettings,
    fit_dataset,
    model_grid,
    write_fit_outputs,
)
from symbolic.continuum_model import ENERGIES


def check_energy_names(energy: str, names: tuple[str, ...]) -> None:
    """Every estimated parameter must enter the chosen energy's equilibrium or dynamics."""
    from experiments.command.options import UsageError

    paper = {"alpha_u", "alpha_v", "alpha_w", "beta", "k0"}
    fibres = {"kf1", "kf2", "fibre_angle"}
    foreign = {
        "dnurbs": {"E", "nu", "k1", "k2"} | fibres,
        "linear-elastic": paper | {"k1", "k2"} | fibres,
        "neo-hookean": paper | {"k1", "k2"} | fibres,
        "exponential": paper | fibres,
        "fibres": paper,
    }
    wrong = [n for n in names if n in foreign[energy]]
    if wrong:
        raise UsageError(
            f"--params {','.join(wrong)} do not enter --energy {energy}; "
            f"use {','.join(ENERGY_NAMES[energy])}"
        )


def build_parser(prog: str = "python -m experiments.fit.command"):
    """The options of ``dvs fit`` (docs/cli.md)."""
    from experiments.command.options import add_dataset_argument, make_parser, path_argument
    from experiments.fit.stepzero import add_model_arguments

    parser = make_parser(prog, "Estimate parameters from a dataset (writes result.json).")
    add_dataset_argument(parser)
    parser.add_argument(
        "--method",
        choices=("auto", "simultaneous", "nested", "paper"),
        default="auto",
        help="inverse formulation (docs/inverse.md); auto: the faster for the problem",
    )
    add_model_arguments(
        parser,
        ("auto", *ENERGIES),
        "base model: auto (step 0 of dvs diagnose chooses between the paper's eq. 18 and "
        "isotropic linear elasticity with its surroundings, docs/continuum.md), dnurbs, "
        "linear-elastic, neo-hookean, exponential (neo-Hookean with strain stiffening "
        "k1, k2; docs/continuum.md) or fibres (exponential with a fibre family kf1, kf2, "
        "fibre_angle)",
        grid="up to 9x9x2, as the markers allow",
        degrees="3x3x1",
    )
    parser.add_argument(
        "--params",
        default=None,
        help="comma list (default: alpha_u,alpha_v,alpha_w,mu,gamma; E,nu for the continua; "
        "E,nu,k1 for exponential; E,nu,kf1,fibre_angle for fibres)",
    )
    parser.add_argument(
        "--objective",
        choices=("markers", "control_points"),
        default=None,
        help="what is compared (default: markers; control_points for --method paper)",
    )
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    return parser


def _warn(prog: str, lines) -> None:
    """Plausibility warnings on stderr, one line each."""
    import sys

    for line in lines:
        print(f"{prog}: warning: {line}", file=sys.stderr)


def fit_settings(args) -> tuple[str, FitSettings]:
    """The energy asked for (``auto``: step 0 chooses) and the fit's settings, from
    ``dvs fit``'s parsed options alone (no file is read): ``UsageError`` names an
    option that contradicts another.

    ``--method paper`` and ``--objective control_points`` are the paper's method, so
    they imply its energy (dnurbs); model options (``--grid``, ``--degrees``,
    ``--margin``) describe a chosen energy and are refused with ``auto``.
    """
    from experiments.command.options import (
        UsageError,
        check_grid,
        check_margin,
        parse_degrees,
        parse_grid,
        parse_names,
        verb,
    )

    objective = "control_points" if args.method == "paper" else "markers"
    energy = args.energy
    paper = args.method == "paper" or args.objective == "control_points"
    if args.params is not None and energy == "auto":
        named = set(parse_names(args.params))
        paper = paper or named <= set(ENERGY_NAMES["dnurbs"])
        if not paper:
            raise UsageError(
                f"--params {args.params} name a continuum's parameters; give --energy "
                "linear-elastic or neo-hookean too"
            )
    if energy == "auto" and paper:
        energy = "dnurbs"  # the paper's method, objective and parameters are its model's
    margin = check_margin(args.margin)
    if energy == "auto":
        chosen = [
            f"--{name}"
            for name, value in (("grid", args.grid != "auto"), ("degrees", args.degrees))
            if value
        ]
        chosen += ["--margin"] * (margin > 0)
        if chosen:
            raise UsageError(
                f"{', '.join(chosen)} {verb(chosen)} the model of a chosen --energy; with "
                "--energy auto (the default) step 0 chooses it, or give --energy too"
            )
    degrees = parse_degrees(args.degrees or "3x3x1")
    if margin > 0 and (args.objective or objective) != "markers":
        raise UsageError("--margin needs --objective markers (control points follow the grid)")
    named = "dnurbs" if energy == "auto" else energy
    names = parse_names(args.params or ",".join(ENERGY_NAMES[named]))
    check_energy_names(named, names)
    grid = None if args.grid == "auto" else check_grid(parse_grid(args.grid), degrees, args.grid)
    settings = FitSettings(
        names=names,
        grid=grid,
        degrees=degrees,
        objective=args.objective or objective,
        energy=named,
        margin=margin,
    )
    return energy, settings


def work(args) -> int:
    """``dvs fit FILE.npz --out DIR``: exit 0, or 2 with one line for bad input.

    Plausibility warnings go to stderr, one line each; the verdict is printed last.
    """
    import sys

    from experiments.command.options import EXIT_NOT_CONVERGED, check_output_dir, plural
    from experiments.data.dataset import load_dataset, require_indentation

    energy, settings = fit_settings(args)
    check_output_dir(args.out)
    dataset = require_indentation(load_dataset(args.dataset), args.prog)
    early = dataset_warnings(dataset)
    _warn(args.prog, early)
    cases = plural(dataset.n_loads, "load case")
    print(f"fitting {args.dataset} ({cases}), {args.method} method", flush=True)
    choice = None
    if energy == "auto":
        from experiments.basemodel import choose_base

        choice = choose_base(dataset, lambda line: print(f"  step 0: {line}", flush=True))
        dataset, settings = choice.dataset(dataset), choice.fit_settings()
        print(f"  {choice.line()}", flush=True)
    grid, degrees = model_grid(dataset, settings)
    print(
        f"  control grid {'x'.join(map(str, grid))}, degrees {degrees}, for "
        f"{dataset.marker_shape[0]} x {dataset.marker_shape[1]} markers"
    )
    progress = lambda line: print(f"  {line}", flush=True)  # noqa: E731
    problem, result, report, document = fit_dataset(dataset, settings, args.method, progress)
    if choice is not None:
        document["base_choice"] = choice.record()
    write_fit_outputs(args.out, problem, result, document)
    if args.method == "auto":
        print(f"  method {result.method} ({document['method_choice']['reason']})")
    for line in report.summary_lines():
        print("  " + line)
    print(
        f"  rms {document['rms_mm'] * 1e3:.4g} um; {result.status}; {result.iterations} "
        f"iterations, {result.forward_solves} forward solves -> {args.out / 'result.json'}"
    )
    if not result.success:
        print(
            f"{args.prog}: error: the solver did not converge ({result.status}); "
            f"{args.out / 'result.json'} has success: false",
            file=sys.stderr,
        )
        return EXIT_NOT_CONVERGED
    print(f"  verdict: {document['verdict']['summary']}")
    _warn(args.prog, document["warnings"][len(early) :])
    return 0


main = Command("experiments.fit.command", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
