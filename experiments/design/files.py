"""The keys every ``next.json`` of ``dvs next`` starts with (schema ``dvs-design/1``,
docs/formats.md; the file's presses are read by ``experiments.data.designfile``)."""

from __future__ import annotations

from experiments.data.designfile import SCHEMA


def next_header(row: dict, args, target: str) -> dict:
    """The keys every ``next.json`` starts with: a ``dvs-design/1`` file whose ``presses``
    hold the proposal (or are empty), what was asked and from which data."""
    press = row["press"]
    return {
        "schema": SCHEMA,
        "kind": "next",  # beside dvs design's files of the same schema
        "target": target,
        "dataset": [str(p) for p in args.datasets],
        "presses_so_far": row["presses"],
        "budget": args.budget,
        "stop": row["stop"],
        "presses": [] if press is None else [press],
    }
