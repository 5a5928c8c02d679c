"""Where a command's memory goes: its resident set sampled beside the project's call stack.

A sampler thread reads the process's resident set size (``/proc/self/statm``) every
``interval`` seconds together with the main thread's stack, kept to the project's own
frames (``symbolic``, ``solvers``, ``experiments``). What C libraries allocate (CHOLMOD's
and SuperLU's factors, CasADi's work vectors) is in the resident set and invisible to
``tracemalloc``; sampling sees both. ``holders`` gives, for each project function, the
largest resident set seen while it was on the stack, and the rise over the resident set
when it was first seen: the functions under which the peak builds up
(docs/results/memory.md).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass, field

PROJECT = ("symbolic", "solvers", "experiments")
"""Top-level packages whose frames the profile keeps."""

PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20


def resident_mb() -> float:
    """This process's resident set size now [MB] (Linux)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * PAGE_MB


def _project_stack(frame) -> tuple[str, ...]:
    """'module.function' of the project's frames on a stack, outermost first."""
    names = []
    while frame is not None:
        module = frame.f_globals.get("__name__", "")
        if module.split(".")[0] in PROJECT:
            names.append(f"{module}.{frame.f_code.co_name}")
        frame = frame.f_back
    return tuple(reversed(names))


@dataclass
class MemoryProfile:
    """Samples of one run: seconds since the start, resident set [MB], project stack."""

    seconds: list = field(default_factory=list)
    resident: list = field(default_factory=list)
    stacks: list = field(default_factory=list)

    @property
    def peak_mb(self) -> float:
        return max(self.resident, default=0.0)

    def peak_stack(self) -> tuple[str, ...]:
        """The project stack at the largest sampled resident set."""
        if not self.resident:
            return ()
        return self.stacks[max(range(len(self.resident)), key=self.resident.__getitem__)]

    def holders(self, top: int = 12) -> list[dict]:
        """Project functions by the largest resident set seen under them [MB], with the
        rise from their first sample to it: the ``top`` largest rises."""
        first: dict[str, float] = {}
        peak: dict[str, float] = {}
        for resident, stack in zip(self.resident, self.stacks):
            for name in set(stack):
                first.setdefault(name, resident)
                peak[name] = max(peak.get(name, 0.0), resident)
        rows = [
            {"function": name, "peak_mb": peak[name], "rise_mb": peak[name] - first[name]}
            for name in peak
        ]
        rows.sort(key=lambda row: (-row["rise_mb"], row["function"]))
        return rows[:top]


def profile(function, *args, interval: float = 0.05, **kwargs):
    """Run ``function(*args, **kwargs)`` on this thread while a sampler records the
    resident set and this thread's project stack every ``interval`` [s]: (its value,
    ``MemoryProfile``)."""
    record = MemoryProfile()
    main = threading.get_ident()
    done = threading.Event()
    begin = time.perf_counter()

    def sample() -> None:
        while not done.is_set():
            frame = sys._current_frames().get(main)
            record.seconds.append(time.perf_counter() - begin)
            record.resident.append(resident_mb())
            record.stacks.append(_project_stack(frame))
            done.wait(interval)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        value = function(*args, **kwargs)
    finally:
        done.set()
        sampler.join()
    return value, record


def print_profile(record: MemoryProfile, title: str, top: int = 12, log=print) -> None:
    """The peak, the stack at the peak and the largest holders, as a Markdown table."""
    log(f"{title}: peak resident {record.peak_mb / 1024:.2f} GB")
    log(
        "at the peak: "
        + " > ".join(
            name.rsplit(".", 2)[-2] + "." + name.rsplit(".", 1)[-1]
            for name in record.peak_stack()[-6:]
        )
    )
    log("| function | largest resident set under it [GB] | rise under it [GB] |")
    log("|---|---|---|")
    for row in record.holders(top):
        log(f"| `{row['function']}` | {row['peak_mb'] / 1024:.2f} | {row['rise_mb'] / 1024:.2f} |")
