"""Sparse Cholesky through the system's CHOLMOD (SuiteSparse), when it is there.

K(p) of the continuum is symmetric positive definite, and SuperLU factorises it as a
general matrix: on default ``dvs diagnose`` over FE tissue (row A of docs/continuum.md,
40 x 33 x 6 quadratic, 47,196 unknowns, 13.5 M nonzeros) one factorisation took 17.7 s
and the factorisations were 48 % of the CPU time. CHOLMOD's supernodal Cholesky does
its work in dense BLAS blocks, so it is only as fast as the BLAS it calls: on that
matrix, one thread each, 18.4 s with Debian's reference BLAS and 3.3 s with an
optimised OpenBLAS (docs/inverse.md, "The factorisation itself").

- **Binding.** The Python bindings (scikit-sparse) do not build against the SuiteSparse
  5.x that Debian 12 ships, so this module calls ``libcholmod.so.3`` through ctypes.
  The four structures it reads are CHOLMOD 3's public ones (``cholmod_core.h``); the
  defaults ``cholmod_start`` writes are checked field by field before anything is
  factorised, so a library with another layout is refused, not misread.
- **BLAS.** Before libcholmod is opened, an OpenBLAS that a required package (pyproject.toml)
  already ships (opencv-python-headless, then CasADi) is opened with global symbols,
  so CHOLMOD's dgemm/dsyrk/dtrsm/dpotrf resolve to it (``OPTIMISED_BLAS``). numpy and
  scipy call their own prefixed copies and are not affected.
- **Threads.** That OpenBLAS runs on one thread, except inside ``Cholesky``'s
  factorisation and solves, which take every core the process may use (``threads``):
  their supernodal blocks are dense and large. On the 47,196-unknown K of row A's
  refined volume, on this project's 2-core machine: a factorisation 2.9 -> 1.75 s
  wall (CPU 2.9 -> 3.3 s), a 10-column solve 0.143 -> 0.108 s.
- **Use.** ``Cholesky(matrix)`` factorises (ordering and supernodal or simplicial as
  CHOLMOD chooses); ``solve`` takes one right-hand side or a matrix of them. A matrix
  that is not positive definite raises ``NotPositiveDefinite``. ``factorised`` is the
  entry point: CHOLMOD for a symmetric positive definite matrix, SuperLU (or any
  fallback) otherwise. ``DVS_FACTORISATION=superlu`` in the environment switches
  CHOLMOD off; ``backend()`` names what is in use.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import importlib.util
import itertools
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp


class NotPositiveDefinite(ValueError):
    """The matrix has a non-positive pivot: it is not SPD (or not numerically)."""


class _Sparse(ctypes.Structure):
    _fields_ = [
        ("nrow", ctypes.c_size_t),
        ("ncol", ctypes.c_size_t),
        ("nzmax", ctypes.c_size_t),
        ("p", ctypes.c_void_p),
        ("i", ctypes.c_void_p),
        ("nz", ctypes.c_void_p),
        ("x", ctypes.c_void_p),
        ("z", ctypes.c_void_p),
        ("stype", ctypes.c_int),
        ("itype", ctypes.c_int),
        ("xtype", ctypes.c_int),
        ("dtype", ctypes.c_int),
        ("sorted", ctypes.c_int),
        ("packed", ctypes.c_int),
    ]


class _Dense(ctypes.Structure):
    _fields_ = [
        ("nrow", ctypes.c_size_t),
        ("ncol", ctypes.c_size_t),
        ("nzmax", ctypes.c_size_t),
        ("d", ctypes.c_size_t),
        ("x", ctypes.c_void_p),
        ("z", ctypes.c_void_p),
        ("xtype", ctypes.c_int),
        ("dtype", ctypes.c_int),
    ]


class _FactorHead(ctypes.Structure):
    """The first two fields of cholmod_factor: n and the first failed column."""

    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t)]


COMMON_BYTES = 1 << 15
"""Room for cholmod_common (about 2.5 kB in CHOLMOD 3; cholmod_start fills it)."""

_DEFAULTS = (  # (offset, ctype, value cholmod_start writes) in CHOLMOD 3's cholmod_common
    (0, ctypes.c_double, 0.0),  # dbound
    (8, ctypes.c_double, 1.2),  # grow0
    (16, ctypes.c_double, 1.2),  # grow1
    (24, ctypes.c_size_t, 5),  # grow2
    (32, ctypes.c_size_t, 8),  # maxrank
    (40, ctypes.c_double, 40.0),  # supernodal_switch
    (48, ctypes.c_int, 1),  # supernodal = CHOLMOD_AUTO
    (144, ctypes.c_int, 3),  # print
)
PRINT_OFFSET = 144
"""Offset of ``print`` in cholmod_common: set to 0, so a failed factorisation is silent."""

REAL, DOUBLE, INT = 1, 0, 0
"""CHOLMOD_REAL, CHOLMOD_DOUBLE, CHOLMOD_INT."""

OPTIMISED_BLAS = (
    ("cv2", "../opencv_python_headless.libs/libopenblas*.so*"),
    ("casadi", "libcasadi-tp-openblas.so*"),
)
"""(package, glob beside its __init__.py) of the OpenBLAS builds tried, in order. They
export the standard LP64 names (dgemm_, dpotrf_, ...)."""

_library = None
_blas = "reference (the system's libblas)"
_blas_library = None  # the OpenBLAS opened for CHOLMOD, whose threads ``_threaded`` sets


def threads() -> int:
    """The BLAS threads of a factorisation: ``OMP_NUM_THREADS`` when set, else the
    cores this process may run on."""
    try:
        return max(1, int(os.environ["OMP_NUM_THREADS"]))
    except (KeyError, ValueError):
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1


class _threaded:
    """Inside: CHOLMOD's OpenBLAS on ``count`` threads; after: as it was before."""

    def __init__(self, count: int):
        self.count = count

    def __enter__(self):
        self.before = None
        if _blas_library is not None:
            self.before = _blas_library.openblas_get_num_threads()
            _blas_library.openblas_set_num_threads(self.count)

    def __exit__(self, *_):
        if self.before is not None:
            _blas_library.openblas_set_num_threads(self.before)


