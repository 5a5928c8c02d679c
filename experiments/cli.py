"""The ``dvs`` command: one table of subcommands, each a module with its own parser.

Every subcommand's module has ``build_parser(prog)`` and ``main(argv, prog)`` and runs
as ``python -m MODULE`` too. Only the module of the command given is imported, so
``dvs --help`` and a bad option answer at once. The contract (exit 0, or 2 with one
line on stderr, never a traceback) is ``experiments.options.run_guarded``.
"""

from __future__ import annotations

import argparse
import importlib
from importlib import metadata

from experiments.options import OneLineParser

CORE = {
    "demo": ("experiments.demo.run", "run the main job on the embedded forehead phantom"),
    "simulate": ("experiments.phantom.simulate", "write a synthetic dataset from the phantom"),
    "fit": ("experiments.fitcommand", "estimate parameters from a dataset, with a verdict"),
    "compare": ("experiments.inverse.compare", "simultaneous vs nested vs paper-faithful"),
    "diagnose": ("experiments.diagnosis.diagnose", "find the effect the model lacks"),
    "next": ("experiments.design.nextpress", "the next press of an experiment, from its data"),
    "transient": ("experiments.dynamics.transient", "transient from rest against equilibrium"),
    "reconstruct": ("experiments.stereo.reconstruct", "images of the marked skin -> dataset"),
}
"""The commands of docs/cli.md's "Core commands" table: name -> (module, one-line help)."""

RESEARCH = {
    "paper": ("experiments.inverse.paper", "the paper's Table 1 on data with known truth"),
    "bench": ("experiments.inverse.bench", "build and solve times, memory, scaling, targets"),
    "batch": ("experiments.inverse.batch", "multi-start and coverage studies on dask"),
    "forward": ("experiments.phantom.forward", "the deformed phantom under a known force"),
    "dynamic": ("experiments.dynamics.inverse", "mu and gamma from marker trajectories"),
    "study": ("experiments.diagnosis.study", "the diagnosis of every effect over seeds"),
    "detection": ("experiments.diagnosis.detection", "how large an effect must be to be found"),
    "outoflibrary": ("experiments.diagnosis.outoflibrary", "data from a linear-elastic FE slab"),
    "continuum-loop": ("experiments.diagnosis.continuum", "the loop on scikit-fem continuum data"),
    "design": ("experiments.design.command", "choose where and how hard to press (design.json)"),
    "designbench": ("experiments.design.bench", "design search: speed, gap, against by hand"),
    "image": ("experiments.imaging.command", "Young's modulus as a field, with its uncertainty"),
    "imagebench": ("experiments.imaging.bench", "stiffness imaging: fit time against N"),
    "imageweights": ("experiments.imaging.weightstudy", "which weight rule sees a small inclusion"),
    "imageadaptive": ("experiments.imaging.adaptive", "adaptive imaging at random places"),
    "realskin": ("experiments.realskin.study", "real in vivo skin: fit and close the loop"),
    "realskin-twin": ("experiments.realskin.twin", "synthetic twin of the keloid extensometer"),
    "realskin-checks": ("experiments.realskin.checks", "checks of the keloid's stiff region"),
    "realskin-strain": ("experiments.realskin.strain", "model-free axial strain from the DIC"),
    "realskin-continuum": ("experiments.realskin.continuum", "real skin: E and nu of the continua"),
    "realskin-authors": ("experiments.realskin.reproduce", "the authors' 2D fit, reproduced"),
    "realskin-data": ("experiments.realskin.data", "summary of the real skin measurements"),
    "realcheck": ("experiments.stereo.realcheck", "the stereo pipeline on real images"),
    "boardbench": ("experiments.stereo.boardbench", "checkerboard detection: time and accuracy"),
    "render": ("experiments.stereo.render", "synthetic images of the forehead experiment"),
}
"""The research scripts (docs/cli.md, "Research scripts"): name -> (module, help)."""

COMMANDS = {**CORE, **RESEARCH}


def version() -> str:
    """The installed package's version (or 'unknown' when run from a bare checkout)."""
    try:
        return metadata.version("dvs")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser: ``--version`` and the list of commands (for ``--help``)."""
    parser = OneLineParser(
        prog="dvs",
        description="Dynamic volume spline models of soft tissue: forward and inverse "
        "solutions. 'dvs COMMAND --help' shows a command's options and defaults.",
    )
    parser.add_argument("--version", action="version", version=f"dvs {version()}")
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=OneLineParser
    )
    for name, (_, text) in COMMANDS.items():
        sub = commands.add_parser(name, help=text, add_help=False)
        sub.add_argument("arguments", nargs=argparse.REMAINDER)
    return parser


def command_parser(name: str) -> argparse.ArgumentParser:
    """The full parser of one command (imports its module)."""
    return importlib.import_module(COMMANDS[name][0]).build_parser(f"dvs {name}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dvs`` console script."""
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        module = importlib.import_module(COMMANDS[argv[0]][0])
        return module.main(argv[1:], prog=f"dvs {argv[0]}")
    build_parser().parse_args(argv)  # --help, --version, or a one-line usage error
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
