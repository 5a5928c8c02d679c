"""The ``dvs`` command: workflow verbs at the top, research commands in groups.

``dvs fit``, ``dvs diagnose``, ... are the verbs; ``dvs bench inverse``, ``dvs study
paper``, ``dvs realskin fit`` the groups' commands (docs/cli.md). Every command's module
has ``build_parser(prog)`` and ``main(argv, prog)`` and runs
as ``python -m MODULE`` too. Only the module of the command given is imported, so
``dvs --help`` and a bad option answer at once. The contract (exit 0, or 2 with one
line on stderr, never a traceback) is ``experiments.command.options.run_guarded``.
"""

from __future__ import annotations

import argparse
import importlib
from importlib import metadata

from experiments.command.options import OneLineParser

VERBS = {
    "demo": ("experiments.demo.run", "run the main job on the embedded forehead phantom"),
    "simulate": ("experiments.phantom.simulate", "write a synthetic dataset from the phantom"),
    "reconstruct": ("experiments.stereo.reconstruct", "images of the marked skin -> dataset"),
    "fit": ("experiments.fit.command", "estimate parameters from a dataset, with a verdict"),
    "diagnose": ("experiments.diagnosis.diagnose", "find the effect the model lacks"),
    "image": (
        "experiments.imaging.command",
        "Young's modulus as a field, with its uncertainty",
    ),
    "design": (
        "experiments.design.command",
        "choose where and how hard to press (design.json)",
    ),
    "next": ("experiments.design.nextpress", "the next press of an experiment, from its data"),
    "transient": ("experiments.dynamics.transient", "transient from rest against equilibrium"),
}
"""The workflow verbs (docs/cli.md, "Workflow commands"): name -> (module, one-line help)."""

GROUPS = {
    "bench": (
        "speed and accuracy benchmarks: inverse, design, image, factorisation, board, ...",
        {
            "inverse": (
                "experiments.inverse.bench",
                "build and solve times, memory, scaling",
            ),
            "design": (
                "experiments.design.bench",
                "design search: speed, gap, against by hand",
            ),
            "image": ("experiments.imaging.bench", "stiffness imaging: fit time against N"),
            "factorisation": (
                "experiments.inverse.factorisation",
                "sparse direct solvers of K side by side",
            ),
            "board": ("experiments.stereo.boardbench", "checkerboard detection: time, accuracy"),
            "sidebyside": (
                "experiments.diagnosis.sidebyside",
                "default dvs diagnose of two checkouts, side by side",
            ),
        },
        "inverse",
    ),
    "study": (
        "research studies on data with known truth: paper, compare, diagnosis, ...",
        {
            "paper": ("experiments.inverse.paper", "the paper's Table 1 on data with known truth"),
            "compare": ("experiments.inverse.compare", "simultaneous vs nested vs paper-faithful"),
            "batch": ("experiments.inverse.batch", "multi-start and coverage studies on dask"),
            "forward": ("experiments.phantom.forward", "the deformed phantom under a known force"),
            "dynamic": ("experiments.dynamics.inverse", "mu and gamma from marker trajectories"),
            "diagnosis": (
                "experiments.diagnosis.study",
                "the diagnosis of every effect over seeds",
            ),
            "detection": (
                "experiments.diagnosis.detection",
                "how large an effect must be to be found",
            ),
            "outoflibrary": ("experiments.diagnosis.outoflibrary", "data from a linear FE slab"),
            "continuum": (
                "experiments.diagnosis.continuumstudy",
                "the loop on scikit-fem continuum data",
            ),
            "imageweights": (
                "experiments.imaging.weightstudy",
                "which weight rule sees an inclusion",
            ),
            "imageadaptive": ("experiments.imaging.adaptive", "adaptive imaging at random places"),
            "render": ("experiments.stereo.render", "synthetic images of the forehead experiment"),
            "realcheck": ("experiments.stereo.realcheck", "the stereo pipeline on real images"),
            "truth-cube": (
                "experiments.truthcube.cubestudy",
                "the Truth Cube: nu, the plate, each state predicted",
            ),
            "phantoms": (
                "experiments.phantoms.study",
                "silicone phantoms: E, the B series predicted",
            ),
        },
        "diagnosis",
    ),
    "import": (
        "measured experiments to the dataset format: truth-cube, compression, extensometer",
        {
            "truth-cube": ("experiments.truthcube.cubeimport", "the Truth Cube's bead file"),
            "compression": (
                "experiments.phantoms.importer",
                "one recipe's phantom compression tests",
            ),
            "extensometer": (
                "experiments.realskin.skinimport",
                "one case of the skin extensometer (DIC, pads, force)",
            ),
        },
        "truth-cube",
    ),
    "realskin": (
        "real in vivo skin (the extensometer data): fit, strain, data",
        {
            "fit": ("experiments.realskin.skinfit", "the real skin through the shared loop"),
            "strain": ("experiments.realskin.strain", "model-free axial strain from the DIC"),
            "data": ("experiments.realskin.data", "summary of the real skin measurements"),
        },
        "fit",
    ),
}
"""The groups: name -> (one-line help, {subcommand: (module, help)}, default).
``dvs GROUP --option ...`` (an option where the subcommand goes) runs the group's
default, the command ``dvs bench``, ``dvs study`` and ``dvs realskin`` were before the
groups."""

