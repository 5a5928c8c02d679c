"""Benchmarks: build and solve times measured side by side in one run.

Run ``python -m experiments.inverse.bench`` (or ``make bench``). Times are wall-clock
on a shared machine; compare the ratios printed, not the absolute numbers.

Every measurement runs in a fresh process, so that its peak resident memory
(``ru_maxrss``) is its own and no cache of an earlier measurement helps it.
The model (geometry fit, numeric M, D, K) is made before the clock starts;
"build" is the CasADi problem and the solver, "solve" the solver's call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from experiments.command.isolation import isolated, peak_mb
from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    probe_loads,
    segmented_surfaces,
)
from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import EquilibriumSolver
from symbolic.model import BoundaryConditions, TissueModel
from symbolic.volume import VolumeSpline

GRIDS = ((9, 9, 2), (17, 17, 3), (33, 33, 4), (65, 65, 4))
REPEATS = 5
"""Repeated solves per method (median reported), besides the first, timed one; only
where a solve takes under 5 s (the paper-faithful method and the 33 x 33 x 4 grid are
timed once)."""


@dataclass
class ForwardTiming:
    """Forward-model timings for one control grid [s]."""

    grid: tuple[int, int, int]
    control_points: int
    free_dofs: int
    fit: float
    build: float
    solve: float
    newton_iterations: int
    stiffness_nonzeros: int = 0
    peak_mb: float = float("nan")
    factorisation: float = float("nan")
    """One factorisation of the scalar stiffness A on this grid [s] (median of 3): the
    floor unit of the "x floor" column."""


def volume_for_grid(grid: tuple[int, int, int]) -> VolumeSpline:
    """The phantom on a given control grid (segmented densely enough for it)."""
    m, n, layers = grid
    settings = PhantomSettings(segmentation=(2 * m + 1, 2 * n + 1), grid=(m, n, 2))
    volume, _ = VolumeSpline.fit(segmented_surfaces(settings), settings.grid, settings.degrees)
    return volume if layers == 2 else volume.with_layers(layers)


def time_forward(grid: tuple[int, int, int], k0: float = 0.0) -> ForwardTiming:
    """Fit, build (model + residual Functions) and solve under 0.25 N."""
    start = time.perf_counter()
    volume = volume_for_grid(grid)
    fitted = time.perf_counter()
    model = TissueModel(volume, {**TRUE_PARAMETERS, "k0": k0}, BoundaryConditions())
    solver = EquilibriumSolver(model)
    force = model.generalized_force(probe_loads(model)[-1])
    built = time.perf_counter()
    result = solver.solve(force)
    solved = time.perf_counter()
    scalar = ScalarSystem(model, ())
    factorisations = []
    for _ in range(3):
        begin = time.perf_counter()
        scalar.factor(())
        factorisations.append(time.perf_counter() - begin)
    return ForwardTiming(
        grid,
        volume.basis.size,
        3 * model.n_free,
        fitted - start,
        built - fitted,
        solved - built,
        result.iterations,
        int(sum(abs(k) for k in model.terms.values()).nnz),
        factorisation=float(np.median(factorisations)),
    )


def print_forward(timings: list[ForwardTiming]) -> None:
    """Table of forward timings plus the fitted scaling exponent of build time."""
    print(
        f"{'grid':>10} {'n':>6} {'dofs':>6} {'nnz K':>8} {'fit s':>7} {'build s':>8} "
        f"{'solve s':>8} {'its':>4} {'factor A s':>10} {'peak MB':>8}"
    )
    for t in timings:
        grid = "x".join(map(str, t.grid))
        print(
            f"{grid:>10} {t.control_points:>6} {t.free_dofs:>6} {t.stiffness_nonzeros:>8} "
            f"{t.fit:7.3f} {t.build:8.3f} {t.solve:8.3f} {t.newton_iterations:>4} "
            f"{t.factorisation:10.4f} {t.peak_mb:8.0f}"
        )
    sizes = np.array([t.control_points for t in timings], dtype=float)
    builds = np.array([t.build for t in timings])
    exponent = scaling_exponent(sizes, builds)
    ratio = builds[-1] / builds[0]
    nonzeros = [t.stiffness_nonzeros for t in timings]
    print(
        f"build time ratio {timings[-1].grid} / {timings[0].grid}: {ratio:.1f} "
        f"for {sizes[-1] / sizes[0]:.1f}x control points; fitted exponent {exponent:.2f} "
        f"against control points, {scaling_exponent(nonzeros, builds):.2f} against the "
        "nonzeros of K (more layers couple more points per row)"
    )


def inverse_problem(grid: tuple[int, int, int]):
    """The phantom's two-load inverse problem (alpha only) on a given control grid."""
    from experiments.phantom.simulate import SimulationSettings, simulate
    from experiments.problem.fitting import FitSettings, build_problem

    m, n, layers = grid
    phantom = PhantomSettings(segmentation=(2 * m + 1, 2 * n + 1), grid=(m, n, 2), markers=(m, n))
    dataset = simulate(phantom, SimulationSettings(noise_mm=0.02, seed=0))
    return build_problem(dataset, FitSettings(names=("alpha_u", "alpha_v", "alpha_w"), grid=grid))


