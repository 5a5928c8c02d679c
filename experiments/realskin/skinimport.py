"""``dvs import extensometer DIR --out X.npz``: one case of the skin extensometer as a
dataset (docs/formats.md, "Measured experiments"; rule 23 of
docs/formats-validation.md; the reader is ``experiments.realskin.data.read_case``, the
mapping ``experiments.realskin.skindataset``)."""

from __future__ import annotations

from experiments.command.options import (
    Command,
    check_output_file,
    importer_parser,
    write_dataset,
)


def build_parser(prog: str = "python -m experiments.realskin.skinimport"):
    """The options of ``dvs import extensometer``."""
    return importer_parser(
        prog,
        "One case of the skin extensometer as a dataset.",
        "folder",
        "one case's folder, e.g. .../skin-extensometer/healthy",
    )


def work(args) -> int:
    """Read the case's folder and write the dataset."""
    check_output_file(args.out, ".npz")
    from experiments.realskin.data import read_case
    from experiments.realskin.skindataset import skin_dataset, skin_summary

    case = read_case(args.folder)
    return write_dataset(args.out, skin_dataset(case), skin_summary(case))


main = Command("experiments.realskin.skinimport", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