def _open_blas() -> None:
    """Open the first optimised OpenBLAS of ``OPTIMISED_BLAS`` with global symbols."""
    global _blas, _blas_library
    for package, pattern in OPTIMISED_BLAS:
        spec = importlib.util.find_spec(package)
        if spec is None or spec.origin is None:
            continue
        for path in sorted(glob.glob(str(Path(spec.origin).parent / pattern))):
            try:
                lib = ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
                lib.openblas_set_num_threads(1)
                lib.openblas_get_num_threads.restype = ctypes.c_int
            except (OSError, AttributeError):
                continue
            _blas, _blas_library = f"OpenBLAS of {package}", lib
            return


def backend() -> str:
    """What ``factorised`` uses for a symmetric positive definite matrix."""
    return f"CHOLMOD with {_blas}" if available() else "SuperLU"


def _load():
    """The library with its signatures and a started common, or None."""
    global _library
    if _library is not None:
        return _library or None
    _library = False
    name = ctypes.util.find_library("cholmod")
    if name is None or os.environ.get("DVS_FACTORISATION", "auto") == "superlu":
        return None
    _open_blas()
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        return None
    common = ctypes.create_string_buffer(COMMON_BYTES)
    handle = ctypes.cast(common, ctypes.c_void_p)
    lib.cholmod_start.argtypes = [ctypes.c_void_p]
    if lib.cholmod_start(handle) != 1 or not _layout_matches(common):
        return None
    ctypes.c_int.from_buffer(common, PRINT_OFFSET).value = 0
    lib.cholmod_analyze.restype = ctypes.c_void_p
    lib.cholmod_analyze.argtypes = [ctypes.POINTER(_Sparse), ctypes.c_void_p]
    lib.cholmod_factorize.argtypes = [ctypes.POINTER(_Sparse), ctypes.c_void_p, ctypes.c_void_p]
    lib.cholmod_solve.restype = ctypes.POINTER(_Dense)
    lib.cholmod_solve.argtypes = [
        ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(_Dense), ctypes.c_void_p
    ]  # fmt: skip
    lib.cholmod_free_dense.argtypes = [ctypes.POINTER(ctypes.POINTER(_Dense)), ctypes.c_void_p]
    lib.cholmod_free_factor.argtypes = [ctypes.POINTER(ctypes.c_void_p), ctypes.c_void_p]
    lib.cholmod_copy_factor.restype = ctypes.c_void_p
    lib.cholmod_copy_factor.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    _library = (lib, common, handle)
    return _library


def _layout_matches(common) -> bool:
    return all(
        abs(kind.from_buffer(common, offset).value - value) < 1e-12
        for offset, kind, value in _DEFAULTS
    )


def available() -> bool:
    """True when libcholmod loaded and its cholmod_common has CHOLMOD 3's layout."""
    return _load() is not None


