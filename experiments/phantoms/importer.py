"""``dvs import compression DIR --out X.npz``: one recipe's silicone-phantom compression
tests as a dataset (docs/formats.md, "Measured experiments"; the reader is
``experiments.data.compression``)."""

from __future__ import annotations

from experiments.command.options import (
    Command,
    check_output_file,
    importer_parser,
    write_dataset,
)
from experiments.data.compression import compression_dataset, compression_summary, read_recipe
from experiments.data.errors import DatasetError


def build_parser(prog: str = "python -m experiments.phantoms.importer"):
    """The options of ``dvs import compression``."""
    parser = importer_parser(
        prog,
        "One recipe's phantom compression tests as a dataset.",
        "folder",
        "one recipe's folder, e.g. .../data/EF10_0T",
    )
    parser.add_argument("--samples", type=int, default=15, help="points per curve (default 15)")
    parser.add_argument(
        "--strain", type=float, default=0.5, help="largest compression / height (default 0.5)"
    )
    return parser


def work(args) -> int:
    """Read the folder, sample its curves, write the dataset."""
    check_output_file(args.out, ".npz")
    if args.samples < 1 or not 0.0 < args.strain < 1.0:
        raise DatasetError("--samples must be >= 1 and --strain in (0, 1)")
    recipe, tests = read_recipe(args.folder)
    dataset = compression_dataset(recipe, tests, args.samples, args.strain)
    summary = compression_summary(recipe, tests, args.samples, args.strain, dataset)
    return write_dataset(args.out, dataset, summary)


main = Command("experiments.phantoms.importer", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
