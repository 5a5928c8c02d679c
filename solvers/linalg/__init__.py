"""Sparse linear algebra: ``cholmod`` (sparse Cholesky through cvxopt's CHOLMOD,
``factorised`` choosing it or SuperLU) and ``blas`` (BLAS threads around thin solves)."""

from solvers.linalg.blas import one_thread
from solvers.linalg.cholmod import Cholesky, NotPositiveDefinite, backend, factorised

__all__ = ["Cholesky", "NotPositiveDefinite", "backend", "factorised", "one_thread"]
