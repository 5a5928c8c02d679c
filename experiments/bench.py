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


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--k0", type=float, default=0.0, help="stiffening for the forward runs")
    args = parser.parse_args(argv)
    print("Forward model (build = TissueModel + residual and Jacobian Functions)")
    print_forward([time_forward(grid, args.k0) for grid in GRIDS])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
