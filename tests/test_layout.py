"""The layout: no import cycles, layers that only point down, modules of readable size.

The import graph is read from the source (every ``import`` and ``from ... import``,
inside functions too), so a cycle hidden behind a local import is still one.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("symbolic", "solvers", "experiments")
LAYER = {name: rank for rank, name in enumerate(PACKAGES)}
MAX_LINES = 400
"""Largest module: lines of code, not counting the module docstring (docs/contributing.md)."""


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {
        _module_name(path): path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
    }


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules that ``name`` imports (a submodule when one is named)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [
                f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base
                for alias in node.names
            ]
        else:
            continue
        found |= {t for t in targets if t in known}
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(name, path, known) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return found


def test_the_graph_reader_sees_a_cycle_and_relative_imports(tmp_path):
    """The checker itself: a two-module cycle is found, a chain is not."""
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    graph = _graph()
    assert "experiments.stereo.cameras" in graph["experiments.stereo.reconstruct"]
    assert "symbolic.model" in graph["solvers.inverse.problem"]


def test_there_are_no_import_cycles():
    cycles = _cycles(_graph())
    assert not cycles, f"import cycles: {cycles}"


def test_layers_only_import_downwards():
    """symbolic <- solvers <- experiments: nothing imports a layer above its own."""
    upward = [
        f"{name} -> {other}"
        for name, targets in _graph().items()
        for other in targets
        if LAYER[other.split(".")[0]] > LAYER[name.split(".")[0]]
    ]
    assert not upward, f"imports against the layering: {upward}"


@pytest.mark.parametrize("name", sorted(_modules()))
def test_module_size(name):
    path = _modules()[name]
    source = path.read_text()
    tree = ast.parse(source)
    docstring = 0
    first = tree.body[0] if tree.body else None
    if isinstance(first, ast.Expr) and isinstance(getattr(first, "value", None), ast.Constant):
        docstring = first.end_lineno - first.lineno + 1
    lines = len(source.splitlines()) - docstring
    assert lines <= MAX_LINES, f"{path.relative_to(ROOT)}: {lines} lines; split it at a seam"


OUTSIDE = re.compile(r"\b(?:MODEL|DESIGN|STYLE)\.md\b|shared/paper|shared/(?:MODEL|DESIGN|STYLE)")
"""A document outside the repository (the brief's files, the paper's text beside it)."""


def test_docstrings_cite_the_repository():
    """No module, test or doc cites a document outside the repository
    (docs/contributing.md); the checker itself sees one."""
    assert OUTSIDE.search("see MODEL.md, eq. (3)") and not OUTSIDE.search("docs/model.md")
    paths = [*(ROOT / p for p in PACKAGES), ROOT / "tests", ROOT / "docs"]
    files = [f for base in paths for f in base.rglob("*") if f.suffix in (".py", ".md", ".ipynb")]
    cited = [
        f"{f.relative_to(ROOT)}: {match.group(0)}"
        for f in files
        if f.name != "test_layout.py"
        for match in [OUTSIDE.search(f.read_text())]
        if match
    ]
    assert not cited, f"documents outside the repository cited: {cited}"


TRACKER = re.compile(r"\bissue [0-9]", re.IGNORECASE)
"""A tracker issue's number: not in the repository, so not cited by the code."""


def test_the_code_cites_no_tracker_issue():
    """The packages say what the code does and cite docs/, never a tracker issue's
    number; the checker itself sees one."""
    assert TRACKER.search("(issue 40)") and not TRACKER.search("tissue 40x40")
    files = [f for p in PACKAGES for f in (ROOT / p).rglob("*.py")]
    cited = [f"{f.relative_to(ROOT)}" for f in files if TRACKER.search(f.read_text())]
    assert not cited, f"tracker issues cited: {cited}"


def _folder(name: str) -> str:
    """The folder a module belongs to, two levels deep (``experiments.design``); a
    loose module of a layer stands for itself."""
    return ".".join(name.split(".")[:2])


