"""How the ``dvs`` process uses the machine: it keeps the memory it frees for its next
arrays, and numpy's BLAS runs on one thread.

**Memory.** glibc's malloc serves a block above its mmap threshold (128 kB at first,
raised towards 32 MiB as such blocks are freed) from fresh pages of the kernel and
hands them back at ``free``; a heap whose free top exceeds the trim threshold is given
back too. A fit allocates arrays of the same few sizes at every evaluation (the
sensitivities' right-hand sides, n_state x n_cases x n_p), so each evaluation would
page-fault them in again. ``keep_freed_memory`` raises the mmap threshold to glibc's
largest (32 MiB) and the trim threshold to 256 MiB, so freed blocks stay in the heap
for reuse. Larger blocks, the Cholesky factor foremost, are reused by
``solvers.linalg.cholmod`` itself. The page faults and times it saves are in
docs/results/next-press-speed.md.

**Threads.** numpy's own OpenBLAS on two threads waits busily on the second core
between the dense products of the fit, where the factorisations want it; on one thread
(``numpy_blas_on_one_thread``) a default ``dvs next`` runs faster (same page).

``configure`` does both. The console entry point calls it, and so do the benchmark
rows that time a command; a library user (a notebook) keeps its allocator and its
threads as they were.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""glibc's ``mallopt`` parameters (malloc.h)."""

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""glibc's largest mmap threshold on 64-bit (``DEFAULT_MMAP_THRESHOLD_MAX``)."""

TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024
"""Free memory at the top of the heap kept before any is given back [bytes]."""


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds (see the module docstring) for this process.

    Returns True when they were set, False where the C library is not glibc (the call
    then changes nothing).
    """
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
        and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )


def numpy_blas_on_one_thread() -> None:
    """The BLAS libraries loaded so far (numpy's) on one thread (threadpoolctl).

    CHOLMOD's OpenBLAS, opened later, starts on one thread and takes the cores inside
    its factorisations and solves only.
    """
    import numpy  # noqa: F401  (its BLAS loaded before the limit)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def configure() -> None:
    """Both settings of the module docstring, for the rest of this process."""
    keep_freed_memory()
    numpy_blas_on_one_thread()
