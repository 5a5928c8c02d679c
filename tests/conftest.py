"""Shared pytest fixtures."""

from __future__ import annotations

import os

import pytest

from experiments.data.paths import shared_data_dir

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def shared_data():
    """Path of ../shared/data; skips the test with a clear message when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data not found at {path} (set DVS_SHARED_DATA to its location)")
    return path


def exit_code_and_stderr(main, argv, capsys) -> tuple[int, str]:
    """Run a command line's ``main(argv)``; its exit code (argparse exits included) and
    what it wrote to stderr."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr().err
