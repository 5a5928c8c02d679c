"""The memory profile sees resident memory where it is allocated, under the function
that holds it (experiments/inverse/memoryprofile.py)."""

from __future__ import annotations

import time

import numpy as np

from experiments.command.isolation import isolated
from experiments.inverse.memoryprofile import print_profile, profile, resident_mb


def _hold(megabytes: int) -> float:
    """Touch ``megabytes`` of memory and hold it for a few samples."""
    block = np.ones(megabytes * 2**20 // 8)
    time.sleep(0.3)
    return float(block[-1])


def _profiled_hold(megabytes: int):
    """In a fresh process (whose freed memory cannot serve the block): the resident set
    before, the value, the profile."""
    before = resident_mb()
    value, record = profile(_hold, megabytes, interval=0.02)
    return before, value, record


def test_the_peak_and_its_holder_are_seen():
    before, value, record = isolated(_profiled_hold, 200)
    assert value == 1.0
    assert record.peak_mb >= before + 150  # the 200 MB block, resident while held
    assert record.peak_stack() == ("experiments.inverse.memoryprofile.profile",)
    (holder,) = record.holders()  # only the project's frames are kept
    assert holder["function"] == "experiments.inverse.memoryprofile.profile"
    assert holder["rise_mb"] >= 150
    lines = []
    print_profile(record, "hold", log=lines.append)
    assert "peak resident" in lines[0] and lines[2].startswith("| function")
