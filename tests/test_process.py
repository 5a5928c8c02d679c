"""The ``dvs`` process (experiments/command/process.py): blocks freed by one evaluation
serve the next without new pages from the kernel, and numpy's BLAS runs on one thread."""

import subprocess
import sys

import pytest

from experiments.command import process

ROUNDS = """
import resource, sys
import numpy as np
from experiments.command.process import keep_freed_memory
kept = sys.argv[1] == "kept" and keep_freed_memory()
blocks = [np.ones(3_000_000) for _ in range(4)]  # 24 MB each: glibc raises its thresholds
del blocks
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):  # an evaluation's arrays: 96 MB, then freed
    blocks = [np.ones(3_000_000) for _ in range(4)]
    del blocks
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple[str, int]:
    out = subprocess.run(
        [sys.executable, "-c", ROUNDS, mode], capture_output=True, text=True, check=True
    )
    kept, faults = out.stdout.split()
    return kept, int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_blocks_are_reused_without_new_pages():
    """Ten rounds of four 24 MB arrays (234,000 pages in all): with glibc's own
    thresholds some of each round's memory goes back to the kernel and is faulted in
    again (19,000 faults measured); kept, the rounds reuse it (none)."""
    kept, faults = _faults("kept")
    if kept != "True":
        pytest.skip("the C library is not glibc")
    _, default = _faults("default")
    assert default >= 2_000, default  # the mechanism: new pages at every round
    assert faults <= 0.1 * default, (faults, default)


THREADS = """
import json
import numpy as np
from threadpoolctl import threadpool_info
from experiments.command.process import configure
configure()
np.ones((300, 300)) @ np.ones((300, 300))
print(json.dumps({i["prefix"]: i["num_threads"] for i in threadpool_info()
                  if i["user_api"] == "blas"}))
"""


def test_numpys_blas_runs_on_one_thread():
    """After ``configure`` every BLAS loaded so far runs on one thread."""
    import json

    out = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    threads = json.loads(out.stdout)
    assert threads and set(threads.values()) == {1}, threads


def test_the_console_script_sets_it_up_and_main_leaves_it():
    """``console`` (the ``dvs`` script) configures the process; ``main``, which tests
    and notebooks call, leaves the host's allocator and threads alone."""
    import inspect

    from experiments.command import cli

    assert "configure()" in inspect.getsource(cli.console)
    assert "configure" not in inspect.getsource(cli.main)
    assert process.TRIM_THRESHOLD_BYTES >= 4 * process.MMAP_THRESHOLD_BYTES
