"""Detection limits: how large must each effect be before the diagnosis meets its criteria?

The acceptance criteria of the diagnosis (docs/diagnosis.md) are, for one
undeclared effect in synthetic data with noise 0.02 mm:

1. the diagnosis selects that effect first;
2. the RMS after is within 20 % of the noise level;
3. the RMS before is at least twice the RMS after.

At the effects' realistic magnitudes (``Effect.default_magnitude``) criterion 3
holds only for the measurement effects (docs/results/diagnosis-phantom.md). This study multiplies
each magnitude by growing factors, on the same design, seed and noise, and
reports the smallest factor at which every criterion holds. A factor is tried
only while the true parameters stay inside the effect's own bounds (the range
over which the fit may move them), so no effect is pushed past what its
parametrisation admits.

Run ``python -m experiments.diagnosis.detection`` (about 15-25 min CPU for every effect;
``--effects a,b`` for some, ``--seed``, ``--design paper``).
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
from experiments.diagnosis.diagnose import diagnose_dataset
from experiments.output.atomic import atomic_write_json
from experiments.phantom.designs import DESIGNS, design_options
from experiments.phantom.simulate import simulate_with_effects
from symbolic.effects.library import EFFECT_NAMES, make_effect

FACTORS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
"""Multiples of the realistic magnitude tried, smallest first."""

AFTER_TOLERANCE = 0.2
"""Criterion 2: |RMS after / noise level - 1| <= 0.2."""

BEFORE_RATIO = 2.0
"""Criterion 3: RMS before >= 2 x RMS after."""


def admissible(name: str, factor: float) -> bool:
    """True while factor x the realistic magnitude stays inside the effect's bounds."""
    effect = make_effect(name)
    low, high = effect.magnitude_range(1)
    return bool(low <= factor * effect.default_magnitude <= high)


def criteria(document: dict, name: str) -> dict:
    """The three acceptance criteria of one diagnosis document (diagnosis.json)."""
    before, after = document["rms_before_mm"], document["rms_after_mm"]
    noise = document["noise_rms_mm"]
    return {
        "first": document["selected"][:1] == [name],
        "after_near_noise": abs(after / noise - 1.0) <= AFTER_TOLERANCE,
        "before_twice_after": before >= BEFORE_RATIO * after,
    }


def detection_limit(
    name: str, seed: int = 1, design: str = "diagnosis", factors=FACTORS, log=print
) -> dict:
    """Diagnose growing multiples of one effect until every criterion holds.

    Returns
    -------
    dict
        ``effect``, ``runs`` (factor, magnitude, selected, RMS before/after [mm],
        noise level [mm], criteria, CPU [s]) and ``limit``: the smallest factor
        at which every criterion held, or None if none did within the bounds.
    """
    options = design_options(design)
    magnitude0 = make_effect(name).default_magnitude
    runs, limit = [], None
    for factor in factors:
        if not admissible(name, factor):
            log(f"{name:>21} x{factor:<4g} outside the effect's bounds: stop")
            break
        begin = time.process_time()
        dataset = simulate_with_effects({name: factor * magnitude0}, seed=seed, **options)
        document = diagnose_dataset(dataset).document()
        met = criteria(document, name)
        run = {
            "factor": factor,
            "magnitude": factor * magnitude0,
            "selected": document["selected"],
            "rms_before_mm": document["rms_before_mm"],
            "rms_after_mm": document["rms_after_mm"],
            "noise_rms_mm": document["noise_rms_mm"],
            "criteria": met,
            "cpu_s": time.process_time() - begin,
        }
        runs.append(run)
        log(
            f"{name:>21} x{factor:<4g} ({run['magnitude']:.4g}): selected {run['selected']}, "
            f"rms {run['rms_before_mm'] * 1e3:.1f} -> {run['rms_after_mm'] * 1e3:.1f} um "
            f"(noise {run['noise_rms_mm'] * 1e3:.1f}), "
            + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in met.items())
            + f", cpu {run['cpu_s']:.1f} s"
        )
        if all(met.values()):
            limit = factor
            break
    return {"effect": name, "runs": runs, "limit": limit}


def print_table(results: list[dict], log=print) -> None:
    """One markdown row per effect: the limit and the figures at it (or at the last try)."""
    log(
        "| effect | realistic magnitude | smallest factor meeting all three | "
        "RMS before -> after [um] at it | noise level [um] |"
    )
    log("|---|---|---|---|---|")
    for result in results:
        effect = make_effect(result["effect"])
        last = result["runs"][-1] if result["runs"] else None
        limit = result["limit"]
        figures = (
            f"{last['rms_before_mm'] * 1e3:.1f} -> {last['rms_after_mm'] * 1e3:.1f}"
            if last
            else "-"
        )
        noise = f"{last['noise_rms_mm'] * 1e3:.1f}" if last else "-"
        reached = (
            f"x{limit:g}"
            if limit is not None
            else f"none up to x{last['factor']:g} (bounds)"
            if last
            else "-"
        )
        log(
            f"| {effect.name} | {effect.default_magnitude:g} {effect.magnitude_unit} | "
            f"{reached} | {figures} | {noise} |"
        )


def build_parser(prog: str = "python -m experiments.diagnosis.detection"):
    """The options of ``dvs study detection``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--effects", default="", help="comma list; default every effect")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the data (>= 0)")
    parser.add_argument("--design", choices=DESIGNS, default="diagnosis", help="where to press")
    parser.add_argument(
        "--factors", default=",".join(f"{f:g}" for f in FACTORS), help="multiples, e.g. 1,2,4"
    )
    parser.add_argument(
        "--out", type=path_argument, default=Path("detection-output"), help="directory"
    )
    return parser


def work(args) -> int:
    """``dvs study detection [--effects a,b] [--factors 1,2,4] --out DIR``: detection.json."""
    factors = tuple(sorted(parse_numbers(args.factors, "--factors")))
    if not factors or min(factors) <= 0 or max(factors) > 100:
        raise UsageError("--factors takes numbers in (0, 100], e.g. 1,2,4")
    names = tuple(n.strip() for n in args.effects.split(",") if n.strip()) or EFFECT_NAMES
    unknown = sorted(set(names) - set(EFFECT_NAMES))
    if unknown:
        raise UsageError(f"--effects: unknown {unknown}; choose from {', '.join(EFFECT_NAMES)}")
    check_seed(args.seed)
    out = check_output_dir(args.out)
    results = [detection_limit(n, args.seed, args.design, factors) for n in names]
    print_table(results)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "detection.json", {"design": args.design, "effects": results})
    print(f"-> {out / 'detection.json'}")
    return 0


main = Command("experiments.diagnosis.detection", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
