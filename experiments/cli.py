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


def _demo(args: argparse.Namespace) -> int:
    from experiments import demo

    return demo.run(args.out)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="dvs",
        description="Dynamic volume spline models of soft tissue: forward and inverse solutions.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = commands.add_parser("demo", help="run the main job on the embedded forehead phantom")
    demo.add_argument("--out", type=Path, default=Path("demo-output"), help="output directory")
    demo.set_defaults(handler=_demo)
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
