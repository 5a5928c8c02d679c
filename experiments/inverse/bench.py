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

import casadi as ca
import numpy as np

from experiments.command.isolation import isolated, peak_mb
from experiments.command.options import Command
from experiments.inverse.benchtables import (
    REPEATS,
    ForwardTiming,
    print_forward,
    print_inverse,
    print_scaling,
    print_targets,
)
from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    probe_loads,
    segmented_surfaces,
)
from solvers.forward.componentwise import ScalarSystem
from solvers.forward.equilibrium import EquilibriumSolver
from symbolic.constraints import BoundaryConditions
from symbolic.model import TissueModel
from symbolic.volume import VolumeSpline

GRIDS = ((9, 9, 2), (17, 17, 3), (33, 33, 4), (65, 65, 4))


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
    from solvers.inverse.nested import NestedSolver
    from solvers.inverse.paperfaithful import PaperNestedSolver
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


def work(args) -> int:
    """Print the benchmark tables (and write ``bench.json`` with ``--out``)."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.output.atomic import atomic_write_json

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
        from experiments.diagnosis.continuumstudy import diagnosis_benchmark
        from experiments.diagnosis.study import diagnosis_timings
        from experiments.diagnosis.tissuedefaults import defaults_benchmark
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


main = Command("experiments.inverse.bench", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
