"""``dvs bench design``: the design search's speed, its gap to exhaustive search, and its
designs against the hand-chosen 10-load design, measured side by side in one run.

On the phantom's diagnosis dataset (9x9 markers, 9x9x2 model, noise 0.02 mm):

1. **speed**: ``dvs design``'s work (base fit, candidate information, search) for the
   base parameters and for effects, with the time of one base fit beside it;
2. **gap**: greedy + exchange against exhaustive enumeration on a small case (9
   contacts x 5 directions at 0.25 N = 45 candidates, 3 presses: 16 215 designs);
3. **better than by hand**: det(F)^(1/p) of the D-design over the 10-load design's,
   and the power of the designs for heterogeneity and base_compliance at their
   realistic magnitudes, with the 10-load design's power beside each.
"""

from __future__ import annotations

import time

from experiments.command.options import Command
from experiments.design.plan import DesignSettings, plan

SPEED_TARGET_S = 30.0
"""The target: a design over at least 100 candidates at 9x9x2 within 30 s."""


def bench_dataset(seed: int = 1):
    """The diagnosis phantom with noise, declaring its noise level."""
    from experiments.design.predictions import NOISE_MM, phantom_dataset

    return phantom_dataset({}, seed, "diagnosis", NOISE_MM)


def time_designs(dataset, targets: dict, budget: int, log=print) -> dict:
    """``plan`` for every target, timed; the power and D figures beside the dataset's."""
    from experiments.design.predictions import base_fit

    begin = time.perf_counter()
    base_fit(dataset)
    fit_seconds = time.perf_counter() - begin
    rows = {}
    for name, target in targets.items():
        begin = time.perf_counter()
        chosen = plan(dataset, DesignSettings(target=target, budget=budget), log=lambda _: None)
        seconds = time.perf_counter() - begin
        document = chosen.document
        reference = document["dataset_design"]["predicted"]["powers"]
        row = {
            "seconds": seconds,
            "candidates": document["candidates"]["count"],
            "criterion": document["criterion"],
            "fit_ratio": seconds / fit_seconds,
            "det_root_ratio": document["det_root_ratio"],
            "powers": {
                effect: {
                    "design": figures["power"],
                    "design_noncentrality": figures["noncentrality"],
                    "ten_load": reference[effect]["power"],
                    "ten_load_noncentrality": reference[effect]["noncentrality"],
                }
                for effect, figures in document["predicted"]["powers"].items()
            },
            "presses": document["presses"],
        }
        rows[name] = row
        log(
            f"  {name:28s} {row['candidates']} candidates  {seconds:6.1f} s "
            f"({row['fit_ratio']:.1f} base fits)"
            + (f"  det ratio {row['det_root_ratio']:.2f}" if name == "alpha" else "")
            + "".join(
                f"  {e}: power {p['design']:.3f} vs 10-load {p['ten_load']:.3f}"
                for e, p in row["powers"].items()
            )
        )
    return {"base_fit_seconds": fit_seconds, "designs": rows}


def gap_study(dataset, targets: dict, budget: int = 3, log=print) -> dict:
    """Greedy, greedy + exchange and exhaustive scores on the small case."""
    from solvers.design.search import exhaustive, search

    settings = {"contacts": 3, "force_range": (0.25, 0.25), "levels": 1}
    out = {}
    for name, target in targets.items():
        chosen = plan(
            dataset, DesignSettings(target=target, budget=budget, **settings), log=lambda _: None
        )
        begin = time.perf_counter()
        found = search(chosen.pool, chosen.criterion, budget, candidates=chosen.candidates)
        fast = time.perf_counter() - begin
        begin = time.perf_counter()
        _, best = exhaustive(chosen.pool, chosen.criterion, budget, candidates=chosen.candidates)
        slow = time.perf_counter() - begin
        out[name] = {
            "candidates": len(chosen.candidates),
            "greedy": found.greedy_score,
            "exchange": found.score,
            "exhaustive": best,
            "gap": best - found.score,
            "relative_gap": (best - found.score) / max(abs(best), 1e-300),
            "search_seconds": fast,
            "exhaustive_seconds": slow,
        }
        row = out[name]
        log(
            f"  {name:28s} greedy {row['greedy']:.5g}  exchange {row['exchange']:.5g}  "
            f"exhaustive {row['exhaustive']:.5g}  gap {row['relative_gap']:.2%}  "
            f"({fast:.2f} s against {slow:.1f} s)"
        )
    return out


TARGETS = {
    "alpha": {"alpha": None},
    "heterogeneity": {"heterogeneity": 0.5},
    "base_compliance": {"base_compliance": 5.0},
    "heterogeneity+base_compliance": {"heterogeneity": 0.5, "base_compliance": 5.0},
}
"""The targets benchmarked, at the library's realistic magnitudes."""


def run(budget: int = 10, gap_budget: int = 3, log=print) -> dict:
    """Both studies; the document of ``designbench.json``."""
    dataset = bench_dataset()
    log(f"speed and quality: {budget} presses, default candidates (dvs design)")
    speed = time_designs(dataset, TARGETS, budget, log)
    slowest = max(row["seconds"] for row in speed["designs"].values())
    log(
        f"  slowest {slowest:.1f} s against the target {SPEED_TARGET_S:g} s: "
        + ("met" if slowest <= SPEED_TARGET_S else "MISSED")
    )
    log(f"gap to exhaustive search: {gap_budget} presses of 45 candidates")
    gap = gap_study(dataset, {k: TARGETS[k] for k in ("alpha", "base_compliance")}, gap_budget, log)
    return {
        "speed": speed,
        "gap": gap,
        "slowest_seconds": slowest,
        "speed_target_s": SPEED_TARGET_S,
        "budget": budget,
    }


def build_parser(prog: str = "python -m experiments.design.bench"):
    """The options of ``dvs bench design``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(
        prog, "Design search: speed, gap to exhaustive, against the 10-load design."
    )
    parser.add_argument("--budget", type=int, default=10, help="presses of the designs (1-20)")
    parser.add_argument(
        "--gap-budget", type=int, default=3, help="presses of the exhaustive case (1-3)"
    )
    parser.add_argument(
        "--out", type=path_argument, default=None, help="also write DIR/designbench.json"
    )
    return parser


def work(args) -> int:
    """``dvs bench design [--out DIR]``."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.output.atomic import atomic_write_json

    if not 1 <= args.budget <= 20:
        raise UsageError(f"--budget must lie in 1-20, got {args.budget}")
    if not 1 <= args.gap_budget <= 3:
        raise UsageError(f"--gap-budget must lie in 1-3, got {args.gap_budget}")
    out = None if args.out is None else check_output_dir(args.out)
    document = run(args.budget, args.gap_budget)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "designbench.json", document)
        print(f"wrote {out / 'designbench.json'}")
    return 0


main = Command("experiments.design.bench", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
