"""How exact is the linearised overfitting guard? Every check of the loop, also refitted.

The loop's left-out-contact guard (``solvers.diagnosis.guard``) takes its left-out
refits as one Gauss-Newton step from the fits to every case, near zero as two, and
refits exactly only where even that improvement is too near zero. This study runs the
default diagnosis (step 0, then the loop) on FE data of two other codes, with every
check decided by the exact refits and its linearised and refined twins computed beside
it, and lists the three: the margins must exceed what the steps can miss by near zero.

The datasets: the scikit-fem slabs of ``experiments.diagnosis.continuumstudy`` (its
scenarios, seeds other than the benchmark's 1, three slab geometries: tissue reaching 5, 10 and
15 mm beyond the markers, free or clamped, and probe radii of 3-5 mm) and the Q2 tissue
patches of ``experiments.diagnosis.tissuedefaults`` (rows A-H, and row A with each injected
departure). The tables of docs/results/left-out-fits.md came
from ``python -c "from experiments.diagnosis.guardstudy import main; main()"`` (about
40 minutes on 2 cores).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

SLABS = {
    "standard": {},
    "wide_clamped": dict(lengths=(70.0, 70.0, 6.0), elements=(28, 28, 4), fix_lateral=True),
    "narrow": dict(lengths=(50.0, 50.0, 4.0), elements=(20, 20, 4)),
}
"""ReferenceSlab changes from ``ContinuumStudy().slab`` (lengths and thickness in mm)."""

SLAB_TABLE = """
compliant_base      2  standard      4
none                2  standard      4
contact_offset      2  narrow        3
stiffness_gradient  2  wide_clamped  5
tilted_force        2  standard      4
larger_probe_patch  3  narrow        4
rigid_motion        3  wide_clamped  4
compliant_base      3  wide_clamped  3
contact_offset      3  standard      5
none                3  narrow        5
stiffness_gradient  3  standard      3
tilted_force        3  wide_clamped  3
"""
SLAB_JOBS = tuple(
    (name, int(seed), slab, float(radius))
    for name, seed, slab, radius in map(str.split, SLAB_TABLE.strip().splitlines())
)
"""(scenario, noise seed, slab, probe radius [mm]) of the scikit-fem datasets."""

TISSUE_JOBS = tuple((row, None) for row in "ABCDEFGH") + tuple(
    ("A", name) for name in ("compliant_base", "contact_offset", "stiffness_gradient")
)
"""(row, injected departure or None) of the Q2 tissue datasets."""


@contextmanager
def recorded_checks(rows: list):
    """Within the block, every guard check of the loop is decided by the exact refits
    and appended to ``rows`` with its linearised and refined twins."""
    from solvers.diagnosis import guard, loop

    original = loop.prediction_check

    def exact_and_linearised(previous, new, sigma, cache=None, exact=False):
        check = original(previous, new, sigma, cache, exact=True)
        twins = {
            name: guard._check(previous, new, sigma, {}, predict, name).improvement
            for name, predict in (
                ("linearised", guard.linearised_left_out),
                ("refined", guard.refined_left_out),
            )
        }
        rows.append(
            {
                "effects": [e.name for e in new.problem.effects],
                "exact": check.improvement,
                **twins,
                "folds": len(check.held_out),
            }
        )
        return check

    loop.prediction_check = exact_and_linearised
    try:
        yield rows
    finally:
        loop.prediction_check = original


def datasets():
    """(label, dataset) of every job, made when asked for."""
    from experiments.diagnosis.continuumstudy import ContinuumStudy, scenario_dataset
    from experiments.diagnosis.tissuedefaults import row_dataset

    for scenario, seed, slab, radius in SLAB_JOBS:
        base = ContinuumStudy()
        study = replace(base, seed=seed, radius=radius, slab=replace(base.slab, **SLABS[slab]))
        label = f"{scenario} (seed {seed}, {slab}, r {radius:g} mm)"
        yield label, scenario_dataset(scenario, study)
    for row, injected in TISSUE_JOBS:
        yield f"row {row}" + (f" + {injected}" if injected else ""), row_dataset(row, injected)


def run(log=print) -> list[dict]:
    """Every check of the default diagnosis of every dataset: exact, linearised, refined."""
    from experiments.diagnosis.diagnose import diagnose_dataset

    rows: list[dict] = []
    for label, dataset in datasets():
        found: list[dict] = []
        with recorded_checks(found):
            diagnose_dataset(dataset)
        for row in found:
            row["dataset"] = label
            log(table_line(row))
        rows += found
    return rows


def table_line(row: dict) -> str:
    """One check as a line of the table."""
    return (
        f"| {row['dataset']} | {' + '.join(row['effects'])} | {row['exact']:.2f} | "
        f"{row['linearised']:.2f} | {row['refined']:.2f} |"
    )


def main() -> int:
    """Print the table, sorted by the exact improvement's size."""
    from experiments.command.process import configure

    configure()
    rows = run(log=lambda _: None)
    print("| data | effects | exact | linearised | refined |")
    print("|---|---|---|---|---|")
    for row in sorted(rows, key=lambda r: abs(r["exact"])):
        print(table_line(row))
    return 0
