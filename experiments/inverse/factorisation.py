"""The factorisation of K(p): the sparse direct solvers side by side in one run.

K is the linear-elastic stiffness of a clamped B-spline box (E 20 kPa, nu 0.45, a
50 x 40 x 5 mm patch, degrees 3 x 3 x 2 as the continuum's ``dvs diagnose`` and
``dvs image``), at 27 x 27 x 4 (the loop-speed grid) and 47 x 40 x 7. Each solver runs
in a fresh process (``isolated``: its own memory peak, no library loaded by another)
on one thread and, where it can use more, on every core the process may use:

- the first factorisation (ordering and symbolic analysis included),
- a refactorisation of a matrix of the same pattern (D K D, D diagonal: the
  symbolic analysis reused where the solver keeps it),
- a solve of 10 right-hand sides, and the relative residual |K X - B| / |B| of the
  solves after both factorisations (the larger),
- the peak resident memory above what the process held before the factorisation.

The times are printed as ratios to SuperLU's (the shared machine moves every column
alike). Solvers: SuperLU (scipy; ``solvers.linalg.cholmod.symmetric_lu``), the
project's CHOLMOD (``solvers.linalg.cholmod``), and MKL's PARDISO (pypardiso) when it
is installed. ``dvs bench factorisation``; part of ``make bench``
(``--diagnose``); docs/results/factorisation.md.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from experiments.command.options import Command

GRIDS = ((27, 27, 4), (47, 40, 7))
"""Control grids of the benchmark: the loop-speed grid and a larger volume."""

DEGREES = (3, 3, 2)
"""Degrees of the benchmark's volume: those of the continuum's default model."""

RIGHT_HAND_SIDES = 10
"""Columns of the timed solve (a diagnosis solves several loads at once)."""


def clamped_elasticity(shape, lengths=(50.0, 40.0, 5.0), degrees=(2, 2, 2)) -> sp.csc_matrix:
    """K [N/mm] of a box of B-splines (E 20 kPa, nu 0.45), its bottom face clamped: SPD.

    Parameters
    ----------
    shape : tuple of int
        Control points along x, y, z.
    lengths : tuple of float
        Box edges [mm].
    degrees : tuple of int
        B-spline degrees along x, y, z.
    """
    from symbolic.continuum import box_volume, elasticity_matrices, lame

    volume = box_volume(lengths, tuple(shape), tuple(degrees))
    terms = elasticity_matrices(volume)
    mu, lam = lame(20.0, 0.45)
    matrix = (mu * terms["shear"] + lam * terms["volumetric"]).tocsc()
    n = volume.basis.size
    bottom = np.flatnonzero(volume.control_points[:, 2] < 1e-9)
    free = np.setdiff1d(np.arange(3 * n), np.concatenate([bottom + k * n for k in range(3)]))
    matrix = matrix[free][:, free].tocsc()
    matrix.sort_indices()
    return matrix


def rescaled(matrix: sp.csc_matrix) -> sp.csc_matrix:
    """D K D with D = diag(1 + 0.2 sin(i)): SPD, K's pattern, other values."""
    d = 1.0 + 0.2 * np.sin(np.arange(matrix.shape[0]))
    columns = np.repeat(np.arange(matrix.shape[0]), np.diff(matrix.indptr))
    data = matrix.data * d[matrix.indices] * d[columns]
    other = sp.csc_matrix((data, matrix.indices.copy(), matrix.indptr.copy()), matrix.shape)
    other.has_sorted_indices = True
    return other


class _SuperLU:
    """scipy's SuperLU as the SPD callers' fallback uses it (no symbolic reuse)."""

    threaded = False

    def __init__(self, threads: int):
        from solvers.linalg.cholmod import symmetric_lu

        self._lu, self.name = symmetric_lu, "SuperLU"

    def factorise(self, matrix):
        self.factor = self._lu(matrix)

    refactorise = factorise

    def solve(self, right):
        return self.factor.solve(right)


class _Cholmod:
    """The project's ``solvers.linalg.cholmod.Cholesky`` (patterns and factors kept);
    cvxopt's OpenBLAS runs on one thread."""

    threaded = False

    def __init__(self, threads: int):
        from solvers.linalg import cholmod

        if not cholmod.available():
            raise ImportError(cholmod.backend())
        self._module, self.name = cholmod, cholmod.backend()

    def factorise(self, matrix):
        if getattr(self, "factor", None) is not None:
            self.factor.close()  # as a fit does: the next K(p) refactorises into it
        self.factor = self._module.Cholesky(matrix)

    refactorise = factorise

    def solve(self, right):
        return self.factor.solve(right)


class _Pardiso:
    """MKL's PARDISO through pypardiso: real SPD (mtype 2) on the upper triangle (CSR);
    phases 11 (analysis), 22 (numeric, again for a refactorisation), 33 (solve)."""

    threaded = True

    def __init__(self, threads: int):
        import pypardiso

        self.solver = pypardiso.PyPardisoSolver(mtype=2)
        self.solver.libmkl.MKL_Set_Num_Threads(threads)
        self.name = "PARDISO (MKL, pypardiso)"

    def _call(self, phase, matrix, right):
        self.solver.set_phase(phase)
        return self.solver._call_pardiso(matrix, right)

    def factorise(self, matrix):
        self.upper = sp.triu(matrix, format="csr")
        self.solver._check_A(self.upper)
        self._call(11, self.upper, np.zeros((matrix.shape[0], 1)))
        self._call(22, self.upper, np.zeros((matrix.shape[0], 1)))

    def refactorise(self, matrix):
        self.upper = sp.triu(matrix, format="csr")
        self._call(22, self.upper, np.zeros((matrix.shape[0], 1)))

    def solve(self, right):
        return self._call(33, self.upper, np.asfortranarray(right))


