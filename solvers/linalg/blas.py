"""BLAS threads around sparse triangular solves.

SuperLU's multi-column solve calls BLAS on thin blocks. With OpenBLAS on two threads
and a busy machine those calls wait on each other: at 27 x 27 x 4 (K with 2.5 M
nonzeros, 8.5 M in its factors) a 10-column solve took 0.88-0.91 s on two threads
and 0.10 s on one, side by side in one process; the factorisation itself is not
affected (docs/results/diagnosis-linear-path.md). ``one_thread`` limits BLAS to one thread
for the duration of a block when threadpoolctl is installed, and does nothing
otherwise.
"""

from __future__ import annotations

from contextlib import nullcontext

try:
    from threadpoolctl import ThreadpoolController
except ImportError:  # optional: without it the solves keep BLAS's own threads
    ThreadpoolController = None

_CONTROLLER = None


def one_thread():
    """A context manager: BLAS on one thread inside it (no-op without threadpoolctl)."""
    global _CONTROLLER
    if ThreadpoolController is None:
        return nullcontext()
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")
