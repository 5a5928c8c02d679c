"""Keys of a JSON output and which of them the format reference (docs/formats.md and its
companion pages, docs/formats-*.md) does not name (for the tests)."""

from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def format_pages() -> list[Path]:
    """docs/formats.md, then every docs/formats-*.md in name order."""
    return [DOCS / "formats.md", *sorted(DOCS.glob("formats-*.md"))]


def format_reference() -> str:
    """The text of every page of the format reference, one after the other."""
    return "\n".join(page.read_text() for page in format_pages())


class _Reference:
    """The format reference as one text, read the way a page is (``FORMATS.read_text()``)."""

    def read_text(self) -> str:
        return format_reference()


FORMATS = _Reference()
"""The format reference every key of every written output must appear in."""


def json_keys(document) -> set[str]:
    """Every dict key in a JSON document (lists are searched, their indices are not keys)."""
    found = set()
    if isinstance(document, dict):
        for key, value in document.items():
            found.add(key)
            found |= json_keys(value)
    elif isinstance(document, list):
        for value in document:
            found |= json_keys(value)
    return found


def undocumented(keys, text: str, skip=()) -> list[str]:
    """The keys not written as `key` in ``text``, but for those in ``skip`` (data, not keys)."""
    return sorted(k for k in keys if f"`{k}`" not in text and k not in skip)
