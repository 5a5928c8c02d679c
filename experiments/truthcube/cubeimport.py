"""``dvs import truth-cube FILE --out X.npz``: the Truth Cube's bead file as a dataset
(docs/formats.md, "Measured experiments"; the reader is ``experiments.data.truthcube``)."""

from __future__ import annotations

from experiments.command.options import (
    Command,
    check_output_file,
    importer_parser,
    write_dataset,
)
from experiments.data.truthcube import read_truth_cube, truth_cube_dataset, truth_cube_summary


def build_parser(prog: str = "python -m experiments.truthcube.cubeimport"):
    """The options of ``dvs import truth-cube``."""
    return importer_parser(
        prog, "The Truth Cube's bead file as a dataset.", "file", "uniaxial_positions.csv"
    )


def work(args) -> int:
    """Read the bead file and write the dataset."""
    check_output_file(args.out, ".npz")
    cube = read_truth_cube(args.file)
    return write_dataset(args.out, truth_cube_dataset(cube), truth_cube_summary(cube))


main = Command("experiments.truthcube.cubeimport", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
