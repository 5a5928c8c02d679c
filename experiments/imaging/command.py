"""``dvs image``: a dataset in, a map of Young's modulus with its uncertainty out.

Writes image.json, map.png, std.png and map.vtu (ParaView) into ``--out``
(docs/cli.md, docs/formats.md; the method in docs/imaging.md). With no model option
(``--energy auto``) the map is made on step 0's continuum (``experiments.imaging.continuum``);
``--energy linear-elastic`` takes the volume of ``--grid``, ``--degrees`` and ``--margin``.
"""

from __future__ import annotations

from experiments.command.options import Command
from experiments.imaging.mapping import REGULARIZERS
from experiments.imaging.options import parse_field, parse_weight
from solvers.imaging.estimate import SOLVERS

DEGREES = (3, 3, 1)
"""Degrees of ``--energy linear-elastic`` without ``--degrees`` (those of ``dvs fit``)."""


def build_parser(prog: str = "python -m experiments.imaging.command"):
    """The options of ``dvs image`` (docs/cli.md)."""
    from experiments.command.options import add_margin_argument, make_parser, path_argument

    parser = make_parser(
        prog, "Image Young's modulus as a field, with its uncertainty (writes image.json)."
    )
    parser.add_argument("dataset", type=path_argument, help="dataset v1 (.npz) with noise_mm")
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument(
        "--field",
        default="auto",
        help="nodes of the field: MxN, or MxNxL; auto (default): half a marker spacing "
        "apart over the volume, at most 256 coefficients",
    )
    parser.add_argument("--over", choices=("surface", "layers", "volume"), default="surface")
    parser.add_argument("--regularizer", choices=tuple(REGULARIZERS), default="h1")
    parser.add_argument(
        "--weight",
        default="gcv",
        help="gcv (default), morozov (needs the noise), lcurve, or beta [mm^2]",
    )
    parser.add_argument(
        "--method",
        choices=("auto", *SOLVERS),
        default="auto",
        help="auto: nested-sensitivity for small fields, nested-adjoint for large",
    )
    parser.add_argument(
        "--noise", type=float, default=None, help="marker noise [mm] (default: the dataset's)"
    )
    parser.add_argument(
        "--energy",
        choices=("auto", "linear-elastic"),
        default="auto",
        help="the continuum imaged on: auto (step 0 of dvs fit and dvs diagnose chooses its "
        "volume, the tissue beyond the markers and the probe radius, docs/stepzero.md), or "
        "linear-elastic on the volume of --grid, --degrees and --margin",
    )
    parser.add_argument(
        "--grid",
        default="auto",
        help="control grid MxNxL (with --energy linear-elastic); auto: up to 9x9x2, as the "
        "markers allow",
    )
    parser.add_argument(
        "--degrees",
        default=None,
        help="degrees PxQxR (with --energy linear-elastic; default 3x3x1)",
    )
    add_margin_argument(parser)
    return parser


def image_settings(args):
    """The imaging settings and the noise level given on the command line [mm] (None:
    the dataset's), from ``dvs image``'s parsed options alone (no file is read):
    ``UsageError`` names a bad or contradicting option. Model options (``--grid``,
    ``--degrees``, ``--margin``) describe ``--energy linear-elastic`` and are refused
    with ``auto``, whose step 0 chooses the model."""
    from experiments.command.options import (
        UsageError,
        check_grid,
        check_margin,
        check_noise,
        parse_degrees,
        parse_grid,
    )
    from experiments.fit.stepzero import refuse_model_options
    from experiments.imaging.mapping import ImageSettings
    from experiments.problem.fitting import FitSettings

    shape = "auto" if args.field == "auto" else parse_field(args.field, args.over)
    weight = parse_weight(args.weight)
    degrees = None if args.degrees is None else parse_degrees(args.degrees)
    grid = None
    if args.grid != "auto":
        grid = check_grid(parse_grid(args.grid), degrees or DEGREES, args.grid)
    margin = check_margin(args.margin)
    if args.energy == "auto":
        refuse_model_options(grid, degrees, margin, "--energy linear-elastic")
    noise = None if args.noise is None else check_noise(args.noise)
    if noise == 0:
        raise UsageError("--noise must be positive: the misfit is whitened by it")
    fit = FitSettings(
        names=("E", "nu"),
        energy="linear-elastic",
        grid=grid,
        degrees=degrees or DEGREES,
        margin=margin,
    )
    return ImageSettings(shape, args.over, args.regularizer, weight, args.method, fit), noise