def time_inverse(grid: tuple[int, int, int], methods=("simultaneous", "nested")) -> dict:
    """Build and solve times [s] of the inverse methods on one grid, in this process."""
    from solvers.inverse.nested import NestedSolver, PaperNestedSolver
    from solvers.inverse.problem import InverseProblem
    from solvers.inverse.simultaneous import SimultaneousSolver

    classes = {
        "simultaneous": SimultaneousSolver,
        "nested": NestedSolver,
        "paper": PaperNestedSolver,
    }
    dataset_problem = inverse_problem(grid)
    rows = {}
    for name in methods:
        start = time.perf_counter()
        # the problem's CasADi residual is built inside each method's timing: "build included"
        problem = InverseProblem(
            dataset_problem.model,
            dataset_problem.cases,
            dataset_problem.space,
            dataset_problem.noise_mm,
            dataset_problem.rest_noise,
        )
        solver = classes[name](problem)
        built = time.perf_counter()
        result = solver.solve()
        total = time.perf_counter() - start
        # repeated solves of the built solver: the steady cost, without first-call set-up
        count = REPEATS if name != "paper" and result.solve_time_s < 5.0 else 0
        repeats = [solver.solve().solve_time_s for _ in range(count)]
        rows[name] = {
            "build": built - start,
            "solve": result.solve_time_s,
            "solve_repeat": float(np.median(repeats)) if repeats else float("nan"),
            "total": total,
            "iterations": result.iterations,
            "forward_solves": result.forward_solves,
            "x": result.x,
            "dofs": 3 * problem.model.n_free,
        }
    return rows


