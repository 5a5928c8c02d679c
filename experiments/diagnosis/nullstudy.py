"""The false-discovery study on null FE data: default ``dvs diagnose`` where no effect is.

Every dataset of ``NULL_JOBS`` comes from one of the two scikit-fem generators with no
departure injected: the Q2 hexahedra patches of ``experiments.phantom.tissue`` and the
P2 tetrahedra slabs of ``experiments.phantom.fe``. They vary the tissue beyond the
markers and its support, curvature, thickness, nu, marker grid, design (2, 8 or 10
loads) and the probe's shape and radius (never declared). Each is diagnosed with the
defaults (step 0, then the loop) in a fresh process. A row is a false discovery
(``false_discovery``) when the loop selected any effect but the set-up terms
(``SETUP_TERMS``), the surroundings and the probe patch that step 0 estimates too.
``python -c "from experiments.diagnosis.nullstudy import main; main()"`` prints one
markdown line per dataset as it finishes, then the counts.
"""

from __future__ import annotations

import tempfile
from collections import Counter
from dataclasses import replace
from pathlib import Path

SETUP_TERMS = ("surrounding_tissue", "contact_patch")
"""Effects that describe the surroundings and the probe patch, not a finding."""

NULL_TABLE = """
name gen    marked beyond support radii  thick nu   markers design    probe   r seed
T01  tissue  40x40       2 clamped flat       6 0.49 9x9     diagnosis gauss 4.0  101
T02  tissue  40x30       3 springs 60x90      5 0.46 11x8    corners   disc  2.0  102
T03  tissue  40x40       4 free    flat       4 0.42 7x10    diagnosis disc  3.0  103
T04  tissue  40x30       5 clamped 80x80      7 0.45 13x6    paper     gauss 3.0  104
T05  tissue  40x40       6 springs flat       8 0.48 9x9     diagnosis disc  5.0  105
T06  tissue  40x30       8 free    70x-       5 0.40 11x8    diagnosis disc  1.5  106
T07  tissue  40x30      10 clamped flat       6 0.47 10x7    corners   gauss 2.5  107
T08  tissue  40x30      12 springs 100x70     4 0.44 8x11    paper     disc  3.5  108
T09  tissue  40x30      15 free    flat       7 0.49 11x8    diagnosis gauss 4.5  109
T10  tissue  40x40      20 clamped 90x90      6 0.41 9x9     corners   disc  2.5  110
T11  tissue  40x30      20 free    flat       5 0.45 12x9    diagnosis disc  3.0  111
T12  tissue  40x30       7 clamped -x60       8 0.43 7x10    diagnosis gauss 2.0  112
T13  tissue  40x30       3 free    flat       4 0.48 13x6    corners   disc  4.0  113
T14  tissue  40x30       9 springs 60x60      6 0.40 10x7    diagnosis gauss 1.5  114
T15  tissue  40x30       5 clamped 120x80     5 0.46 8x6     paper     disc  2.0  115
T16  tissue  40x30      15 springs flat       8 0.42 11x8    diagnosis disc  2.0  116
S01  slab   40x40       2 clamped flat       5 0.45 9x9     diagnosis gauss 3.0  201
S02  slab   40x30       4 free    flat       6 0.49 11x8    paper     gauss 2.0  202
S03  slab   40x30       5 clamped flat       4 0.40 7x10    corners   gauss 4.5  203
S04  slab   40x30       6 free    flat       8 0.47 13x6    diagnosis gauss 1.5  204
S05  slab   40x30       8 clamped flat       7 0.43 10x7    diagnosis gauss 5.0  205
S06  slab   40x40      10 free    flat       5 0.46 9x9     corners   gauss 2.5  206
S07  slab   40x30      10 clamped flat       6 0.41 8x11    paper     gauss 3.5  207
S08  slab   40x30      12 free    flat       4 0.48 11x8    diagnosis gauss 4.0  208
S09  slab   40x30      15 clamped flat       8 0.44 12x9    corners   gauss 2.0  209
S10  slab   40x40      20 free    flat       6 0.45 9x9     diagnosis gauss 3.0  210
S11  slab   40x30      20 clamped flat       5 0.49 7x10    paper     gauss 1.5  211
S12  slab   40x30       3 free    flat       7 0.42 10x7    diagnosis gauss 3.5  212
S13  slab   40x30       7 clamped flat       4 0.47 13x6    corners   gauss 2.5  213
S14  slab   40x30      14 free    flat       5 0.40 11x8    corners   gauss 5.0  214
S15  slab   40x30       2 free    flat       6 0.46 8x6     diagnosis gauss 4.5  215
S16  slab   40x40      18 clamped flat       7 0.48 9x9     diagnosis gauss 2.0  216
"""
"""One null dataset a line: name, generator, marked area [mm], tissue beyond the markers
[mm], lateral support, skin radii R_x x R_y [mm] ("-" flat that way), thickness [mm],
nu, markers U x V, design, probe, probe radius [mm] (never declared), noise seed. E =
20 kPa, forces 0.17 and 0.25 N, 0.02 mm noise; cells of 2.5 mm over the marked area, 4
through the thickness (the slab's uniform, the patch's graded x1.5 beyond). The slab
generator is flat and Gaussian only, and holds its sides free or clamped (no springs)."""

