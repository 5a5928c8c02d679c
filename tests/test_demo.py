"""The demo report reads as a short paper and is consistent with the numbers it wrote.

- every figure the demo writes is shown in report.md, and every figure shown exists;
- figures are numbered 1, 2, ... in order, each with a caption;
- every number in the abstract is a value of summary.json (in mm or in um), to the
  precision printed;
- the report has an abstract, a conclusion with limitations and cites the paper.
"""

from __future__ import annotations

import json
import re

import pytest

from experiments.demo.run import main

NUMBER = re.compile(r"(?<![\w.\[])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?![\w\]])")


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["--out", str(out)]) == 0
    return out, (out / "report.md").read_text()


def _leaves(value) -> list[float]:
    if isinstance(value, dict):
        return [x for v in value.values() for x in _leaves(v)]
    if isinstance(value, list):
        return [x for v in value for x in _leaves(v)]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return []
    return [float(value)]


def _matches(token: str, values: list[float]) -> bool:
    """Some value, in mm or in um, rounds to the printed token."""
    shown = float(token)
    if "e" in token.lower():
        mantissa = token.lower().split("e")[0]
        digits = len(mantissa.split(".")[1]) if "." in mantissa else 0
        tolerance = 0.5 * 10.0 ** (-digits) * abs(shown) / abs(float(mantissa))
    else:
        digits = len(token.split(".")[1]) if "." in token else 0
        tolerance = 0.5 * 10.0**-digits
    candidates = values + [1e3 * v for v in values]
    return any(abs(v - shown) <= tolerance * (1 + 1e-9) for v in candidates)


def test_every_figure_written_is_shown_and_every_figure_shown_exists(demo):
    out, text = demo
    shown = re.findall(r"!\[Figure (\d+)\]\(([^)]+)\)", text)
    assert [int(n) for n, _ in shown] == list(range(1, len(shown) + 1))
    for number, path in shown:
        assert (out / path).is_file(), path
        assert f"*Figure {number}.*" in text, f"figure {number} has no caption"
    written = {str(p.relative_to(out)) for p in out.rglob("*.png") if p.parts[-2] != "experiment"}
    assert written <= {path for _, path in shown}, written - {path for _, path in shown}


def test_every_number_in_the_abstract_is_in_the_summary(demo):
    out, text = demo
    abstract = text.split("**Abstract.**", 1)[1].split("\n## ", 1)[0]
    values = _leaves(json.loads((out / "summary.json").read_text()))
    tokens = NUMBER.findall(abstract)
    assert len(tokens) >= 15, tokens
    missing = [t for t in tokens if not _matches(t, values)]
    assert not missing, f"abstract numbers not in summary.json: {missing}"


def test_the_report_reads_as_a_short_paper(demo):
    out, text = demo
    headings = re.findall(r"^## (.+)$", text, flags=re.MULTILINE)
    assert headings[-1] == "References" and "2010" in text.split("## References")[1]
    assert any("Conclusion and limitations" in h for h in headings)
    assert "**Limitations.**" in text and "[1]" in text
    assert "image-reconstructed" in text and "A second dataset" in text
    assert "False" not in text and "nan%" not in text and "two minutes" not in text
    # the paper-faithful method runs in the comparison, and its speed is stated
    compare = json.loads((out / "compare.json").read_text())
    assert compare["paper"]["iterations"] > 0 and compare["speedup_simultaneous_vs_paper"] > 10
