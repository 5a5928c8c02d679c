"""The tables ``dvs bench inverse`` prints: forward and inverse times, the scaling
exponents and the targets (docs/inverse.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