COLUMNS, *_ROWS = map(str.split, NULL_TABLE.strip().splitlines())
NULL_JOBS = {fields[0]: dict(zip(COLUMNS, fields)) for fields in _ROWS}
"""name -> the table's fields (strings) of each null dataset."""

LOADS = {"paper": 2, "corners": 8, "diagnosis": 10}
GENERATORS = {"tissue": "Q2 hex (tissue.py)", "slab": "P2 tet (fe.py)"}


def _pair(text: str, kind=float) -> tuple:
    """``40x30`` -> (40.0, 30.0); ``-`` -> None."""
    return tuple(None if part == "-" else kind(part) for part in text.split("x"))


def null_dataset(name: str):
    """The dataset of a job of ``NULL_JOBS``: no departure, the probe radius not declared.

    Parameters
    ----------
    name : str
        A key of ``NULL_JOBS``.

    Returns
    -------
    Dataset
        Marker positions [mm] at rest and under each load, forces [N], contacts [mm],
        ``noise_mm`` 0.02 and ``probe_radius`` None.
    """
    from experiments.phantom.fe import ReferenceSlab, SlabSolution, reference_dataset
    from experiments.phantom.simulate import SimulationSettings
    from experiments.phantom.tissue import TissuePatch, tissue_cases, tissue_dataset

    job = NULL_JOBS[name]
    marked, markers = _pair(job["marked"]), _pair(job["markers"], int)
    extent, thickness, radius = (float(job[k]) for k in ("beyond", "thick", "r"))
    measurement = SimulationSettings(noise_mm=0.02, seed=int(job["seed"]))
    if job["gen"] == "tissue":
        curvature = (None, None) if job["radii"] == "flat" else _pair(job["radii"])
        support = "elastic" if job["support"] == "springs" else job["support"]
        patch = TissuePatch(
            marked=marked,
            extent_mm=extent,
            thickness=thickness,
            support=support,
            curvature_radii=curvature,
            poisson=float(job["nu"]),
            layers=4,
        )
        forces, contacts = tissue_cases(job["design"], patch)
        return tissue_dataset(
            patch, forces, contacts, radius, markers, job["probe"], measurement=measurement
        )
    if job["probe"] != "gauss" or job["radii"] != "flat" or job["support"] == "springs":
        raise ValueError(f"{name}: the slab is flat, Gaussian-probed, free or clamped")
    lengths = tuple(m + 2 * extent for m in marked)
    slab = ReferenceSlab(
        lengths=(*lengths, thickness),
        marked=marked,
        poisson=float(job["nu"]),
        elements=(*(round(n / 2.5) for n in lengths), 4),
        fix_lateral=job["support"] == "clamped",
    )
    forces, contacts = tissue_cases(job["design"], slab)
    dataset = reference_dataset(
        slab, forces, contacts, radius, markers, measurement, None, SlabSolution(slab)
    )
    return replace(dataset, probe_radius=None)


def varies(name: str) -> str:
    """What the dataset is, in a few words."""
    job = NULL_JOBS[name]
    shape = "flat" if job["radii"] == "flat" else f"R {job['radii']}"
    return (
        f"+{job['beyond']} mm {job['support']}, {shape}, {job['thick']} mm, nu {job['nu']}, "
        f"{job['markers']}, {LOADS[job['design']]} loads, {job['probe']} r {job['r']}"
    )


def configured_diagnosis(path: str) -> dict:
    """``timed_default_diagnosis`` in a process set up as the ``dvs`` command sets its own
    (``experiments.command.process.configure``: numpy's BLAS on one thread)."""
    from experiments.command.process import configure
    from experiments.diagnosis.tissuedefaults import timed_default_diagnosis

    configure()
    return timed_default_diagnosis(path)


