"""The diagnosis study (``dvs study diagnosis``): every effect alone, over several seeds.

- ``study(seeds)`` hides each effect of the library at its realistic magnitude in
  synthetic data (and none, the negative control), runs the diagnosis and reports
  what it selected, the RMS before and after against the noise level, and the time
  (docs/results/diagnosis-phantom.md).
- ``benchmark()`` measures the cost of the score tests in forward solves.
"""

from __future__ import annotations

import time
from pathlib import Path

from experiments.command.options import (
    Command,
    UsageError,
    check_output_dir,
    check_seed,
    parse_numbers,
)
from experiments.diagnosis.diagnose import BASE_NAMES, diagnose_dataset
from experiments.output.atomic import atomic_write_json
from experiments.phantom.designs import DESIGNS, design_options
from experiments.phantom.simulate import simulate_with_effects
from symbolic.effects.library import EFFECT_NAMES, make_effect


def study(seeds=(1, 2, 3, 4), log=print, design: str = "diagnosis", names=None) -> list[dict]:
    """Every effect alone at its realistic magnitude, plus none, over several seeds.

    ``design``: "diagnosis" (``DIAGNOSIS_CONTACTS``, tilted second load) or
    "paper" (two loads at the centre). ``names``: the effects studied (default
    none and every effect; "none" is the negative control). Prints one line per
    run: selected effects, RMS before/after against the noise level (expected
    RMS of a pure-noise residual) and CPU time.
    """
    options = design_options(design)
    chosen = (None,) + EFFECT_NAMES if names is None else names
    rows = []
    for name in (None if n in (None, "none") else n for n in chosen):
        for seed in seeds:
            effects = {} if name is None else {name: make_effect(name).default_magnitude}
            begin = time.process_time()
            diagnosis = diagnose_dataset(simulate_with_effects(effects, seed=seed, **options))
            document = diagnosis.document()
            row = {
                "effect": name,
                "seed": seed,
                "selected": document["selected"],
                "first": bool(
                    document["selected"][:1] == [name] if name else not document["selected"]
                ),
                "rms_before_mm": document["rms_before_mm"],
                "rms_after_mm": document["rms_after_mm"],
                "noise_rms_mm": document["noise_rms_mm"],
                "unexplained": document["unexplained"],
                "cpu_s": time.process_time() - begin,
            }
            rows.append(row)
            log(
                f"{name or 'none':>21} seed {seed}: selected {row['selected']}, rms "
                f"{row['rms_before_mm'] * 1e3:.1f} -> {row['rms_after_mm'] * 1e3:.1f} um "
                f"(noise {row['noise_rms_mm'] * 1e3:.1f}), unexplained {row['unexplained']}, "
                f"cpu {row['cpu_s']:.1f} s"
            )
    return rows


# ---------------------------------------------------------------------- benchmark
def benchmark(effects: dict[str, float] | None = None, repeat: int = 3, log=print) -> dict:
    """Cost of the score tests in forward-solve equivalents (printed and returned).

    A forward solve is one Newton solve from rest of every load case of the
    fitted base model (for the linear base model: one Jacobian, one sparse LU
    and two residual evaluations per case), without sensitivities. Each
    candidate's score test is timed twice: the first call includes building
    its CasADi Functions (and the effect's one-off matrices), the repeats only
    the numeric work (one sensitivity evaluation and back-substitutions per
    case; a new dg/ds and its LU only for base_compliance, which adds state).
    """
    from experiments.problem.fitting import FitSettings, build_problem, dataset_loads
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit
    from solvers.diagnosis.stats import score_test
    from symbolic.effects.library import effect_library

    dataset = simulate_with_effects(effects or {}, seed=0)
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), [])
    current = fit(problem)
    sigma = float(dataset.noise_mm)
    begin = time.perf_counter()
    for _ in range(repeat):
        for position in range(len(problem.positions)):
            problem.solve_state(position, current.p)
    forward = (time.perf_counter() - begin) / repeat
    rows = {}
    for name, effect in effect_library().items():
        begin = time.perf_counter()
        score_test(current, effect, sigma)
        first = time.perf_counter() - begin
        begin = time.perf_counter()
        for _ in range(repeat):
            test = score_test(current, effect, sigma)
        numeric = (time.perf_counter() - begin) / repeat
        rows[name] = {
            "first_s": first,
            "numeric_s": numeric,
            "statistic": test.statistic,
            "forward_equivalents": numeric / forward,
            "forward_equivalents_with_build": first / forward,
        }
    log(
        f"forward solve (Newton from rest, all {len(problem.positions)} cases, fitted base "
        f"model): {forward * 1e3:.1f} ms"
    )
    log(f"{'candidate':>22} {'first call [ms]':>16} {'repeat [ms]':>12} {'forward solves':>15}")
    for name, row in rows.items():
        log(
            f"{name:>22} {row['first_s'] * 1e3:16.1f} {row['numeric_s'] * 1e3:12.1f} "
            f"{row['forward_equivalents']:15.2f}"
        )
    return {"forward_solve_s": forward, "candidates": rows}


