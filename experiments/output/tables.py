"""Markdown tables, as every report writes them (docs/formats.md)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def table_lines(header: str | Sequence[str], rows: Iterable[Sequence]) -> list[str]:
    """The lines of a Markdown table: ``header`` (its columns, or their names joined by
    " | " as the table shows them), its separator, then one line per row of cells (each
    written with ``str``)."""
    columns = header.split(" | ") if isinstance(header, str) else list(header)
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return lines


def with_rivals(selected: Sequence[str], rivals: dict) -> str:
    """The effects a diagnosis named, each with the rivals it could not be told from
    (``a or b``), comma-separated; "-" when it named none."""
    named = [" or ".join([e, *rivals[e]]) if e in rivals else e for e in selected]
    return ", ".join(named) or "-"
