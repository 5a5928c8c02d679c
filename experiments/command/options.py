"""Command-line plumbing shared by ``dvs`` and every research script.

The contract of every command (docs/cli.md): exit 0 on success; exit 2 with one
line on stderr for bad input, never a traceback; 130 when interrupted. Each
command module has ``build_parser(prog)`` and ``main(argv, prog)``; ``run_guarded``
turns the errors a user can fix into that one line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from experiments.data.dataset import DatasetError

EXIT_BAD_INPUT = 2
"""Exit code for input the user can fix (an option, a path, a dataset)."""

EXIT_INTERNAL = 1
"""Exit code of an error that is not the input's fault (a bug: please report it)."""

EXIT_NOT_CONVERGED = 3
"""Exit code when a solver did not converge or a computation failed (a JSON written
then says ``success: false``)."""

EXIT_INTERRUPTED = 130
"""Exit code after Ctrl-C (128 + SIGINT)."""


class UsageError(ValueError):
    """Bad input that a user can fix; printed as one line, exit code 2."""


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (and exit code 2)."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _DefaultsFormatter(argparse.RawDescriptionHelpFormatter):
    """Help that ends each option's line with its default, when it has a useful one
    (description and epilog are kept as written)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        empty = default is None or default is False or default is argparse.SUPPRESS
        empty = empty or (isinstance(default, (str, list)) and not default)
        if action.required or empty or "%(default)" in text or not action.option_strings:
            return text
        return f"{text} (default: %(default)s)"


def not_converged(prog: str, what: str, path) -> int:
    """One line saying that ``what`` did not converge and ``path`` says so; exit 3."""
    print(f"{prog}: error: {what} did not converge; {path} has success: false", file=sys.stderr)
    return EXIT_NOT_CONVERGED


def make_parser(prog: str, description: str) -> OneLineParser:
    """A one-line-error parser that shows every option's default in ``--help``."""
    return OneLineParser(prog=prog, description=description, formatter_class=_DefaultsFormatter)


def one_line(error: BaseException) -> str:
    """The first line of an error's message, or its type's name when it has none."""
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


USER_ERRORS = (UsageError, DatasetError, ValueError, OSError)
"""Errors that mean bad input (options, paths, files): one line and exit 2."""


@dataclass(frozen=True)
class Command:
    """A ``dvs`` command as its module states it: its options and its work.

    ``main`` parses the arguments and runs ``work(args)`` under the contract
    (``run_guarded``); it is what ``experiments.command.cli`` calls with the command's
    name, and what ``python -m MODULE`` runs.

    Attributes
    ----------
    module : str
        The module's dotted name (the ``prog`` of ``python -m MODULE``).
    build_parser : callable
        ``build_parser(prog)`` -> the command's ``argparse`` parser.
    work : callable
        ``work(args)`` -> exit code (None means 0): checks its input, then works.
        ``args.prog`` holds the name the command runs under ("dvs fit"), for its
        messages.
    """

    module: str
    build_parser: Callable[[str], argparse.ArgumentParser]
    work: Callable[[argparse.Namespace], int | None]

    def main(self, argv: list[str] | None = None, prog: str | None = None) -> int:
        """Parse ``argv`` and run the work: exit 0, or 2 with one line for bad input."""
        prog = prog or f"python -m {self.module}"
        args = self.build_parser(prog).parse_args(argv)
        args.prog = prog
        return run_guarded(prog, lambda: self.work(args))