def test_folders_only_import_downwards():
    """Folders, as modules do, form no cycle: a folder that imports another is above it
    (docs/contributing.md). ``phantom`` reading design files from ``design`` while
    ``design`` simulates on the ``phantom`` was the last such pair."""
    graph: dict[str, set[str]] = {}
    for name, targets in _graph().items():
        graph.setdefault(_folder(name), set()).update(
            _folder(t) for t in targets if _folder(t) != _folder(name)
        )
    for target in {t for targets in graph.values() for t in targets}:
        graph.setdefault(target, set())
    cycles = _cycles(graph)
    assert not cycles, f"folders that import each other: {cycles}"


GENERIC = frozenset({"shared", "files", "linear", "numeric", "utils", "helpers", "misc", "common"})
"""Module names that say nothing of what the module holds."""

NAMED_AFTER_THE_FOLDER = {"experiments/data/dataset.py"}
"""``Dataset``, the class users import to write their data (docs/formats.md), keeps its
name."""


def _folder_words(folder: str) -> tuple[str, ...]:
    """The words a module name would repeat its folder with: ``design``, ``phantoms`` and
    ``phantom``, ``imaging`` and ``image``."""
    words = [folder]
    if folder.endswith("s"):
        words.append(folder[:-1])
    if folder.endswith("ing"):
        words.append(folder[:-3] + "e")
    return tuple(words)


def test_module_names_say_what_they_hold_within_their_folder():
    """Names are scoped by folder (``design/command.py``, ``imaging/command.py``): none
    repeats its folder's name (``design/designcommand.py``), and none is a word that
    says nothing (``shared``, ``files``, ``linear``, ``numeric``); the checker sees both."""
    assert "designcommand".startswith(_folder_words("design"))
    assert "imagebench".startswith(_folder_words("imaging"))
    assert not "dynamics".startswith(_folder_words("design"))
    repeating, generic = [], []
    for path in _modules().values():
        if path.name in ("__init__.py", "__main__.py"):
            continue
        where = str(path.relative_to(ROOT))
        if path.stem.startswith(_folder_words(path.parent.name)):
            if where not in NAMED_AFTER_THE_FOLDER:
                repeating.append(where)
        if path.stem in GENERIC:
            generic.append(where)
    assert not repeating, f"modules named after their folder: {repeating}"
    assert not generic, f"module names that say nothing: {generic}"


def test_every_project_import_resolves():
    """Each ``from symbolic|solvers|experiments.X import name``, inside functions too, names
    something X has: a local import of a moved name fails only when its branch runs."""
    import importlib

    missing = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom) or node.level or not node.module:
                continue
            if node.module.split(".")[0] not in PACKAGES:
                continue
            module = importlib.import_module(node.module)
            for alias in node.names:
                if hasattr(module, alias.name):
                    continue
                try:
                    importlib.import_module(f"{node.module}.{alias.name}")
                except ImportError:
                    missing.append(f"{name}: {node.module} has no {alias.name}")
    assert not missing, missing


def test_every_package_says_what_it_offers_and_exports_it():
    """Each package's ``__init__`` has a docstring, and every name of its ``__all__`` is
    there (eagerly, or on first use through ``experiments.lazy_exports``)."""
    import importlib

    bare, missing = [], []
    for name, path in _modules().items():
        if path.name != "__init__.py":
            continue
        package = importlib.import_module(name)
        if not (package.__doc__ or "").strip():
            bare.append(name)
        missing += [
            f"{name}.{n}" for n in getattr(package, "__all__", ()) if not hasattr(package, n)
        ]
    assert not bare and not missing, (bare, missing)


def test_the_command_lines_help_imports_no_solver():
    """``dvs --help`` and the packages' lazy exports import neither CasADi nor the solvers."""
    import subprocess
    import sys

    code = (
        "import contextlib, io, sys, experiments.data, experiments.design, experiments.problem\n"
        "from experiments.command.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        "print(sorted(m for m in sys.modules if m == 'casadi' or m.startswith('solvers')))"
    )
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert shown.returncode == 0 and shown.stdout.strip() == "[]", shown.stdout + shown.stderr
