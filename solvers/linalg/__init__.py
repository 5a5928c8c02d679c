"""Sparse linear algebra: ``cholmod`` (sparse Cholesky through the system's CHOLMOD,
``factorised`` choosing it or SuperLU) and ``blas`` (BLAS threads around thin solves)."""
