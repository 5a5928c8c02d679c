"""The docs cover every CLI command and option, and every key of every output format.

Keys are collected from files the commands really write, so a key added to the
code without a line in the format reference (docs/formats.md and docs/formats-*.md)
fails here. The CLI reference is docs/cli.md with docs/cli-*.md.
"""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import numpy as np
import pytest
from formatkeys import format_reference
from formatkeys import json_keys as _keys
from formatkeys import undocumented as _undocumented

from experiments.command.cli import COMMANDS, command_parser, main

DOCS = Path(__file__).resolve().parents[1] / "docs"


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A simulated dataset, the fit of it, and its diagnosis, written by the CLI."""
    root = tmp_path_factory.mktemp("docs")
    dataset = root / "data.npz"
    assert main(["simulate", "--seed", "1", "--out", str(dataset)]) == 0
    assert main(["fit", str(dataset), "--method", "nested", "--out", str(root / "fit")]) == 0
    assert main(["diagnose", str(dataset), "--out", str(root / "diagnosis")]) == 0
    return root


def _sections(text: str, sections: dict[str, str] | None = None) -> dict[str, str]:
    """'### `dvs NAME [SUBCOMMAND]`' headings of one page -> the text of each section, added
    to ``sections``. A section ends at the next such heading or at its page's end, so a
    page's last section never takes in the next page's text."""
    sections = {} if sections is None else sections
    for part in text.split("\n### `dvs ")[1:]:
        words = part.split("`", 1)[0].split()
        name = " ".join(itertools.takewhile(lambda w: re.fullmatch(r"[a-z][a-z-]*", w), words))
        sections[name] = sections.get(name, "") + part
    return sections


def _cli_pages() -> list[Path]:
    """The CLI reference: docs/cli.md (exit codes, workflow verbs, groups) and its
    companion pages docs/cli-*.md (the groups' commands in detail)."""
    pages = [DOCS / "cli.md", *sorted(DOCS.glob("cli-*.md"))]
    assert len(pages) > 1, pages
    return pages


def test_every_command_and_option_is_in_the_cli_reference():
    """Each command has a section of docs/cli.md or docs/cli-*.md that names every
    option it takes."""
    sections: dict[str, str] = {}
    for page in _cli_pages():
        _sections(page.read_text(), sections)
    missing = []
    for name in COMMANDS:
        if name not in sections:
            missing.append(f"section dvs {name}")
            continue
        for action in command_parser(name)._actions:
            for option in action.option_strings:
                if option.startswith("--") and option != "--help" and option not in sections[name]:
                    missing.append(f"dvs {name} {option}")
    assert not missing, f"not in docs/cli.md or docs/cli-*.md: {missing}"


def test_every_script_is_a_dvs_command():
    """Every module that runs as ``python -m`` is in dvs's table, and so is every
    ``python -m experiments.X`` that the docs name."""
    modules = {module for module, _ in COMMANDS.values()}
    root = DOCS.parent
    scripts = {
        ".".join(path.relative_to(root).with_suffix("").parts)
        for path in (root / "experiments").rglob("*.py")
        if 'if __name__ == "__main__"' in path.read_text()
    }
    assert "experiments.inverse.paper" in scripts  # the scan itself works
    assert not scripts - modules - {"experiments.command.cli"}, sorted(scripts - modules)
    pattern = r"python -m (experiments(?:\.\w+)+)"
    assert re.findall(pattern, "run python -m experiments.inverse.paper --out x")
    text = " ".join(path.read_text() for path in DOCS.rglob("*.md"))
    named = set(re.findall(pattern, text + (root / "README.md").read_text()))
    named -= {"experiments.realskin"}  # the package runs experiments.realskin.skinfit
    assert not named - modules, f"scripts without a dvs command: {sorted(named - modules)}"


def test_every_dataset_key_is_in_the_format_reference(written):
    text = format_reference()
    with np.load(written / "data.npz") as data:
        keys = set(data.files)
    assert not _undocumented(keys, text)


def test_every_result_key_is_in_the_format_reference(written):
    text = format_reference()
    document = json.loads((written / "fit" / "result.json").read_text())
    parameter_names = set(document["parameters"])
    labels = set(document["per_load_rms_mm"])
    fixed = set(document["model"]["fixed_parameters"])
    skip = parameter_names | labels | fixed  # data, not keys of the format
    assert not _undocumented(_keys(document), text, skip)


def test_every_diagnosis_key_is_in_the_format_reference(written):
    text = format_reference()
    document = json.loads((written / "diagnosis" / "diagnosis.json").read_text())
    names = set()  # the labels of fitted parameters (steps and stand-ins) are data
    for record in [*document["steps"], *document.get("stand_ins", [])]:
        names |= set(record.get("parameters") or {})
    assert not _undocumented(_keys(document), text, names)


def test_the_api_overview_example_runs():
    text = (DOCS / "api.md").read_text()
    example = text.split("```python\n", 1)[1].split("```", 1)[0]
    namespace: dict = {}
    exec(compile(example, "docs/api.md", "exec"), namespace)
    assert namespace["result"].success
    assert np.allclose(namespace["result"].x, namespace["check"].x, rtol=1e-6)


def test_the_guide_paraview_example_runs(tmp_path, monkeypatch):
    """docs/guide.md's VTU snippet, after the API overview's fit."""
    pytest.importorskip("meshio")
    monkeypatch.chdir(tmp_path)
    api = (DOCS / "api.md").read_text().split("```python\n", 1)[1].split("```", 1)[0]
    guide = (DOCS / "guide.md").read_text()
    snippet = guide.split("## 5. Look at it in ParaView", 1)[1].split("```python\n", 1)[1]
    namespace: dict = {}
    exec(compile(api + snippet.split("```", 1)[0], "docs/guide.md", "exec"), namespace)
    assert (tmp_path / "deformed.vtu").stat().st_size > 1000


ROOT = DOCS.parent
PACKAGES = ("symbolic", "solvers", "experiments", "tests")
TICKED = re.compile(r"`([^`\s]+?)[.,;:)]*`")
MODULE = re.compile(r"^(?:symbolic|solvers|experiments)(?:\.\w+)+$")
SOURCE = re.compile(r"^[\w./-]+\.(?:py|ipynb)$")
FILE = re.compile(r"^(?:symbolic|solvers|experiments|tests|docs)/[\w./-]+\.\w+$")


def _named(text: str):
    """Repository paths and modules a page names in backticks: dotted modules (with an
    attribute after them), source files (``.py``, ``.ipynb``; a short path relative to a
    package, as docs/api.md's tables give them, or a bare file name) and any file under a
    top-level folder. Output files of the commands (``fit/result.json``) are not paths of
    the repository and are not matched."""
    for token in TICKED.findall(text):
        if MODULE.match(token) or SOURCE.match(token) or FILE.match(token):
            yield token


def _exists(token: str) -> bool:
    import importlib
    import importlib.util

    def found(name: str) -> bool:
        try:
            return importlib.util.find_spec(name) is not None
        except ImportError:  # a name under a module, not a package
            return False

    if MODULE.match(token):
        parts = token.split(".")
        n = next(n for n in range(len(parts), 0, -1) if found(".".join(parts[:n])))
        target = importlib.import_module(".".join(parts[:n]))
        for attribute in parts[n:]:
            if not hasattr(target, attribute):
                return False
            target = getattr(target, attribute)
        return True
    if "/" not in token:
        return any(any(ROOT.joinpath(p).rglob(token)) for p in (*PACKAGES, "docs"))
    return any(ROOT.joinpath(base, token).exists() for base in ("", *PACKAGES))


def test_every_path_and_module_the_docs_name_exists():
    """README.md and docs/ (not docs/results/, whose pages record a study at the commit
    they name): every module, source file and repository file named in backticks exists."""
    broken = "`solvers/diagnosis/linear.py`, `experiments.design.designcommand`, `docs/nowhere.md`"
    assert list(_named(broken)) == [t.strip("`") for t in broken.split(", ")]
    assert not any(_exists(token) for token in _named(broken))  # the checker sees a break
    assert _exists("solvers/forward/linearpath.py") and _exists("experiments.design.command")
    pages = [ROOT / "README.md"] + [p for p in DOCS.rglob("*.md") if "results" not in p.parts]
    missing = [
        f"{page.relative_to(ROOT)}: {token}"
        for page in pages
        for token in dict.fromkeys(_named(page.read_text()))
        if not _exists(token)
    ]
    assert not missing, missing
