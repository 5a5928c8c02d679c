"""The keys every ``next.json`` of ``dvs next`` starts with (schema ``dvs-design/1``,
docs/formats.md; the file's presses are read by ``experiments.data.designfile``), and
its ``why``."""

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


def next_why(press: dict | None, measure: str, **extra) -> dict | None:
    """``why`` of ``next.json``: the question the proposed press answers, the ``measure``
    of it before and after the press (predicted), ``extra`` keys, and the progress the
    press makes (eq. D7 or I13); None when the loop stops.

    Parameters
    ----------
    press : dict or None
        The proposed press (its ``answers``, ``{measure}_before``, ``{measure}_after`` and
        ``progress``), or None.
    measure : str
        "ratio" (the question's value over its need) or "information" (lambda of the
        inclusion).
    """
    if press is None:
        return None
    return {
        "question": press["answers"],
        **{key: press[key] for key in (f"{measure}_before", f"{measure}_after")},
        **extra,
        "progress": press["progress"],
    }