SOLVERS = {"superlu": _SuperLU, "cholmod": _Cholmod, "pardiso": _Pardiso}
"""The compared solvers by name; each that cannot load is left out of the table."""


def _memory_kb(field: str) -> int:
    """A field of /proc/self/status [kB] (VmRSS, VmHWM)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def _residual(matrix, solution, right) -> float:
    return float(np.linalg.norm(matrix @ solution - right) / np.linalg.norm(right))


def _measure(name: str, path: str, threads: int) -> dict | None:
    """Run in a fresh process: one solver on the matrix saved at ``path``."""
    from solvers.linalg.blas import one_thread

    matrix = sp.load_npz(path).tocsc()
    matrix.sort_indices()
    other = rescaled(matrix)
    right = np.random.default_rng(0).standard_normal((matrix.shape[0], RIGHT_HAND_SIDES))
    try:
        solver = SOLVERS[name](threads)
    except (ImportError, OSError) as error:
        return {"name": name, "missing": str(error)}
    with one_thread() if threads == 1 else _unchanged():
        warm = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(50, 50), format="csc")
        solver.factorise(warm)  # libraries loaded, lazy imports done: not timed
        solver.solve(np.ones((50, 1)))
        Path("/proc/self/clear_refs").write_text("5")  # VmHWM := VmRSS
        before = _memory_kb("VmRSS")
        begin = time.perf_counter()
        solver.factorise(matrix)
        first = time.perf_counter() - begin
        begin = time.perf_counter()
        solution = solver.solve(right)
        solve = time.perf_counter() - begin
        residual = _residual(matrix, solution, right)
        begin = time.perf_counter()
        solver.refactorise(other)
        again = time.perf_counter() - begin
        residual = max(residual, _residual(other, solver.solve(right), right))
        peak = _memory_kb("VmHWM") - before
    return {
        "name": solver.name,
        "threads": threads,
        "factorise_s": first,
        "refactorise_s": again,
        "solve_s": solve,
        "residual": residual,
        "peak_mb": peak / 1024.0,
    }


class _unchanged:
    def __enter__(self):
        return self

    def __exit__(self, *_):
        return False


def factorisation_benchmark(grids=GRIDS, solvers=tuple(SOLVERS), log=print) -> list[dict]:
    """Every solver of ``solvers`` on K of each grid, each in a fresh process; one
    table per grid, times as ratios to SuperLU's on one thread.

    Returns
    -------
    list of dict
        One row per grid, solver and thread count: ``factorise_s``, ``refactorise_s``,
        ``solve_s`` [s], ``residual`` [1], ``peak_mb`` [MB].
    """
    from experiments.command.isolation import isolated

    rows = []
    for shape in grids:
        matrix = clamped_elasticity(shape, degrees=DEGREES)
        label = "x".join(map(str, shape))
        log(
            f"factorisation of K at {label} ({'x'.join(map(str, DEGREES))}): "
            f"{matrix.shape[0]} unknowns, {matrix.nnz / 1e6:.2f} M nonzeros; "
            f"{RIGHT_HAND_SIDES}-column solve"
        )
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "k.npz")
            sp.save_npz(path, matrix, compressed=False)
            del matrix
            measured = []
            cores = len(os.sched_getaffinity(0))
            for name in solvers:
                counts = (1, cores) if SOLVERS[name].threaded and cores > 1 else (1,)
                for count in counts:
                    row = isolated(_measure, name, path, count)
                    if "missing" in row:
                        log(f"  {name}: not available ({row['missing']})")
                        break
                    measured.append({**row, "grid": shape})
        reference = next((r for r in measured if r["name"] == "SuperLU"), measured[0])
        log(
            "  solver | threads | factorise | refactorise | solve | residual | peak MB"
            " (times [s], and / SuperLU's)"
        )
        for row in measured:
            ratios = [row[k] / reference[k] for k in ("factorise_s", "refactorise_s", "solve_s")]
            log(
                f"  {row['name']} | {row['threads']} | {row['factorise_s']:.3f} "
                f"({ratios[0]:.2f}) | {row['refactorise_s']:.3f} ({ratios[1]:.2f}) | "
                f"{row['solve_s']:.3f} ({ratios[2]:.2f}) | {row['residual']:.1e} | "
                f"{row['peak_mb']:.0f}"
            )
        rows.extend(measured)
    return rows


def build_parser(prog: str = "python -m experiments.inverse.factorisation"):
    """The options of ``dvs bench factorisation``."""
    from experiments.command.options import make_parser

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--grids",
        default=",".join("x".join(map(str, g)) for g in GRIDS),
        help="control grids MxNxL, comma-separated (27x27x4,47x40x7)",
    )
    parser.add_argument(
        "--solvers", default=",".join(SOLVERS), help="of superlu,cholmod,pardiso (all)"
    )
    return parser


def work(args) -> int:
    """Check the grids and solvers, then print the table (``factorisation_benchmark``)."""
    from experiments.command.options import UsageError, check_grid, parse_grid

    texts = [g for g in args.grids.split(",") if g]
    if not texts:
        raise UsageError("--grids takes a comma list of grids, e.g. 27x27x4")
    grids = [check_grid(parse_grid(g, "--grids"), DEGREES, g, "--grids") for g in texts]
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    unknown = sorted(set(solvers) - set(SOLVERS))
    if unknown or not solvers:
        choices = ",".join(SOLVERS)
        raise UsageError(f"--solvers takes a comma list of {choices}, got {args.solvers!r}")
    factorisation_benchmark(grids, solvers)
    return 0


main = Command("experiments.inverse.factorisation", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