def _sparse(n: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray) -> _Sparse:
    """A cholmod_sparse view of a CSC matrix's lower triangle (stype -1: the upper part
    is ignored, so the full symmetric matrix can be passed)."""
    return _Sparse(
        n, n, data.size, indptr.ctypes.data, indices.ctypes.data, None,
        data.ctypes.data, None, -1, INT, REAL, DOUBLE, 1, 1,
    )  # fmt: skip


def symmetric(matrix: sp.spmatrix, tolerance: float = 1e-10) -> bool:
    """True when u^T A v = v^T A u for two random vectors, to ``tolerance`` relative.

    Two products instead of forming A - A^T (0.06 s against 0.6 s at 13.5 M nonzeros).
    An asymmetry far below the tolerance passes; the Cholesky factor then solves the
    symmetric part, and ``solvers.diagnosis.linear.solve_states`` refines against A.
    """
    rng = np.random.default_rng(0)
    u, v = rng.standard_normal((2, matrix.shape[0]))
    au, av = matrix @ u, matrix @ v
    scale = max(float(np.linalg.norm(au) * np.linalg.norm(v)), 1e-300)
    return bool(abs(float(u @ av) - float(v @ au)) <= tolerance * scale)


def symmetric_lu(matrix: sp.spmatrix):
    """SuperLU for a symmetric positive definite matrix: a symmetric ordering, no pivoting."""
    import scipy.sparse.linalg as spla

    return spla.splu(
        sp.csc_matrix(matrix),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


def factorised(matrix: sp.spmatrix, fallback, known_symmetric: bool = False):
    """``Cholesky(matrix)`` when CHOLMOD is there and the matrix is symmetric positive
    definite, else ``fallback(matrix)`` (an object with ``solve``, SuperLU's say).
    ``known_symmetric`` skips the check when the caller made it."""
    if available() and (known_symmetric or symmetric(matrix)):
        try:
            return Cholesky(matrix)
        except NotPositiveDefinite:
            pass
    return fallback(matrix)


ANALYSES_KEPT = 4
"""Symbolic analyses kept for reuse (most recent first), one per sparsity pattern: a
diagnosis with base_compliance alternates between four (K, K with the extra state, and
the two blocks of the block-triangular case), and with two kept it analysed three of
them again."""

SPARES_KEPT = 2
"""Numeric factors kept after their ``Cholesky`` is closed, for the next matrix of their
pattern (``_spare``)."""

_analyses: list = []  # [(indptr, indices, symbolic factor pointer, serial)]
_spares: list = []  # [(serial of the pattern's analysis, numeric factor pointer)]
_serials = itertools.count()  # never reused, where a freed analysis's address may be


def _analysis(pattern, structure: _Sparse) -> tuple[ctypes.c_void_p, int]:
    """The symbolic factor (ordering, elimination tree, supernodes) of ``pattern`` and
    the serial number of its analysis.

    The fill-reducing ordering and the supernodes depend on the sparsity pattern alone,
    and a fit refactorises K(p) of one pattern many times: on the 40 x 33 x 6 K of the
    module docstring the analysis takes 0.9 s of the factorisation's 3.6 s. The last
    ``ANALYSES_KEPT`` patterns keep theirs; ``Cholesky`` factorises a copy (or a spare).
    """
    lib, _, common = _load()
    indptr, indices = pattern
    for k, (kept_ptr, kept_indices, factor, serial) in enumerate(_analyses):
        if np.array_equal(kept_ptr, indptr) and np.array_equal(kept_indices, indices):
            _analyses.insert(0, _analyses.pop(k))
            return factor, serial
    factor = ctypes.c_void_p(lib.cholmod_analyze(structure, common))
    if not factor.value:
        raise RuntimeError("cholmod_analyze failed (out of memory?)")
    serial = next(_serials)
    _analyses.insert(0, (indptr.copy(), indices.copy(), factor, serial))
    while len(_analyses) > ANALYSES_KEPT:
        *_, evicted, gone = _analyses.pop()
        for entry in [entry for entry in _spares if entry[0] == gone]:
            _spares.remove(entry)
            lib.cholmod_free_factor(ctypes.byref(entry[1]), common)
        lib.cholmod_free_factor(ctypes.byref(evicted), common)
    return factor, serial


def _spare(symbolic: ctypes.c_void_p, serial: int) -> ctypes.c_void_p:
    """A numeric factor of the pattern of analysis ``serial`` to factorise into, else a
    new copy of its symbolic factor.

    CHOLMOD refactorises a numeric factor in its own memory. A new one is a fresh
    allocation of all of L, which the kernel maps page by page on first touch: on the
    15,360-unknown K (4.1 M nonzeros) of a default ``dvs next`` over FE tissue, 3.1 M
    page faults in one run, and 1.6 M with the spares (docs/inverse.md, "A factor's
    memory kept for the next one").
    """
    for k, (key, factor) in enumerate(_spares):
        if key == serial:
            del _spares[k]
            return factor
    lib, _, common = _load()
    return ctypes.c_void_p(lib.cholmod_copy_factor(symbolic, common))


def _retire(serial: int, factor: ctypes.c_void_p, n: int) -> bool:
    """Keep a closed, successful factor as a spare of its pattern while that pattern's
    analysis (``serial``) is kept; False when the caller should free it."""
    kept = any(entry[3] == serial for entry in _analyses)
    if not kept or _FactorHead.from_address(factor.value).minor < n:
        return False
    _spares.insert(0, (serial, factor))
    lib, _, common = _load()
    while len(_spares) > SPARES_KEPT:
        lib.cholmod_free_factor(ctypes.byref(_spares.pop()[1]), common)
    return True


class Cholesky:
    """L L^T of a sparse symmetric positive definite matrix (CHOLMOD).

    Parameters
    ----------
    matrix : scipy.sparse matrix
        Square and symmetric; only its lower triangle is read.
    blas_threads : int, optional
        BLAS threads of the factorisation and the solves (default ``threads()``).

    Raises
    ------
    RuntimeError
        When CHOLMOD is not available (see ``available``).
    NotPositiveDefinite
        When a pivot is not positive.
    """

    def __init__(self, matrix, blas_threads: int | None = None):
        self.blas_threads = threads() if blas_threads is None else int(blas_threads)
        library = _load()
        if library is None:
            raise RuntimeError("CHOLMOD (libcholmod.so.3 of SuiteSparse 5) is not available")
        self._lib, _, self._common = library
        compressed = sp.issparse(matrix) and matrix.format == "csc" and matrix.dtype == float
        csc = matrix if compressed else sp.csc_matrix(matrix, dtype=float)
        csc.sort_indices()  # a no-op where the order is known
        self.n = csc.shape[0]
        self._arrays = (  # referenced by the structure: kept alive with the object
            np.ascontiguousarray(csc.indptr, dtype=np.int32),
            np.ascontiguousarray(csc.indices, dtype=np.int32),
            np.ascontiguousarray(csc.data, dtype=float),
        )
        structure = _sparse(self.n, *self._arrays)
        symbolic, self._serial = _analysis(self._arrays[:2], structure)
        self._factor = _spare(symbolic, self._serial)
        if not self._factor.value:
            raise RuntimeError("cholmod_copy_factor failed (out of memory?)")
        with _threaded(self.blas_threads):
            self._lib.cholmod_factorize(structure, self._factor, self._common)
        minor = _FactorHead.from_address(self._factor.value).minor
        if minor < self.n:
            self.close()  # freed, never kept as a spare
            raise NotPositiveDefinite(f"pivot {minor} of {self.n} is not positive")

    def solve(self, right: np.ndarray) -> np.ndarray:
        """A^-1 right, for a vector or the columns of a matrix."""
        right = np.asarray(right, dtype=float)
        block = np.asfortranarray(right.reshape(self.n, -1))
        dense = _Dense(self.n, block.shape[1], block.size, self.n, block.ctypes.data, None, REAL)
        with _threaded(self.blas_threads):
            result = self._lib.cholmod_solve(0, self._factor, dense, self._common)  # CHOLMOD_A
        if not result:
            raise RuntimeError("cholmod_solve failed (out of memory?)")
        out = result.contents
        values = np.ctypeslib.as_array(
            ctypes.cast(out.x, ctypes.POINTER(ctypes.c_double)), shape=(out.ncol, out.nrow)
        ).T.copy()
        self._lib.cholmod_free_dense(ctypes.byref(result), self._common)
        return values.reshape(right.shape)

    def close(self) -> None:
        """Release the factor (also done when the object is collected): kept as a spare
        of its pattern (``_retire``) or freed."""
        factor = getattr(self, "_factor", None)
        if factor is not None and factor.value:
            try:
                kept = _retire(self._serial, factor, self.n)
            except (TypeError, AttributeError):  # module globals gone at interpreter exit
                kept = False
            if not kept:
                self._lib.cholmod_free_factor(ctypes.byref(factor), self._common)
        self._factor = None

    def __del__(self):
        self.close()