def _load_libraries() -> None:
    """Load IPOPT and MUMPS once (a one-off cost per process, not part of any method)."""
    x = ca.MX.sym("x")
    solver = ca.nlpsol(
        "warm",
        "ipopt",
        {"x": x, "f": (x - 1) ** 2},
        {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"},
    )
    solver(x0=0.0)


def _forward_job(grid, k0) -> ForwardTiming:
    _load_libraries()
    timing = time_forward(grid, k0)
    timing.peak_mb = peak_mb()
    return timing


def _inverse_job(grid, method) -> dict:
    _load_libraries()
    row = time_inverse(grid, (method,))[method]
    row["peak_mb"] = peak_mb()
    return row


def scaling_exponent(dofs, times) -> float:
    """Slope of log(time) against log(dofs): time ~ dofs^exponent."""
    return float(np.polyfit(np.log(np.asarray(dofs, float)), np.log(np.asarray(times)), 1)[0])


def floor_ratio(row: dict, factorisation: float) -> float:
    """Solve time / (iterations x one scalar factorisation of A on the grid): how far a
    method is from its floor of one factorisation per iteration."""
    return row["solve"] / (max(row["iterations"], 1) * factorisation)


def print_inverse(grid, rows: dict, factorisation: float = float("nan")) -> None:
    """One block of the inverse table: times, iterations, memory and the distance to the
    floor (``floor_ratio``); then how the methods compare."""
    label = "x".join(map(str, grid))
    for name, row in rows.items():
        print(
            f"{label:>10} {name:>13} build {row['build']:7.3f} s  solve {row['solve']:8.3f} s "
            f"(repeated {row.get('solve_repeat', np.nan):7.3f} s)  "
            f"total {row['total']:8.3f} s  its {row['iterations']:>3}  "
            f"x floor {floor_ratio(row, factorisation):7.1f}  "
            f"peak {row.get('peak_mb', np.nan):6.0f} MB"
        )
    fastest = min(rows, key=lambda name: rows[name]["total"])
    for name, row in rows.items():
        if name != fastest:
            print(
                f"{'':>10} {fastest} (build included) is "
                f"{row['total'] / rows[fastest]['total']:.1f}x faster than {name}"
            )


def print_scaling(results: dict) -> None:
    """Fitted exponent of total inverse time against free degrees of freedom, per method."""
    for method in ("simultaneous", "nested"):
        points = [
            (rows[method]["dofs"], rows[method]["total"])
            for rows in results.values()
            if method in rows
        ]
        if len(points) >= 2:
            dofs, times = zip(*points)
            print(
                f"{method:>13}: total time ~ dofs^{scaling_exponent(dofs, times):.2f} "
                f"over {min(dofs)}-{max(dofs)} free dofs"
            )


def print_targets(forward: list[ForwardTiming], results: dict) -> None:
    """Each target of the issues next to the measured value, met or not."""

    def line(text, value, target, met):
        print(f"  [{'met' if met else 'NOT met'}] {text}: {value} (target {target})")

    def total(grid, method):
        return results.get(grid, {}).get(method, {}).get("total")

    print("\nTargets")
    if len(forward) >= 2:
        exponent = scaling_exponent(
            [t.stiffness_nonzeros for t in forward], [t.build for t in forward]
        )
        line(
            "forward build time exponent against the nonzeros of K",
            f"{exponent:.2f}",
            "<= 1, linear (+0.05 for timing noise)",
            exponent <= 1.05,
        )
    for t in forward:
        if t.grid == (33, 33, 4):
            line("33x33x4 model build", f"{t.build:.2f} s", "about 1 s", t.build <= 1.0)
    small = results.get((9, 9, 2), {})
    if "simultaneous" in small:
        first, repeated = small["simultaneous"]["solve"], small["simultaneous"]["solve_repeat"]
        line(
            "9x9x2 simultaneous solve, first call", f"{1e3 * first:.0f} ms", "< 50 ms", first < 0.05
        )
        line(
            f"9x9x2 simultaneous solve, median of {REPEATS} repeats",
            f"{1e3 * repeated:.0f} ms",
            "< 50 ms",
            repeated < 0.05,
        )
    if "paper" in small:
        ratio = small["paper"]["total"] / small["simultaneous"]["total"]
        line(
            "9x9x2 paper-faithful / simultaneous (build incl.)",
            f"{ratio:.0f}x",
            ">= 50x",
            ratio >= 50,
        )
    goals = (
        ((33, 33, 4), "nested", 3.0, "<= 3 s"),
        ((33, 33, 4), "simultaneous", 15.0, "<= 15 s (goal 5 s)"),
        ((65, 65, 4), "nested", 30.0, "<= 30 s"),
    )
    for grid, method, limit, target in goals:
        seconds = total(grid, method)
        if seconds is not None:
            label = "x".join(map(str, grid))
            line(f"{label} {method}, build included", f"{seconds:.1f} s", target, seconds <= limit)
    row = results.get((65, 65, 4), {}).get("nested")
    if row is not None:
        line(
            "65x65x4 nested peak memory",
            f"{row['peak_mb']:.0f} MB",
            "<= 4 GB",
            row["peak_mb"] <= 4096,
        )


def build_parser(prog: str = "python -m experiments.inverse.bench"):
    """The options of ``dvs bench inverse``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--k0", type=float, default=0.0, help="stiffening for the forward runs")
    parser.add_argument("--skip-paper", action="store_true", help="omit the slow paper method")
    parser.add_argument(
        "--paper-grids",
        default="9x9x2,17x17x3",
        help="grids for the paper-faithful method (66 transients; 33x33x4 would take hours)",
    )
    parser.add_argument("--grids", default="9x9x2,17x17x3,33x33x4,65x65x4", help="inverse grids")
    parser.add_argument("--methods", default="simultaneous,nested", help="inverse methods")
    parser.add_argument("--out", type=path_argument, default=None, help="also write DIR/bench.json")
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="only the loop-speed rows: dvs diagnose at 9x9x2, and at 27x27x4 diagnose, "
        "default dvs diagnose on two tissue patches, image, a design search and one "
        "sequential step",
    )
    return parser


def _grids(text: str, option: str) -> list[tuple[int, int, int]]:
    """Comma list of control grids, each one ``dvs fit --grid`` would accept."""
    from experiments.command.options import check_grid, parse_grid
    from experiments.problem.fitting import FitSettings

    degrees = FitSettings().degrees
    return [
        check_grid(parse_grid(g.strip(), option), degrees, g.strip(), option)
        for g in text.split(",")
        if g.strip()
    ]


def main(argv: list[str] | None = None, prog: str = "python -m experiments.inverse.bench") -> int:
    """Print the benchmark tables (and write ``bench.json`` with ``--out``)."""
    from experiments.command.options import UsageError, check_output_dir, run_guarded
    from experiments.output.atomic import atomic_write_json

    args = build_parser(prog).parse_args(argv)

    def work() -> int:
        if args.out is not None:  # first: the grids' check imports the fitting stack
            check_output_dir(args.out)
        grids = _grids(args.grids, "--grids")
        paper_grids = _grids(args.paper_grids, "--paper-grids")
        methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
        if not methods or set(methods) - {"simultaneous", "nested", "paper"}:
            raise UsageError(f"--methods takes simultaneous,nested,paper; got {args.methods!r}")
        if args.diagnose:
            from experiments.design.speed import (
                design_search_benchmark,
                next_benchmark,
                sequential_step_benchmark,
            )
            from experiments.diagnosis.continuum import diagnosis_benchmark
            from experiments.diagnosis.defaults import defaults_benchmark
            from experiments.diagnosis.study import diagnosis_timings
            from experiments.imaging.bench import imaging_benchmark
            from experiments.inverse.factorisation import factorisation_benchmark

            factorisation_benchmark()
            diagnosis_timings()
            diagnosis_benchmark()
            defaults_benchmark()
            imaging_benchmark()
            design_search_benchmark()
            sequential_step_benchmark()
            next_benchmark()
            return 0
        print("Forward model (build = TissueModel + residual and Jacobian Functions)", flush=True)
        forward = [isolated(_forward_job, grid, args.k0) for grid in GRIDS]
        factorisations = {timing.grid: timing.factorisation for timing in forward}
        print_forward(forward)
        print("\nInverse, two load cases, alpha_u, alpha_v, alpha_w, from the paper's start")
        results = {}
        for grid in grids:
            chosen = methods + (("paper",) if grid in paper_grids and not args.skip_paper else ())
            results[grid] = {m: isolated(_inverse_job, grid, m) for m in dict.fromkeys(chosen)}
            print_inverse(grid, results[grid], factorisations.get(grid, float("nan")))
        if len(results) >= 2:
            print("\nScaling")
            print_scaling(results)
        print_targets(forward, results)
        if args.out is not None:
            document = {
                "forward": [vars(row) for row in forward],
                "inverse": {"x".join(map(str, g)): rows for g, rows in results.items()},
            }
            args.out.mkdir(parents=True, exist_ok=True)
            atomic_write_json(args.out / "bench.json", document)
            print(f"-> {args.out / 'bench.json'}")
        return 0

    return run_guarded(prog, work)


if __name__ == "__main__":
    raise SystemExit(main())
