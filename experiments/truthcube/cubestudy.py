"""The Truth Cube study: nu, the bead errors, leave-one-state-out, and the loop.

``python -m experiments.truthcube --out DIR [--checks]`` (``main``) writes
``DIR/cubestudy.json`` (every number of docs/experiments.md, "Truth Cube"),
``DIR/diagnosis.json`` (the loop's document, schema ``dvs-diagnosis/1``) and
``DIR/report.md`` (the tables). ``--checks`` adds the discretisation checks of
``experiments.truthcube.cubechecks`` (scikit-fem comparison and nu by grid; about two
minutes more).

Per energy (linear, neo-Hookean) on the chosen grid (``CubeSettings``: 7 x 7 x 7
control points, cubic; ``cubechecks`` gives the reasons):

1. the fit of nu and the plate to all three states (``cubefit``), for a bonded plate
   (translation t per state) and a slipping one (t and the face's lateral stretch b);
2. for the slipping plate, leave one state out: nu and the other states' plates fitted
   to two states, the third predicted twice, with its plate fitted to its own beads
   (four numbers) and with its plate extrapolated from the two fitted ones
   (proportional to the nominal travel): the second is the prediction of the 18.25 %
   state from the others;
3. the loop (``cubeloop``) on the linear base (``--loop-energy neo-hookean``: the
   neo-Hookean one) with the slipping plate's fitted d, and its final model's left-out
   predictions.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.command.options import Command, check_output_dir, make_parser
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.truthcube.cubefit import (
    CubeSolver,
    extrapolated_translation,
    fit_cube,
    layer_bulge,
    predict_state,
)
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


CONTACTS = {"bonded": False, "slip": True}
"""The plate's contact: bonded (the face moves with the plate) or slipping (the face also
stretches laterally by b, ``cubemodel.plate_displacement``)."""


def leave_one_out(solver: CubeSolver, full, data: CubeData, name: str, log=print) -> list[dict]:
    """Each state predicted from the other two (module docstring, 2)."""
    folds = []
    states = list(range(data.loaded.shape[0]))
    for held in states:
        train = [k for k in states if k != held]
        fitted = fit_cube(solver, train, full.nu, full.translations)
        plate = fit_cube(solver, [held], translations0=full.translations, fixed_nu=fitted.nu)
        guessed = extrapolated_translation(fitted, data.nominal_travel, held)
        _, extrapolated = predict_state(solver, fitted.nu, guessed, held)
        folds.append(
            {
                "held_out": data.labels[held],
                "nu": fitted.nu,
                "nu_se": fitted.nu_se,
                "rms_plate_fitted_mm": plate.rms_mm[0],
                "rms_plate_extrapolated_mm": extrapolated,
                "plate_fitted": plate.translations[0].tolist(),
                "plate_extrapolated": guessed.tolist(),
            }
        )
        log(
            f"  {name}, {data.labels[held]} left out: nu {fitted.nu:.4f}, RMS "
            f"{plate.rms_mm[0]:.3f} mm (plate fitted), {extrapolated:.3f} mm (extrapolated)"
        )
    return folds


def energy_study(
    settings: CubeSettings, energy: str, contact: str, data: CubeData, folds=True, log=print
) -> dict:
    """Fit all states with one energy and plate contact, and (``folds``) leave each state
    out (module docstring, 1-2)."""
    begin = time.perf_counter()
    solver = CubeSolver(cube_model(settings, energy), data, slip=CONTACTS[contact])
    full = fit_cube(solver, nu0=0.49)
    name = f"{energy}, {contact}"
    log(f"{name}: nu {full.nu:.4f} +- {full.nu_se:.4f}, RMS {np.round(full.rms_mm, 3)} mm")
    last = data.loaded.shape[0] - 1
    seen = np.all(np.isfinite(data.loaded[last]), axis=1)
    layer = np.round(data.params[:, 2] * 8).astype(int)  # bead layers 1..7 from the base
    model_positions = data.loaded[last][seen] + full.errors[-1]
    return {
        "energy": energy,
        "contact": contact,
        "nu": full.nu,
        "nu_se": full.nu_se,
        "rms_mm": full.rms_mm,
        "plate": full.translations.tolist(),
        "plate_se": full.translation_se.tolist(),
        "bulge_measured": layer_bulge(
            data.rest[seen], data.loaded[last][seen], layer[seen]
        ).tolist(),
        "bulge_model": layer_bulge(data.rest[seen], model_positions, layer[seen]).tolist(),
        "leave_one_out": leave_one_out(solver, full, data, name, log) if folds else None,
        "seconds": time.perf_counter() - begin,
    }


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
):
    """The whole study (module docstring); writes its files when ``out`` is given.
    ``cube`` is the ``TruthCube`` to study (default: the shared data's bead file).

    ``loop_energy`` is the loop's base: "linear" (the default, within the two-minute
    budget) or "neo-hookean" (its loop alone took 107 s)."""
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
        # the bonded plate's fits show the contact; the slipping plate, which the data
        # prefer, is left out state by state and is the loop's base
        fits = [energy_study(settings, e, "bonded", data, False, log) for e in ENERGIES]
        fits += [energy_study(settings, e, "slip", data, True, log) for e in ENERGIES]
        result["fits"] = fits
        base = next(f for f in fits[2:] if f["energy"] == loop_energy)
        result["loop"], diagnosis = loop_study(settings, data, base, log)
        result["seconds"] = time.perf_counter() - begin
        if checks:
            from experiments.truthcube.cubechecks import fem_comparison, grid_study

            started = time.perf_counter()
            result["fem_comparison"] = fem_comparison(data, log)
            result["grid_study"] = grid_study(data, log=log)
            result["checks_seconds"] = time.perf_counter() - started
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
    return parser


def work(args) -> int:
    """Run the study into ``--out``."""
    check_output_dir(args.out)
    run_study(
        args.out,
        checks=args.checks,
        loop_energy=args.loop_energy,
        log=lambda line: print(line, flush=True),
    )
    return 0


main = Command("experiments.truthcube", build_parser, work).main
