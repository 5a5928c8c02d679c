"""The Truth Cube's fits by contact, their leave-one-state-out folds, and the contact
they name (docs/truthcube.md, "Results": "How the contact is decided").

``energy_study`` fits nu and the plate to all states with one energy and one plate
contact (``cubefit``) and leaves each state out: nu and the other states' plates fitted
to two states, the third predicted with its plate fitted to its own beads, with its
plate fitted to one half of its beads predicting the other half (``bead_halves``,
``split_prediction``: every bead predicted once by a plate it did not fit), and with its
plate extrapolated from the fitted ones. ``contact_study`` does so for both contacts and
``decide_contact`` names the one whose split predictions are better by more than chance
allows (the bonded plate, with fewer parameters, otherwise). Used by the study
(``cubestudy``) and the synthetic twins (``cubetwin``).
"""

from __future__ import annotations

import time

import numpy as np

from experiments.truthcube.cubefit import (
    CubeSolver,
    extrapolated_translation,
    fit_cube,
    layer_bulge,
    predict_state,
)
from experiments.truthcube.cubemodel import CubeData, CubeSettings, cube_model

CONTACTS = {"bonded": False, "slip": True}
"""The plate's contact: bonded (the face moves with the plate) or slipping (the face also
stretches laterally by b, ``cubemodel.plate_displacement``)."""


DECISION_Z = 2.0
"""A contact is named over the other when its left-out squared bead distance is smaller
by more than this many standard errors of the mean paired difference (``decide_contact``);
otherwise the bonded plate, which has fewer parameters, is named."""


def bead_halves(data: CubeData) -> np.ndarray:
    """(N,) bool: the beads whose lattice index i + j + k is even (a checkerboard: each
    half fills the whole cube, every bead's neighbours are in the other half)."""
    index = np.round(data.params * 8).astype(int)  # beads 1 cm apart, 1 cm inside the faces
    return index.sum(axis=1) % 2 == 0


def split_prediction(solver: CubeSolver, nu: float, plates, held: int, halves) -> np.ndarray:
    """Squared distances [mm^2] of a held-out state's beads, predicted at ``nu`` with the
    state's plate fitted to the other half of its beads (``bead_halves``), (N,) (NaN:
    not located). ``plates`` (S, width) are the start plate parameters."""
    loaded = solver.data.loaded[held]
    seen = np.all(np.isfinite(loaded), axis=1)
    squared = np.full(loaded.shape[0], np.nan)
    for half in (halves, ~halves):
        plate = fit_cube(solver, [held], translations0=plates, fixed_nu=nu, beads=half)
        solution = solver.equilibrium(nu, plate.translations[0], key=held)
        scored = seen & ~half
        squared[scored] = np.sum((solver.positions(solution) - loaded)[scored] ** 2, axis=1)
    return squared


def leave_one_out(
    solver: CubeSolver, full, data: CubeData, name: str, split: bool = True, log=print
):
    """Each state predicted from the other two (module docstring, 2): the folds' records
    and (``split``) the held-out beads' squared distances of the split prediction (S, N)
    [mm^2], else None."""
    folds, squared = [], []
    states = list(range(data.loaded.shape[0]))
    halves = bead_halves(data)
    for held in states:
        train = [k for k in states if k != held]
        fitted = fit_cube(solver, train, full.nu, full.translations)
        plate = fit_cube(solver, [held], translations0=full.translations, fixed_nu=fitted.nu)
        guessed = extrapolated_translation(fitted, data.nominal_travel, held)
        _, extrapolated = predict_state(solver, fitted.nu, guessed, held)
        split_rms = None
        if split:
            start = np.array(full.translations)
            start[held] = plate.translations[0]
            squared.append(split_prediction(solver, fitted.nu, start, held, halves))
            split_rms = float(np.sqrt(np.nanmean(squared[-1])))
        folds.append(
            {
                "held_out": data.labels[held],
                "nu": fitted.nu,
                "nu_se": fitted.nu_se,
                "rms_plate_fitted_mm": plate.rms_mm[0],
                "rms_plate_split_mm": split_rms,
                "rms_plate_extrapolated_mm": extrapolated,
                "plate_fitted": plate.translations[0].tolist(),
                "plate_extrapolated": guessed.tolist(),
            }
        )
        halved = "" if split_rms is None else f", {split_rms:.3f} mm (plate from other half)"
        log(
            f"  {name}, {data.labels[held]} left out: nu {fitted.nu:.4f}, RMS "
            f"{plate.rms_mm[0]:.3f} mm (plate fitted){halved}, {extrapolated:.3f} mm "
            "(extrapolated)"
        )
    return folds, (np.array(squared) if split else None)