def run_guarded(prog: str, work: Callable[[], int | None]) -> int:
    """Run ``work`` under the contract: every failure is one line on stderr.

    Bad input (``USER_ERRORS``) exits 2; a failed computation (``RuntimeError``: a solver
    without equilibrium, a failed transient, CasADi) exits 3; anything else is a bug and
    exits 1 (``DVS_DEBUG=1`` re-raises it with its traceback); Ctrl-C exits 130. Python
    warnings of the libraries are silenced (``DVS_DEBUG=1`` shows them): the command's
    own warnings are one-line messages.

    Parameters
    ----------
    prog : str
        Name printed before the message, e.g. "dvs fit".
    work : callable
        The command's body; returns an exit code (None means 0).
    """
    import os
    import warnings

    try:
        with warnings.catch_warnings():
            if not os.environ.get("DVS_DEBUG"):  # library warnings would break the one line
                warnings.simplefilter("ignore")
            return int(work() or 0)
    except USER_ERRORS as error:
        print(f"{prog}: error: {one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except RuntimeError as error:  # solver failures: EquilibriumError, TransientError, CasADi
        if os.environ.get("DVS_DEBUG"):
            raise
        print(f"{prog}: error: the computation failed: {one_line(error)}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    except Exception as error:  # noqa: BLE001  the contract: never a traceback
        if os.environ.get("DVS_DEBUG"):
            raise
        print(
            f"{prog}: internal error: {type(error).__name__}: {one_line(error)} "
            "(please report it; DVS_DEBUG=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


def write_dataset(path: Path, dataset, summary: str) -> int:
    """Save ``dataset`` to ``path`` (docs/formats.md) and print one line of what it holds:
    the end of every command that makes a dataset (``dvs simulate``, ``dvs import``);
    exit code 0."""
    from experiments.data.dataset import save_dataset

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_dataset(path, dataset)
    print(f"wrote {path}: {summary}")
    return 0


def plural(count: int, noun: str) -> str:
    """'1 load case', '2 load cases'."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


def parse_grid(text: str, option: str = "--grid", sizes: int = 3) -> tuple[int, ...]:
    """'9x9x2' -> (9, 9, 2): ``sizes`` integers >= 2 joined by x (two for a planar grid,
    '21x11'): one syntax for every command's grid."""
    try:
        grid = tuple(int(part) for part in text.lower().split("x"))
    except ValueError:
        grid = ()
    if len(grid) != sizes or min(grid) < 2:
        example = "x".join(["9", "9", "2"][:sizes] if sizes <= 3 else ["9"] * sizes)
        count = {2: "two", 3: "three"}.get(sizes, str(sizes))
        raise UsageError(f"{option} must look like {example} ({count} integers >= 2), got {text!r}")
    return grid


def parse_names(text: str, option: str = "--params") -> tuple[str, ...]:
    """'alpha_u,alpha_v' -> ('alpha_u', 'alpha_v'), checked against the model's names."""
    from symbolic.model import PARAMETERS

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PARAMETERS]
    if not names or unknown:
        raise UsageError(f"{option} takes a comma list from {', '.join(PARAMETERS)}; got {text!r}")
    return names


MAX_LIST = 100
"""Most entries of a comma-list option (seeds, factors, ratios, frames)."""


def parse_numbers(text: str, option: str, kind=float) -> tuple:
    """'1,2,3' -> (1, 2, 3) of ``kind``: finite, at most ``MAX_LIST``; '' gives ()."""
    import math

    try:
        values = tuple(kind(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise UsageError(f"{option} takes a comma list of numbers, got {text!r}") from None
    if len(values) > MAX_LIST or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{option} takes at most {MAX_LIST} finite numbers, got {text!r}")
    return values


def check_seed(seed: int, option: str = "--seed") -> int:
    """A random seed numpy accepts: 0 to 2^32 - 1."""
    if not 0 <= seed < 2**32:
        raise UsageError(f"{option} must be an integer from 0 to 2^32 - 1, got {seed}")
    return seed


def check_noise(noise: float, option: str = "--noise") -> float:
    """A marker noise level [mm] in [0, 1]."""
    if not 0 <= noise <= 1:
        raise UsageError(f"{option} must be a number in [0, 1] mm, got {noise}")
    return noise


MAX_MARGIN_MM = 100.0
"""Widest band of tissue beyond the markers (``--margin``) [mm]."""


def importer_parser(prog: str, description: str, source: str, source_help: str):
    """The options every ``dvs import`` command shares: the measured file or folder
    ``source`` (a ``Path``) and ``--out``, the dataset file (.npz) to write."""
    parser = make_parser(prog, description)
    parser.add_argument(source, type=Path, help=source_help)
    parser.add_argument(
        "--out", type=path_argument, required=True, help="dataset file (.npz) to write"
    )
    return parser


def add_margin_argument(parser, default: float = 0.0) -> None:
    """``--margin MM`` of ``dvs fit`` and ``dvs diagnose`` (``FitSettings.margin``)."""
    parser.add_argument(
        "--margin",
        type=float,
        default=default,
        help="width [mm] of tissue beyond the markers the volume also covers (0: ends at the "
        "markers; e.g. 10 for the continua, docs/continuum.md)",
    )


def check_margin(margin: float, option: str = "--margin") -> float:
    """A margin of tissue beyond the markers [mm] in [0, 100]."""
    if not 0 <= margin <= MAX_MARGIN_MM:
        raise UsageError(
            f"{option} must be a width in [0, {MAX_MARGIN_MM:g}] mm (e.g. 10), got {margin}"
        )
    return margin


def _writable(directory, option: str, path) -> None:
    """Probe ``directory`` with a temporary file (``os.access`` says yes to root)."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise UsageError(
            f"{option} {path}: cannot write in {directory} ({reason}); choose another place"
        ) from None


def check_output_file(path, suffix: str | None = None, option: str = "--out"):
    """Check, before any work, that ``path`` can be written as a file (nothing is created).

    Raises
    ------
    UsageError
        When ``path`` is empty, has the wrong suffix, is a directory, or its folder
        cannot be made or written.
    """
    from pathlib import Path

    if path is None or str(path) == "":
        raise UsageError(f"{option} needs a file name")
    path = Path(path)
    if suffix is not None and path.suffix != suffix:
        raise UsageError(f"{option} must name a {suffix} file, got {path}")
    if path.is_dir():
        raise UsageError(f"{option} {path} is a directory; name a file")
    check_output_dir(path.parent, option, shown=path)
    return path


def check_output_dir(path, option: str = "--out", shown=None):
    """Check, before any work, that ``path`` can become a writable output directory.

    Nothing is created: the directory is made when the first output is written, so a
    command that fails on its input leaves nothing behind.

    Raises
    ------
    UsageError
        When ``path`` is empty, an existing file, below a file, or not writable.
    """
    from pathlib import Path

    if path is None or str(path) == "":
        raise UsageError(f"{option} needs a directory name")
    path = Path(path)
    shown = path if shown is None else shown
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {shown}: {path} is an existing file; name a directory")
    ancestor = path.absolute()
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise UsageError(f"{option} {shown}: {ancestor} is a file, not a directory")
    _writable(ancestor, option, shown)
    return path


def path_argument(text: str):
    """argparse ``type`` of a path option: a non-empty name (``Path('')`` would mean '.')."""
    from pathlib import Path

    if not text.strip():
        raise argparse.ArgumentTypeError("needs a path, got an empty name")
    return Path(text)


# ------------------------------------------------------------- spline grids
MAX_LAYERS = 12
"""Most control-point layers through the thickness (``--grid``'s third number)."""

MAX_CONTROL_POINTS = 66 * 66 * 6
"""Most control points of a fit (about 8 times the 33 x 33 x 4 grid of the benchmarks)."""


def check_grid(grid: tuple[int, int, int], degrees, text: str, option: str = "--grid"):
    """A control grid the degrees allow (>= degree + 1 each) and the machine can afford."""
    least = tuple(d + 1 for d in degrees)
    if any(g < m for g, m in zip(grid, least)):
        raise UsageError(
            f"{option} {text}: degrees {tuple(degrees)} need at least "
            f"{'x'.join(map(str, least))} control points"
        )
    if grid[2] > MAX_LAYERS or grid[0] * grid[1] * grid[2] > MAX_CONTROL_POINTS:
        raise UsageError(
            f"{option} {text}: at most {MAX_LAYERS} layers and {MAX_CONTROL_POINTS} control points"
        )
    return grid


def parse_degrees(text: str, option: str = "--degrees") -> tuple[int, int, int]:
    """'3x3x2' -> (3, 3, 2): three integers in 1-5."""
    try:
        degrees = tuple(int(part) for part in text.lower().split("x"))
    except ValueError:
        degrees = ()
    if len(degrees) != 3 or not all(1 <= d <= 5 for d in degrees):
        raise UsageError(f"{option} must look like 3x3x1 (three integers in 1-5), got {text!r}")
    return degrees


def verb(options: list) -> str:
    """'sets' after one option name, 'set' after several."""
    return "sets" if len(options) == 1 else "set"


def add_noise_seed_arguments(parser) -> None:
    """``--noise MM`` and ``--seed N`` of the commands that simulate marker data
    (``check_noise_seed`` checks them)."""
    parser.add_argument("--noise", type=float, default=0.02, help="marker noise [mm], 0-1")
    parser.add_argument("--seed", type=int, default=0, help="random seed, 0 to 2^32 - 1")


def check_noise_seed(args) -> None:
    """Check ``args.noise`` [mm] and ``args.seed`` of ``add_noise_seed_arguments``."""
    check_noise(args.noise)
    check_seed(args.seed)


def add_dataset_argument(parser, more: str = "", nargs: str | None = None) -> None:
    """The ``dataset`` argument of a command that reads a dataset v1 (.npz): ``more`` ends
    its help (e.g. "; default: phantom"); ``nargs="?"`` makes it optional (None then)."""
    parser.add_argument("dataset", type=path_argument, nargs=nargs, help=f"dataset v1 (.npz){more}")
