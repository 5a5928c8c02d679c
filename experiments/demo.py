"""The main job, ``dvs demo`` / ``make demo``.

Until the inverse and the experiment pipeline land, it runs what exists:
the forward solution of the default forehead phantom under 0.25 N.
"""

from __future__ import annotations

from pathlib import Path

from experiments import forward


def run(out: Path) -> int:
    """Run the demo into ``out``; returns the exit code."""
    print("[1/1] forward solution of the forehead phantom under 0.25 N")
    forward.run(Path(out), force=0.25)
    return 0
