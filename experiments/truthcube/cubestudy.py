"""The Truth Cube study: nu, the bead errors, leave-one-state-out, and the loop.

``python -m experiments.truthcube --out DIR [--checks]`` (``main``) writes
``DIR/cubestudy.json`` (every number of docs/truthcube.md),
``DIR/diagnosis.json`` (the loop's document, schema ``dvs-diagnosis/1``) and
``DIR/report.md`` (the tables). ``--checks`` adds the discretisation checks of
``experiments.truthcube.cubechecks`` (scikit-fem comparison and nu by grid; about two
minutes more).

Per energy (linear, neo-Hookean) on the chosen grid (``CubeSettings``: 7 x 7 x 7
control points, cubic; ``cubechecks`` gives the reasons):

1. the fit of nu and the plate to all three states (``cubefit``), for a bonded plate
   (translation t per state) and a slipping one (t and the face's lateral stretch b);
2. leave one state out: nu and the other states' plates fitted to two states, the third
   predicted three times: with its plate fitted to its own beads, with its plate fitted
   to one half of its beads predicting the other half (``bead_halves``, both ways round:
   every bead predicted once, by a plate it did not fit), and with its plate
   extrapolated from the two fitted ones (proportional to the nominal travel). With the
   linear energy both contacts are left out, and the contact is **decided out of
   sample** (``cubefolds.decide_contact``): over every held-out bead of the three
   folds, the mean paired difference bonded - slip of the split prediction's squared
   distance over its standard error, z; slip is named when z > ``cubefolds.DECISION_Z``,
   else the bonded plate (fewer parameters; also when it predicts better). The
   neo-Hookean energy fits both contacts and leaves out the named one;
3. the loop (``cubeloop``) on the linear base (``--loop-energy neo-hookean``: the
   neo-Hookean one) with the named contact's fitted d, and its final model's left-out
   predictions.

``--twins`` adds the same decision on the scikit-fem twins of ``cubetwin``.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.command.options import Command, check_output_dir, make_parser
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.truthcube.cubefolds import CONTACTS, contact_study, energy_study
from experiments.truthcube.cubeloop import final_left_out, run_loop, step_table
from experiments.truthcube.cubemodel import (
    CubeData,
    CubeSettings,
    cube_model,
    lattice_scatter,
    load_truth_cube,
)
from solvers.linalg.blas import one_thread

ENERGIES = ("linear", "neo-hookean")
"""The energies compared (``cubemodel.ENERGY_MODELS``)."""


def noise_record(cube) -> dict:
    """The bead-location noise from the rest lattice: scatter about an affine and a
    quadratic map of the bead index, per component [mm], and the quadratic one's RMS
    bead distance (sqrt of the sum of squares) [mm]."""
    affine = lattice_scatter(cube.index, cube.rest, order=1)
    quadratic = lattice_scatter(cube.index, cube.rest, order=2)
    return {
        "affine_mm": affine.tolist(),
        "quadratic_mm": quadratic.tolist(),
        "rms_distance_mm": float(np.sqrt(np.sum(quadratic**2))),
    }


DECISION_ENERGY = "linear"
"""The energy whose left-out predictions name the plate's contact (``contact_study``;
the other energy's folds would break the two-minute budget)."""


def loop_study(settings: CubeSettings, data: CubeData, base: dict, log=print):
    """The loop on the energy and plate of ``base`` (a fit's record; module docstring,
    3): its steps, its final model's left-out RMS per state, the ``Diagnosis``."""
    begin = time.perf_counter()
    model = cube_model(settings, base["energy"], base["nu"])
    diagnosis = run_loop(model, data, np.asarray(base["plate"]), base["nu"], log=log)
    record = {
        "energy": base["energy"],
        "contact": base["contact"],
        "steps": step_table(diagnosis),
        "selected": [s.effect for s in diagnosis.steps[1:]],
        "sigma_mm": diagnosis.noise_mm,
        "sigma_source": diagnosis.noise_source,
        "final_left_out_rms_mm": final_left_out(diagnosis),
    }
    record["seconds"] = time.perf_counter() - begin
    return record, diagnosis


def run_study(
    out: Path | None = None,
    settings: CubeSettings | None = None,
    checks: bool = False,
    loop_energy: str = "linear",
    log=print,
    cube=None,
    twins: bool = False,
):
    """The whole study (module docstring); writes its files when ``out`` is given.
    ``cube`` is the ``TruthCube`` to study (default: the shared data's bead file).

    ``loop_energy`` is the loop's base: "linear" (the default, within the two-minute
    budget) or "neo-hookean" (its loop alone took 107 s). ``twins`` adds the contact
    decision on the synthetic twins (``experiments.truthcube.cubetwin``, about 40 s)."""
    begin = time.perf_counter()
    settings = settings or CubeSettings((7, 7, 7), 3, 12)
    cube = load_truth_cube() if cube is None else cube
    data = CubeData.of(cube)
    result = {
        "settings": asdict(settings),
        "cube_origin_file_mm": data.frame.origin.tolist(),
        "noise": noise_record(cube),
        "nominal_travel_mm": data.nominal_travel.tolist(),
        "states": data.labels,
    }
    with one_thread():
        # both contacts left out state by state with the linear energy name the contact;
        # the neo-Hookean energy fits both and leaves out the named one (the budget)
        fits, decision = contact_study(settings, DECISION_ENERGY, data, log)
        for energy in ENERGIES:
            if energy != DECISION_ENERGY:
                for contact in CONTACTS:
                    folds = contact == decision["named"]
                    fits.append(energy_study(settings, energy, contact, data, folds, log))
                    fits[-1].pop("squared")
        result["fits"] = fits
        result["contact"] = decision
        named = decision["named"]
        base = next(f for f in fits if f["energy"] == loop_energy and f["contact"] == named)
        result["loop"], diagnosis = loop_study(settings, data, base, log)
        result["seconds"] = time.perf_counter() - begin
        if checks:
            from experiments.truthcube.cubechecks import fem_comparison, grid_study

            started = time.perf_counter()
            result["fem_comparison"] = fem_comparison(data, log)
            result["grid_study"] = grid_study(data, log=log)
            result["checks_seconds"] = time.perf_counter() - started
        if twins:
            from experiments.truthcube.cubetwin import twin_study

            started = time.perf_counter()
            result["twins"] = twin_study(cube, settings, log=log)
            result["twins_seconds"] = time.perf_counter() - started
    if out is not None:
        from experiments.truthcube.cubereport import report_text

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "cubestudy.json", result)
        atomic_write_json(out / "diagnosis.json", diagnosis.document())
        atomic_write_text(out / "report.md", report_text(result))
    log(f"study: {result['seconds']:.0f} s")
    result["diagnosis"] = diagnosis.document()
    return result


def build_parser(prog: str = "python -m experiments.truthcube"):
    """The options of ``dvs study truth-cube``."""
    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--loop-energy",
        choices=ENERGIES,
        default="linear",
        help="the loop's base energy (neo-hookean: about two minutes more)",
    )
    parser.add_argument(
        "--checks", action="store_true", help="also the scikit-fem comparison and nu by grid"
    )
    parser.add_argument(
        "--twins",
        action="store_true",
        help="also the contact decision on the scikit-fem twins (bonded, frictionless plate)",
    )
    return parser


def work(args) -> int:
    """Run the study into ``--out``."""
    check_output_dir(args.out)
    run_study(
        args.out,
        checks=args.checks,
        twins=args.twins,
        loop_energy=args.loop_energy,
        log=lambda line: print(line, flush=True),
    )
    return 0


main = Command("experiments.truthcube", build_parser, work).main