COMMANDS = {
    **VERBS,
    **{
        f"{group} {name}": entry
        for group, (_, table, _) in GROUPS.items()
        for name, entry in table.items()
    },
}
"""Every command by its full name ("fit", "bench inverse"): name -> (module, help)."""

FORMER = {
    "compare": "study compare",
    "paper": "study paper",
    "batch": "study batch",
    "forward": "study forward",
    "dynamic": "study dynamic",
    "detection": "study detection",
    "outoflibrary": "study outoflibrary",
    "continuum-loop": "study continuum",
    "imageweights": "study imageweights",
    "imageadaptive": "study imageadaptive",
    "render": "study render",
    "realcheck": "study realcheck",
    "designbench": "bench design",
    "imagebench": "bench image",
    "boardbench": "bench board",
    "realskin-strain": "realskin strain",
    "realskin-data": "realskin data",
}
"""The flat names of before the groups, still accepted (docs/cli-groups.md): old -> new."""


def resolve(argv: list[str]) -> tuple[str, list[str]] | None:
    """(full command name, its arguments) of ``argv``, or None when it names no command
    (the top-level parser answers then: --help, --version, a usage error)."""
    if not argv:
        return None
    head, rest = argv[0], argv[1:]
    if head in FORMER:
        return FORMER[head], rest
    if head in VERBS:
        return head, rest
    if head in GROUPS:
        _, table, default = GROUPS[head]
        if rest and rest[0] in table:
            return f"{head} {rest[0]}", rest[1:]
        if rest and rest[0].startswith("-") and rest[0] not in ("-h", "--help"):
            return f"{head} {default}", rest
    return None


def version() -> str:
    """The installed package's version (or 'unknown' when run from a bare checkout)."""
    try:
        return metadata.version("dvs")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser: ``--version``, the verbs and the groups (for ``--help``)."""
    parser = OneLineParser(
        prog="dvs",
        description="Dynamic volume spline models of soft tissue: forward and inverse "
        "solutions. 'dvs COMMAND --help' shows a command's options and defaults; "
        "'dvs GROUP --help' lists a group's commands.",
    )
    parser.add_argument("--version", action="version", version=f"dvs {version()}")
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=OneLineParser
    )
    for name, (_, text) in VERBS.items():
        commands.add_parser(name, help=text, add_help=False).add_argument(
            "arguments", nargs=argparse.REMAINDER
        )
    for group, (text, table, _) in GROUPS.items():
        sub = commands.add_parser(group, help=text, description=text)
        inner = sub.add_subparsers(
            dest="subcommand", required=True, metavar="COMMAND", parser_class=OneLineParser
        )
        for name, (_, help_text) in table.items():
            inner.add_parser(name, help=help_text, add_help=False).add_argument(
                "arguments", nargs=argparse.REMAINDER
            )
    return parser


def command_parser(name: str) -> argparse.ArgumentParser:
    """The full parser of one command by its full name (imports its module)."""
    return importlib.import_module(COMMANDS[name][0]).build_parser(f"dvs {name}")


def main(argv: list[str] | None = None) -> int:
    """The command line: run the command ``argv`` names (default ``sys.argv[1:]``)."""
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    found = resolve(argv)
    if found is not None:
        name, rest = found
        return importlib.import_module(COMMANDS[name][0]).main(rest, prog=f"dvs {name}")
    build_parser().parse_args(argv)  # --help, --version, or a one-line usage error
    return 2


def console() -> int:
    """The ``dvs`` console script: ``main`` in a process set up for the work
    (``experiments.command.process``: freed memory kept, numpy's BLAS on one thread)."""
    from experiments.command.process import configure

    configure()
    return main()


if __name__ == "__main__":
    raise SystemExit(console())
