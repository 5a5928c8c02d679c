"""A short paper in Markdown: abstract, numbered sections, captioned figures, references.

Figures are numbered in the order they are added, and each gets its caption below
it; ``figure_paths`` lists them so that a test can check that every figure written
is shown and every figure shown exists.
"""

from __future__ import annotations

from pathlib import Path

from experiments.output.atomic import atomic_write_text


class Report:
    """Markdown parts collected in order and written once at the end.

    Parameters
    ----------
    title : str
        The report's title.
    """

    def __init__(self, title: str) -> None:
        self.title = title
        self.abstract = ""
        self.sections: list[str] = []
        self.figures: list[str] = []
        self.references: list[str] = []

    def section(self, heading: str, text: str) -> None:
        """Append a numbered section."""
        number = len(self.sections) + 1
        self.sections.append(f"\n## {number}. {heading}\n\n{text.strip()}\n")

    def figure(self, path: str, caption: str) -> str:
        """Markdown of the next numbered figure, with its caption below it."""
        self.figures.append(path)
        number = len(self.figures)
        return f"![Figure {number}]({path})\n\n*Figure {number}.* {caption.strip()}\n"

    def cite(self, reference: str) -> str:
        """Register a reference and return its marker, e.g. "[1]"."""
        if reference not in self.references:
            self.references.append(reference)
        return f"[{self.references.index(reference) + 1}]"

    def text(self) -> str:
        """The whole report."""
        abstract = " ".join(self.abstract.split())
        parts = [f"# {self.title}\n", f"\n**Abstract.** {abstract}\n"]
        parts += self.sections
        if self.references:
            listed = "\n".join(f"{k}. {r}" for k, r in enumerate(self.references, 1))
            parts.append(f"\n## References\n\n{listed}\n")
        return "".join(parts)

    def write(self, path: Path) -> None:
        """Write report.md atomically."""
        atomic_write_text(path, self.text())
