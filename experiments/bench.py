"""Benchmarks: build and solve times measured side by side in one run.

Run ``python -m experiments.bench`` (or ``make bench``). Times are wall-clock
on a shared machine; compare the ratios printed, not the absolute numbers.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from experiments.synthetic import TRUE_PARAMETERS, PhantomSettings, probe_loads, segmented_surfaces
from solvers.equilibrium import EquilibriumSolver
from symbolic.model import BoundaryConditions, TissueModel
from symbolic.volume import VolumeSpline

GRIDS = ((9, 9, 2), (17, 17, 3), (33, 33, 4))


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
    return ForwardTiming(
        grid,
        volume.basis.size,
        3 * model.n_free,
        fitted - start,
        built - fitted,
        solved - built,
        result.iterations,
    )


def print_forward(timings: list[ForwardTiming]) -> None:
    """Table of forward timings plus the fitted scaling exponent of build time."""
    print(
        f"{'grid':>10} {'n':>6} {'dofs':>6} {'fit s':>7} {'build s':>8} {'solve s':>8} {'its':>4}"
    )
    for t in timings:
        grid = "x".join(map(str, t.grid))
        print(
            f"{grid:>10} {t.control_points:>6} {t.free_dofs:>6} {t.fit:7.3f} "
            f"{t.build:8.3f} {t.solve:8.3f} {t.newton_iterations:>4}"
        )
    sizes = np.array([t.control_points for t in timings], dtype=float)
    builds = np.array([t.build for t in timings])
    exponent = np.polyfit(np.log(sizes), np.log(builds), 1)[0]
    ratio = builds[-1] / builds[0]
    print(
        f"build time ratio {timings[-1].grid} / {timings[0].grid}: {ratio:.1f} "
        f"for {sizes[-1] / sizes[0]:.1f}x control points; fitted exponent {exponent:.2f}"
    )


def inverse_problem(grid: tuple[int, int, int]):
    """The phantom's two-load inverse problem (alpha only) on a given control grid."""
    from experiments.fitting import FitSettings, build_problem
    from experiments.simulate import SimulationSettings, simulate

    m, n, layers = grid
    phantom = PhantomSettings(segmentation=(2 * m + 1, 2 * n + 1), grid=(m, n, 2), markers=(m, n))
    dataset = simulate(phantom, SimulationSettings(noise_mm=0.02, seed=0))
    return build_problem(dataset, FitSettings(names=("alpha_u", "alpha_v", "alpha_w"), grid=grid))


def time_inverse(grid: tuple[int, int, int], methods=("simultaneous", "nested")) -> dict:
    """Build and solve times [s] of the inverse methods on one grid, side by side."""
    from solvers.nested import NestedSolver, PaperNestedSolver
    from solvers.problem import InverseProblem
    from solvers.simultaneous import SimultaneousSolver

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
        rows[name] = {
            "build": built - start,
            "solve": result.solve_time_s,
            "total": time.perf_counter() - start,
            "iterations": result.iterations,
            "forward_solves": result.forward_solves,
            "x": result.x,
        }
    return rows


def print_inverse(grid, rows: dict) -> None:
    """One block of the inverse table, with the speed-up of simultaneous over the others."""
    label = "x".join(map(str, grid))
    for name, row in rows.items():
        print(
            f"{label:>10} {name:>13} build {row['build']:7.3f} s  solve {row['solve']:8.3f} s  "
            f"total {row['total']:8.3f} s  its {row['iterations']:>3}  "
            f"forward solves {row['forward_solves']:>4}"
        )
    base = rows["simultaneous"]["total"]
    for name, row in rows.items():
        if name != "simultaneous":
            print(
                f"{'':>10} simultaneous (build included) is {row['total'] / base:.1f}x "
                f"faster than {name}"
            )


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--k0", type=float, default=0.0, help="stiffening for the forward runs")
    parser.add_argument("--skip-paper", action="store_true", help="omit the slow paper method")
    parser.add_argument("--grids", default="9x9x2,17x17x3,33x33x4", help="inverse grids")
    args = parser.parse_args(argv)
    print("Forward model (build = TissueModel + residual and Jacobian Functions)")
    print_forward([time_forward(grid, args.k0) for grid in GRIDS])
    print("\nInverse, two load cases, alpha_u, alpha_v, alpha_w, from the paper's start")
    for text in args.grids.split(","):
        grid = tuple(int(v) for v in text.split("x"))
        methods = ("simultaneous", "nested")
        if grid == (9, 9, 2) and not args.skip_paper:
            methods += ("paper",)
        print_inverse(grid, time_inverse(grid, methods))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