def run_study(names=None, log=print) -> list[dict]:
    """Default ``dvs diagnose`` of each null dataset, each in a fresh process, one at a time.

    Parameters
    ----------
    names : iterable of str, optional
        Keys of ``NULL_JOBS`` (default all, in the table's order).
    log : callable
        Gets each row's table line (``table_line``) as it finishes.

    Returns
    -------
    list of dict
        ``timed_default_diagnosis``'s rows (times [s], peak memory [MB], RMS [um]) with
        the ``dataset`` name, its ``generator`` and what ``varies``.
    """
    from experiments.command.isolation import isolated
    from experiments.data.dataset import save_dataset

    rows = []
    for name in names or NULL_JOBS:
        with tempfile.TemporaryDirectory() as folder:
            path = str(Path(folder) / f"{name}.npz")
            save_dataset(path, null_dataset(name))
            row = isolated(configured_diagnosis, path)
        row.update(dataset=name, generator=NULL_JOBS[name]["gen"], varies=varies(name))
        rows.append(row)
        log(table_line(row))
    return rows


def false_discovery(row: dict) -> bool:
    """True when the row selected any effect but the set-up terms (``SETUP_TERMS``)."""
    return any(effect not in SETUP_TERMS for effect in row["selected"])


def presented(row: dict) -> bool:
    """True when a false discovery is the verdict's explanation: explained, and the base
    model alone not consistent with noise (``solvers.diagnosis.report.presents_as_cause``;
    rows without that record: explained)."""
    return false_discovery(row) and row.get("presented_as_cause", not row["unexplained"])


def base_label(row: dict) -> str:
    """Step 0's choice: the energy, and for the continuum its band, probe and grid."""
    if row["base"] == "dnurbs":
        return "paper's energy"
    s = row["surroundings"]
    radius = s["probe_radius_mm"]
    probe = "declared" if radius is None else f"r {radius:.2f}"
    text = (
        f"{s['margin_mm']:g} mm {s['support']}, {s['probe_shape']} {probe}, "
        f"{'x'.join(map(str, row['grid']))} ({', '.join(row['resolution'])})"
    )
    return text + "".join(f"; -> {r}" for r in row.get("revisits", []))


HEADER = (
    "| dataset | generator | what varies | step 0 base | selected | verdict "
    "| RMS before -> after [um] | time [s] (step 0) | peak [MB] |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def table_line(row: dict) -> str:
    """One markdown line; a false discovery's selection in bold."""
    from experiments.output.tables import with_rivals

    selected = with_rivals(row["selected"], row["rivals"])
    if false_discovery(row):
        selected = f"**{selected}**"
    verdict = "unexplained" if row["unexplained"] else "explained"
    return (
        f"| {row['dataset']} | {GENERATORS[row['generator']]} | {row['varies']} "
        f"| {base_label(row)} | {selected} | {verdict} "
        f"| {row['rms_before_um']:.1f} -> {row['rms_after_um']:.1f} "
        f"| {row['wall_s']:.0f} ({row['step0_s']:.0f}) | {row['peak_mb']:.0f} |"
    )


def print_table(rows: list[dict]) -> None:
    """Print the rows as a markdown table (``HEADER``, then ``table_line`` of each)."""
    print("\n".join([HEADER, *map(table_line, rows)]), flush=True)


def counts(rows: list[dict]) -> str:
    """False discoveries, those presented as the explanation, their effects, and time."""
    found = [row for row in rows if false_discovery(row)]
    effects = Counter(e for row in found for e in row["selected"] if e not in SETUP_TERMS)
    wall = [row["wall_s"] for row in rows]
    return (
        f"{len(found)} of {len(rows)} datasets named a non-set-up effect "
        f"({', '.join(f'{e} x{n}' for e, n in effects.most_common()) or 'none'}); "
        f"{sum(map(presented, rows))} presented one as the explanation; "
        f"{sum(row['unexplained'] for row in rows)} ended unexplained. "
        f"Time {sum(wall):.0f} s in all, {min(wall):.0f}-{max(wall):.0f} s per dataset."
    )


def main(names=None) -> list[dict]:
    """Run the study, printing each row as it finishes, then the counts; the rows."""
    print(HEADER, flush=True)
    rows = run_study(names, log=lambda line: print(line, flush=True))
    print("\n" + counts(rows), flush=True)
    return rows
