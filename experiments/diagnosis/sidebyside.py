"""``dvs bench sidebyside``: default ``dvs diagnose`` of two checkouts, side by side in one run.

A speed claim against an earlier commit has to be measured in one run on a shared,
noisy machine: each dataset is written once, then diagnosed by this checkout and by
the other (``git worktree add DIR REV`` with its own ``.venv``), one after the other,
each in a fresh process (``experiments.diagnosis.tissuedefaults.timed_default_diagnosis``).
The ratio of CPU times is the figure to read (other jobs change it least)::

    dvs bench sidebyside --other /path/to/worktree A G A:rigid_motion

Each argument is a row of ``experiments.diagnosis.tissuedefaults.ROWS``, with ``:effect`` for
the row's design with that departure injected (docs/results/tissue-defaults.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from experiments.command.options import Command

_RUN = (
    "import json, sys; from experiments.diagnosis.tissuedefaults import timed_default_diagnosis; "
    "print('ROW ' + json.dumps(timed_default_diagnosis(sys.argv[1]), default=str))"
)


def timed_in(root: Path, path: str) -> dict:
    """``timed_default_diagnosis(path)`` run by the checkout at ``root`` (its ``.venv``)."""
    python = root / ".venv" / "bin" / "python"
    done = subprocess.run(
        [str(python), "-c", _RUN, path], cwd=root, capture_output=True, text=True, check=True
    )
    line = [t for t in done.stdout.splitlines() if t.startswith("ROW ")][-1]
    return json.loads(line[4:])


def compare(names, other: Path, log=print) -> list[dict]:
    """Each named dataset diagnosed by the other checkout, then by this one."""
    from experiments.data.dataset import save_dataset
    from experiments.diagnosis.tissuedefaults import row_dataset

    here = Path(__file__).resolve().parents[2]
    log(
        "| data | selected (other -> this) | wall [s] other / this | CPU [s] other / this "
        "| CPU ratio |"
    )
    log("|---|---|---|---|---|")
    rows = []
    for name in names:
        row, _, injected = name.partition(":")
        with tempfile.TemporaryDirectory() as folder:
            path = str(Path(folder) / "data.npz")
            save_dataset(path, row_dataset(row, injected or None))
            before, after = timed_in(other, path), timed_in(here, path)
        ratio = after["cpu_s"] / before["cpu_s"]
        rows.append({"data": name, "other": before, "this": after, "cpu_ratio": ratio})
        chosen = f"{before['selected'] or '-'} -> {after['selected'] or '-'}"
        log(
            f"| {name} | {chosen} | {before['wall_s']:.0f} / {after['wall_s']:.0f} | "
            f"{before['cpu_s']:.0f} / {after['cpu_s']:.0f} | {ratio:.2f} |"
        )
    return rows


def build_parser(prog: str):
    """The options of ``dvs bench sidebyside``."""
    from experiments.command.options import make_parser

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--other", type=Path, required=True, help="the other checkout")
    parser.add_argument("--json", type=Path, default=None, help="write the rows here")
    parser.add_argument("data", nargs="+", help="rows, e.g. A G A:rigid_motion")
    return parser


def work(args) -> int:
    """Check the output file, the rows and the other checkout, then compare."""
    from experiments.command.options import UsageError, check_output_file
    from experiments.diagnosis.tissuedefaults import ROWS, injected_scenarios

    if args.json is not None:
        check_output_file(args.json, ".json", "--json")
    for name in args.data:
        row, _, injected = name.partition(":")
        if row not in ROWS or (injected and injected not in injected_scenarios()):
            rows = ", ".join(sorted(ROWS))
            raise UsageError(f"unknown dataset {name!r}; use a row ({rows}), optionally :effect")
    if not (args.other / ".venv" / "bin" / "python").exists():
        raise UsageError(f"--other: no {args.other}/.venv/bin/python; make that checkout first")
    rows = compare(args.data, args.other, log=lambda text: print(text, flush=True))
    if args.json:
        from experiments.output.atomic import atomic_write_json

        atomic_write_json(args.json, rows)
    return 0


main = Command("experiments.diagnosis.sidebyside", build_parser, work).main

if __name__ == "__main__":
    sys.exit(main())