def decide_contact(squared: dict, labels: list) -> dict:
    """The plate's contact named by the left-out predictions (module docstring, 2).

    Parameters
    ----------
    squared : dict
        Per contact ("bonded", "slip"), the held-out beads' squared distances (S, N)
        [mm^2] of ``leave_one_out``.
    labels : list of str
        The states.

    Returns
    -------
    dict
        ``named`` (the contact), ``distinguished`` (the difference exceeds chance),
        ``z`` (the mean paired difference bonded - slip of the beads' squared distances
        over its standard error), the difference and its standard error [mm^2], and
        per contact the left-out RMS bead distance of every state and over all [mm].
    """
    bonded, slip = np.asarray(squared["bonded"]), np.asarray(squared["slip"])
    both = np.isfinite(bonded) & np.isfinite(slip)
    difference = (bonded - slip)[both]
    mean = float(difference.mean())
    se = float(difference.std(ddof=1) / np.sqrt(difference.size))
    z = mean / se if se > 0 else 0.0
    distinguished = abs(z) > DECISION_Z
    named = "slip" if distinguished and z > 0 else "bonded"
    rms_left_out = {
        contact: {
            "states_mm": [float(np.sqrt(np.mean(v[k][both[k]]))) for k in range(len(labels))],
            "all_mm": float(np.sqrt(np.mean(v[both]))),
        }
        for contact, v in (("bonded", bonded), ("slip", slip))
    }
    return {
        "named": named,
        "distinguished": bool(distinguished),
        "z": z,
        "difference_mm2": mean,
        "difference_se_mm2": se,
        "beads": int(difference.size),
        "left_out_rms": rms_left_out,
    }


def energy_study(
    settings: CubeSettings,
    energy: str,
    contact: str,
    data: CubeData,
    folds=True,
    log=print,
    split: bool = False,
) -> dict:
    """Fit all states with one energy and plate contact, and (``folds``) leave each state
    out (module docstring, 1-2); with ``split`` too the record's ``"squared"`` holds the
    split prediction's squared distances (``leave_one_out``; else None), which the caller
    takes out."""
    begin = time.perf_counter()
    solver = CubeSolver(cube_model(settings, energy), data, slip=CONTACTS[contact])
    full = fit_cube(solver, nu0=0.49)
    name = f"{energy}, {contact}"
    log(f"{name}: nu {full.nu:.4f} +- {full.nu_se:.4f}, RMS {np.round(full.rms_mm, 3)} mm")
    last = data.loaded.shape[0] - 1
    seen = np.all(np.isfinite(data.loaded[last]), axis=1)
    layer = np.round(data.params[:, 2] * 8).astype(int)  # bead layers 1..7 from the base
    model_positions = data.loaded[last][seen] + full.errors[-1]
    left_out, squared = (
        leave_one_out(solver, full, data, name, split, log) if folds else (None, None)
    )
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
        "leave_one_out": left_out,
        "squared": squared,
        "seconds": time.perf_counter() - begin,
    }


def contact_study(settings: CubeSettings, energy: str, data: CubeData, log=print):
    """Both plate contacts fitted and left out state by state with one energy, and the
    contact they name (``decide_contact``): the two fits' records and the decision."""
    fits = [energy_study(settings, energy, c, data, True, log, split=True) for c in CONTACTS]
    decision = decide_contact({f["contact"]: f.pop("squared") for f in fits}, data.labels)
    decision["energy"] = energy
    rms_text = ", ".join(f"{c} {decision['left_out_rms'][c]['all_mm']:.3f} mm" for c in CONTACTS)
    log(f"{energy}: left-out RMS {rms_text} (z {decision['z']:.1f}): {decision['named']}")
    return fits, decision
