"""The docs cover every CLI command and option, and every key of every output format.

Keys are collected from files the commands really write, so a key added to the
code without a line in docs/formats.md fails here.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from experiments.cli import build_parser, main

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _keys(document, prefix: str = "") -> set[str]:
    """Every dict key in a JSON document (lists are searched, their indices are not keys)."""
    found = set()
    if isinstance(document, dict):
        for key, value in document.items():
            found.add(key)
            found |= _keys(value)
    elif isinstance(document, list):
        for value in document:
            found |= _keys(value)
    return found


def _undocumented(keys, text: str, skip=()) -> list[str]:
    return sorted(k for k in keys if f"`{k}`" not in text and k not in skip)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A simulated dataset, the fit of it, and its diagnosis, written by the CLI."""
    root = tmp_path_factory.mktemp("docs")
    dataset = root / "data.npz"
    assert main(["simulate", "--seed", "1", "--out", str(dataset)]) == 0
    assert main(["fit", str(dataset), "--method", "nested", "--out", str(root / "fit")]) == 0
    assert main(["diagnose", str(dataset), "--out", str(root / "diagnosis")]) == 0
    return root


def test_every_command_and_option_is_in_the_cli_reference():
    text = (DOCS / "cli.md").read_text()
    parser = build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    missing = []
    for name, sub in commands.choices.items():
        if f"dvs {name}" not in text:
            missing.append(f"dvs {name}")
        for action in sub._actions:
            for option in action.option_strings:
                if option.startswith("--") and option != "--help" and option not in text:
                    missing.append(f"dvs {name} {option}")
    assert not missing, f"not in docs/cli.md: {missing}"


def test_every_dataset_key_is_in_the_format_reference(written):
    text = (DOCS / "formats.md").read_text()
    with np.load(written / "data.npz") as data:
        keys = set(data.files)
    assert not _undocumented(keys, text)


def test_every_result_key_is_in_the_format_reference(written):
    text = (DOCS / "formats.md").read_text()
    document = json.loads((written / "fit" / "result.json").read_text())
    parameter_names = set(document["parameters"])
    labels = set(document["per_load_rms_mm"])
    fixed = set(document["model"]["fixed_parameters"])
    skip = parameter_names | labels | fixed  # data, not keys of the format
    assert not _undocumented(_keys(document), text, skip)


def test_every_diagnosis_key_is_in_the_format_reference(written):
    text = (DOCS / "formats.md").read_text()
    document = json.loads((written / "diagnosis" / "diagnosis.json").read_text())
    names = set()
    for step in document["steps"]:
        names |= set(step.get("parameters") or {})
    assert not _undocumented(_keys(document), text, names)


def test_the_api_overview_example_runs():
    text = (DOCS / "api.md").read_text()
    example = text.split("```python\n", 1)[1].split("```", 1)[0]
    namespace: dict = {}
    exec(compile(example, "docs/api.md", "exec"), namespace)
    assert namespace["result"].success
    assert np.allclose(namespace["result"].x, namespace["check"].x, rtol=1e-6)
