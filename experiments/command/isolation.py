"""Measurements in a fresh process: their own memory peak, no cache of an earlier one,
and the "x floor" unit (one factorisation of the model's K, timed in that process)."""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def isolated(function, *args):
    """Run ``function(*args)`` in a fresh process (own memory peak, cold caches)."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(function, *args).result()


def factorisation_seconds(stiffness) -> float:
    """The median of three factorisations (and one solve) of ``stiffness`` [s], as the
    loop factorises (``solvers.forward.linearpath.StateJacobian``)."""
    from solvers.forward.linearpath import StateJacobian

    times = []
    for _ in range(3):
        begin = time.perf_counter()
        StateJacobian(stiffness).solve(np.ones(stiffness.shape[0]))
        times.append(time.perf_counter() - begin)
    return float(np.median(times))


def peak_mb() -> float:
    """This process's peak resident memory so far [MB]."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