def diagnosis_timings(log=print) -> list[dict]:
    """Wall time of ``dvs diagnose``'s loop on 10-load datasets at 9 x 9 x 2 (target 60 s).

    Two datasets of the diagnosis design: the phantom (paper's base model) and a
    scikit-fem slab (the linear-elastic base model, when scikit-fem is installed).
    Each is reported with the time of one base fit measured in the same run, so
    the ratio holds on a busy machine too.
    """
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem, dataset_loads
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit

    datasets = [
        ("phantom", "dnurbs", simulate_with_effects({}, seed=0, **design_options("diagnosis")))
    ]
    try:
        from experiments.diagnosis.continuumstudy import ContinuumStudy, scenario_dataset

        study = ContinuumStudy(grid=(9, 9, 2), degrees=(3, 3, 1))
        datasets.append(("scikit-fem slab", "linear-elastic", scenario_dataset("none", study)))
    except ImportError:
        log("scikit-fem is not installed: the continuum row is skipped")
    rows = []
    for label, energy, dataset in datasets:
        settings = base_settings(energy=energy)
        begin = time.perf_counter()
        base = build_problem(dataset, settings)
        fit(ExtendedProblem(base, dataset_loads(dataset, base.model.volume), []))
        one_fit = time.perf_counter() - begin
        begin = time.perf_counter()
        document = diagnose_dataset(dataset, base=settings).document()
        wall = time.perf_counter() - begin
        rows.append({"data": label, "energy": energy, "wall_s": wall, "base_fit_s": one_fit})
        log(
            f"diagnose, {label} ({energy}), 10 loads, 9x9x2: {wall:.1f} s (target 60 s, "
            f"{'met' if wall <= 60 else 'MISSED'}); one base fit {one_fit:.2f} s, ratio "
            f"{wall / one_fit:.0f}; selected {document['selected']}"
        )
    return rows


def build_parser(prog: str = "python -m experiments.diagnosis.study"):
    """The options of ``dvs study diagnosis``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "Every effect alone over several seeds, diagnosed.")
    parser.add_argument("--seeds", default="1,2,3,4", help="comma list of seeds (>= 0)")
    parser.add_argument("--design", choices=DESIGNS, default="diagnosis", help="where to press")
    parser.add_argument(
        "--effects", default="", help="only these (comma list, 'none' too); default every effect"
    )
    parser.add_argument("--benchmark", action="store_true", help="time the score tests instead")
    parser.add_argument("--out", type=path_argument, default=Path("study-output"), help="directory")
    return parser


def work(args) -> int:
    """``dvs study diagnosis --out DIR``: study.json (or benchmark.json with ``--benchmark``)."""
    seeds = parse_numbers(args.seeds, "--seeds", int)
    names = tuple(n.strip() for n in args.effects.split(",") if n.strip()) or None
    unknown = set(names or ()) - set(EFFECT_NAMES) - {"none"}
    if not seeds or unknown:
        raise UsageError(
            f"--seeds takes integers and --effects names from {', '.join(EFFECT_NAMES)}"
        )
    for seed in seeds:
        check_seed(seed, "--seeds")
    out = check_output_dir(args.out)
    if args.benchmark:
        document, name = benchmark(), "benchmark.json"
    else:
        document, name = (
            {"design": args.design, "runs": study(seeds, print, args.design, names)},
            "study.json",
        )
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / name, document)
    print(f"-> {out / name}")
    return 0


main = Command("experiments.diagnosis.study", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
