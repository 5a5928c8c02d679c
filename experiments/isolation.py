"""Measurements in a fresh process: their own memory peak, no cache of an earlier one."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor


def isolated(function, *args):
    """Run ``function(*args)`` in a fresh process (own memory peak, cold caches)."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(function, *args).result()
