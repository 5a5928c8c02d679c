"""Batch studies on dask.distributed: multi-start robustness and Monte-Carlo coverage.

By default the work runs on a ``LocalCluster`` on this machine (one process
per worker, one thread each: CasADi and SuperLU are not shared between
threads). ``scheduler="tcp://host:8786"`` sends it to a real cluster; the
workers there need this package installed. ``scheduler=None`` with
``workers=0`` runs serially, for comparison.

Run ``python -m experiments.inverse.batch --study coverage --count 20 [--scheduler ADDR]``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from experiments.command.options import Command

ALPHAS = ("alpha_u", "alpha_v", "alpha_w")


def coverage_task(seed: int, noise_mm: float = 0.02) -> dict:
    """One Monte-Carlo draw: simulate, fit (nested exact), report estimates and std."""
    from experiments.phantom.simulate import SimulationSettings, simulate
    from experiments.problem.fitting import FitSettings, build_problem
    from solvers.inverse.identifiability import analyse
    from solvers.inverse.nested import NestedSolver

    dataset = simulate(measurement=SimulationSettings(noise_mm=noise_mm, seed=int(seed)))
    problem = build_problem(dataset, FitSettings(names=ALPHAS))
    result = NestedSolver(problem).solve()
    report = analyse(problem, result.x)
    return {
        "seed": int(seed),
        "x": result.x.tolist(),
        "std": [p.std for p in report.parameters],
        "success": result.success,
    }


def multistart_task(start: Sequence[float], seed: int = 0) -> dict:
    """One start of the simultaneous method on the phantom's dataset (seed fixes the data)."""
    from experiments.phantom.simulate import SimulationSettings, simulate
    from experiments.problem.fitting import FitSettings, build_problem
    from solvers.inverse.simultaneous import SimultaneousSolver

    dataset = simulate(measurement=SimulationSettings(seed=int(seed)))
    problem = build_problem(dataset, FitSettings(names=ALPHAS))
    result = SimultaneousSolver(problem).solve(np.asarray(start, dtype=float))
    return {
        "start": list(map(float, start)),
        "x": result.x.tolist(),
        "cost": result.cost,
        "success": result.success,
    }


def run_batch(
    task: Callable, items: Sequence, scheduler: str | None = None, workers: int = 2, log=print
) -> list:
    """Map ``task`` over ``items`` on dask (local cluster, or ``scheduler``), in order.

    ``workers=0`` without a scheduler runs serially in this process.
    """
    if scheduler is None and workers == 0:
        return [task(item) for item in items]
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        )
    client = Client(scheduler if scheduler else cluster)
    try:
        futures = client.map(task, list(items), pure=False)
        done = 0
        for _ in as_completed(futures):
            done += 1
            log(f"  {done}/{len(futures)} done")
        return client.gather(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def coverage_summary(results: list[dict], truth: dict) -> dict:
    """Fraction within 3 std and RMS z-score per parameter."""
    x = np.array([r["x"] for r in results])
    std = np.array([r["std"] for r in results], dtype=float)
    z = (x - np.array([truth[n] for n in ALPHAS])) / std
    return {
        "draws": len(results),
        "within_3_std": dict(zip(ALPHAS, np.mean(np.abs(z) < 3, axis=0).tolist())),
        "rms_z": dict(zip(ALPHAS, np.sqrt(np.mean(z**2, axis=0)).tolist())),
    }


def build_parser(prog: str = "python -m experiments.inverse.batch"):
    """The options of ``dvs study batch``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "Batch studies on dask.distributed.")
    parser.add_argument(
        "--study", choices=("coverage", "multistart"), default="coverage", help="which study"
    )
    parser.add_argument("--count", type=int, default=20, help="draws or starts (1-10000)")
    parser.add_argument("--workers", type=int, default=2, help="local workers (1-64)")
    parser.add_argument("--scheduler", default=None, help="address of a dask scheduler")
    parser.add_argument("--out", type=path_argument, default=None, help="also write DIR/batch.json")
    return parser


def work(args) -> int:
    """Command line for the batch studies."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.output.atomic import atomic_write_json
    from experiments.phantom.forehead import TRUE_PARAMETERS

    if not 1 <= args.count <= 10_000 or not 1 <= args.workers <= 64:
        raise UsageError("--count must lie in 1-10000 and --workers in 1-64")
    if args.out is not None:
        check_output_dir(args.out)
    print(f"{args.study}: {args.count} runs on {args.workers} workers", flush=True)
    if args.study == "coverage":
        results = run_batch(coverage_task, range(args.count), args.scheduler, args.workers)
        summary = coverage_summary(results, TRUE_PARAMETERS)
        print(json.dumps(summary, indent=2))
    else:
        rng = np.random.default_rng(0)
        starts = np.exp(rng.uniform(np.log(1e-2), np.log(1e2), (args.count, 3)))
        results = run_batch(multistart_task, starts.tolist(), args.scheduler, args.workers)
        best = min(r["cost"] for r in results)
        hits = sum(r["success"] and r["cost"] <= best * (1 + 1e-6) for r in results)
        summary = {"starts": len(results), "best_cost": best, "hits": hits}
        print(f"{hits}/{len(results)} starts reached the best cost {best:.6g}")
    if args.out is not None:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_json(Path(args.out) / "batch.json", {"study": args.study, **summary})
    return 0


main = Command("experiments.inverse.batch", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