def work(args) -> int:
    """``dvs image FILE.npz --out DIR``: exit 0, 2 for bad input, 3 if a solve failed."""
    import sys
    from dataclasses import replace

    from experiments.command.options import EXIT_NOT_CONVERGED, UsageError, check_output_dir
    from experiments.data.dataset import load_dataset, require_indentation
    from experiments.fit.stepzero import model_record
    from experiments.imaging.mapping import image_dataset
    from experiments.imaging.outputs import document, plot_maps, write_vtu

    settings, noise = image_settings(args)
    check_output_dir(args.out)
    dataset = require_indentation(load_dataset(args.dataset), args.prog)
    if noise is not None:
        dataset = replace(dataset, noise_mm=noise)
    if not dataset.noise_mm or dataset.noise_mm <= 0:
        raise UsageError(
            f"{args.dataset} declares no noise level; give it with --noise MM "
            "(the misfit is whitened by it)"
        )
    print(f"imaging {args.dataset} ({dataset.n_loads} load cases)", flush=True)
    log = lambda line: print(line, flush=True)  # noqa: E731
    chosen, problem = None, None
    if args.energy == "auto":
        from experiments.imaging.continuum import imaging_model

        chosen = imaging_model(dataset, log=log)
        dataset, problem = chosen.dataset(dataset), chosen.problem()
        settings = replace(settings, fit=chosen.settings())
    image = image_dataset(dataset, settings, log=log, problem=problem)
    model = model_record(image.field_problem.problem.model, settings.fit.margin, dataset)
    if chosen is None:
        model.update(source="options", note="", resolution=[])
    else:
        model.update(source=chosen.source, note=chosen.note, resolution=chosen.resolution)
    base_choice = None if chosen is None else chosen.base_choice
    record = document(image, str(args.dataset), dataset.outer_rest, model, base_choice)
    args.out.mkdir(parents=True, exist_ok=True)
    plot_maps(image, dataset.outer_rest, args.out / "map.png", args.out / "std.png")
    if not write_vtu(image, args.out / "map.vtu"):
        print(f"{args.prog}: warning: map.vtu not written: pip install meshio", file=sys.stderr)
    from experiments.output.atomic import atomic_write_json

    atomic_write_json(args.out / "image.json", record)
    residual, strongest = record["residual"], record["strongest_departure"]
    shape = "x".join(map(str, record["field_choice"]["shape"]))
    print(
        f"  field {shape} ({record['field_choice']['rule']}), "
        f"beta {record['weight']['beta_mm2']:.3g} mm^2 ({record['weight']['note']}), "
        f"chi2/n {residual['chi2_over_n']:.3f}, rms {residual['rms_um']:.1f} um, "
        f"{record['effective_dof']:.1f} effective dof; E "
        f"{min(record['field']['E_kPa']):.3g}-{max(record['field']['E_kPa']):.3g} kPa"
    )
    verdict = "significant" if strongest["significant"] else "not significant"
    print(
        f"  strongest departure: E x {strongest['E_ratio_to_mean']:.2f} of the mean at "
        f"({strongest['node_xyz_mm'][0]:.1f}, {strongest['node_xyz_mm'][1]:.1f}) mm, "
        f"{strongest['z']:.1f} std ({verdict}) -> {args.out / 'image.json'}"
    )
    if not record["weight"]["reached"] and residual["chi2_over_n"] > 1.0:
        print(
            f"{args.prog}: warning: no field brings the residual down to the noise "
            f"(chi2/n {residual['chi2_over_n']:.2f} at the smallest weight): the model "
            "lacks something and the map absorbs it (docs/imaging.md; dvs diagnose "
            "names what)",
            file=sys.stderr,
        )
    if not record["success"]:
        print(
            f"{args.prog}: error: the field estimate did not converge ({record['message']}); "
            f"{args.out / 'image.json'} has success: false",
            file=sys.stderr,
        )
        return EXIT_NOT_CONVERGED
    return 0


main = Command("experiments.imaging.command", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
