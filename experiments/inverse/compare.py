"""Simultaneous vs nested exact vs nested paper-faithful, on one problem (``dvs study compare``).

For each method: iterations, forward solves, build and solve wall time, final
cost, parameter error (when the truth is known), and the success rate over a
multi-start set (log-uniform within the bounds). A start succeeds when the
method reports convergence and its cost is within 1e-6 (relative) of the best
cost any method found.

Run ``python -m experiments.inverse.compare --out DIR`` for the default phantom.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.command.options import Command
from experiments.output.atomic import atomic_savefig, atomic_write_json, atomic_write_text  # noqa: E402
from experiments.problem.fitting import FitSettings, build_problem  # noqa: E402
from solvers.inverse.nested import NestedSolver
from solvers.inverse.paperfaithful import PaperNestedSolver
from solvers.inverse.problem import InverseProblem  # noqa: E402
from solvers.inverse.simultaneous import SimultaneousSolver  # noqa: E402

METHODS = {
    "simultaneous": SimultaneousSolver,
    "nested": NestedSolver,
    "paper": PaperNestedSolver,
}
ALPHAS = ("alpha_u", "alpha_v", "alpha_w")

MAX_STARTS = 1000
"""Most multi-start points accepted on the command line."""


def log_uniform_starts(problem: InverseProblem, count: int, seed: int = 0) -> np.ndarray:
    """``count`` start points, log-uniform within the bounds (natural units)."""
    rng = np.random.default_rng(seed)
    lower, upper = problem.space.lower, problem.space.upper
    return np.exp(rng.uniform(np.log(lower), np.log(upper), (count, len(lower))))


def compare(
    problem: InverseProblem,
    starts: int = 20,
    paper_starts: int | None = None,
    truth: dict | None = None,
    seed: int = 0,
    methods=tuple(METHODS),
    log=print,
) -> dict:
    """Run every method from the paper's start and from a multi-start set.

    Parameters
    ----------
    problem : InverseProblem
        The shared problem.
    starts : int
        Multi-start points for the simultaneous and nested exact methods.
    paper_starts : int, optional
        Multi-start points for the paper-faithful method (default ``starts``);
        it is about two orders of magnitude slower per start.
    truth : dict, optional
        True parameter values, for the parameter error.
    """
    points = log_uniform_starts(problem, starts, seed)
    rows = {}
    for name in methods:
        begin = time.perf_counter()
        solver = METHODS[name](problem)
        build = time.perf_counter() - begin
        result = solver.solve()
        row = {
            "iterations": result.iterations,
            "forward_solves": result.forward_solves,
            "build_time_s": build,
            "solve_time_s": result.solve_time_s,
            "cost": result.cost,
            "estimate": result.as_dict(),
            "status": result.status,
            "success": bool(result.success),
        }
        if truth:
            row["max_relative_error"] = max(
                abs(result.as_dict()[n] / truth[n] - 1) for n in problem.names if n in truth
            )
        count = starts if name != "paper" or paper_starts is None else paper_starts
        multi = [solver.solve(point) for point in points[:count]]
        row["multistart"] = [(r.success, r.cost) for r in multi]
        row["multistart_time_s"] = sum(r.solve_time_s for r in multi)
        rows[name] = row
        log(
            f"  {name:>12}: cost {result.cost:.6g}, {result.iterations} its, "
            f"{result.forward_solves} forward solves, build {build:.3f} s, "
            f"solve {result.solve_time_s:.3f} s, {count} starts in {row['multistart_time_s']:.1f} s"
        )
    best = min(
        min(c for _, c in row["multistart"] + [(True, row["cost"])]) for row in rows.values()
    )
    for row in rows.values():
        hits = [ok and c <= best * (1 + 1e-6) + 1e-15 for ok, c in row["multistart"]]
        row["success_rate"] = float(np.mean(hits)) if hits else float("nan")
        row["starts"] = len(hits)
        del row["multistart"]
    rows["success"] = all(row["success"] for row in rows.values() if isinstance(row, dict))
    if "simultaneous" in rows and "paper" in rows:
        sim, paper = rows["simultaneous"], rows["paper"]
        total = sim["build_time_s"] + sim["solve_time_s"]
        rows["speedup_simultaneous_vs_paper"] = (
            paper["build_time_s"] + paper["solve_time_s"]
        ) / total
    return rows


def table(rows: dict) -> str:
    """Markdown table of a comparison."""
    header = (
        "| method | iterations | forward solves | build [s] | solve [s] | cost [mm^2] "
        "| max rel. error | success rate |\n|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for name, row in rows.items():
        if not isinstance(row, dict):
            continue
        error = row.get("max_relative_error")
        rate = f"{row['success_rate']:.0%} of {row['starts']}" if row["starts"] else "- (no starts)"
        lines.append(
            f"| {name} | {row['iterations']} | {row['forward_solves']} | "
            f"{row['build_time_s']:.3f} | {row['solve_time_s']:.3f} | {row['cost']:.6g} | "
            f"{'' if error is None else f'{error:.2e}'} | "
            f"{rate} |"
        )
    text = header + "\n".join(lines) + "\n"
    if "speedup_simultaneous_vs_paper" in rows:
        text += (
            f"\nSimultaneous (build + solve) is {rows['speedup_simultaneous_vs_paper']:.0f} times "
            "faster than the paper-faithful nested method, measured in the same run.\n"
        )
    return text


def plot(rows: dict, path: Path) -> None:
    """Wall time (log scale) and success rate per method."""
    names = [n for n, r in rows.items() if isinstance(r, dict)]
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.6))
    total = [rows[n]["build_time_s"] + rows[n]["solve_time_s"] for n in names]
    left.bar(names, total, color=["C0", "C1", "C2"][: len(names)])
    left.set(yscale="log", ylabel="build + solve [s]", title="time from the paper's start")
    right.bar(names, [100 * rows[n]["success_rate"] for n in names], color="0.5")
    right.set(ylim=(0, 105), ylabel="converged [%]", title="multi-start success")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def run(dataset, out: Path, starts: int = 20, paper_starts: int = 5, truth=None, log=print):
    """Compare the methods on a dataset (path or Dataset) and write the outputs."""
    from experiments.data.dataset import Dataset, load_dataset

    data = dataset if isinstance(dataset, Dataset) else load_dataset(dataset)
    problem = build_problem(data, FitSettings(names=ALPHAS))
    log(
        f"comparing methods on {problem.n_residuals} residuals, {starts} starts "
        f"({paper_starts} for the paper-faithful method)"
    )
    rows = compare(problem, starts, paper_starts, truth, log=log)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "compare.json", rows)
    atomic_write_text(out / "compare.md", table(rows))
    plot(rows, out / "compare.png")
    return rows


def build_parser(prog: str = "python -m experiments.inverse.compare"):
    """The options of ``dvs study compare``."""
    from experiments.command.options import add_dataset_argument, make_parser, path_argument

    parser = make_parser(prog, "Simultaneous vs nested vs paper-faithful, multi-start.")
    add_dataset_argument(parser, "; default: phantom", nargs="?")
    parser.add_argument("--starts", type=int, default=20, help="multi-start points")
    parser.add_argument(
        "--paper-starts",
        type=int,
        default=3,
        help="multi-start points for the (slow) paper-faithful method",
    )
    parser.add_argument(
        "--out", type=path_argument, default=Path("compare-output"), help="directory"
    )
    return parser


def work(args) -> int:
    """``dvs study compare [FILE.npz] --out DIR``; exit 2 with one line for bad input."""
    from experiments.command.options import UsageError, check_output_dir, not_converged
    from experiments.phantom.forehead import TRUE_PARAMETERS
    from experiments.phantom.simulate import simulate

    if not 1 <= args.starts <= MAX_STARTS or not 0 <= args.paper_starts <= MAX_STARTS:
        raise UsageError(
            f"--starts must lie in 1-{MAX_STARTS} and --paper-starts in 0-{MAX_STARTS}"
        )
    check_output_dir(args.out)
    dataset = args.dataset or simulate()
    truth = None if args.dataset else TRUE_PARAMETERS
    rows = run(dataset, args.out, args.starts, args.paper_starts, truth)
    print(table(rows))
    if not rows["success"]:
        failed = [n for n, r in rows.items() if isinstance(r, dict) and not r["success"]]
        what = f"{', '.join(failed)} from the paper's start"
        return not_converged(args.prog, what, args.out / "compare.json")
    return 0


main = Command("experiments.inverse.compare", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
