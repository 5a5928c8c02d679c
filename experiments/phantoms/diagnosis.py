"""``dvs diagnose`` on one recipe's compression curves (a ``dvs import compression``
dataset): the phantom study's models and rule on the dataset's own samples.

The base model is the published fits' assumption: sliding plates, uniform uniaxial
stress. The one candidate effect is the plates' hold on the ends, **bonded plates**
(the cylinder barrels: the 3D volume spline). Both are fitted to the A series
(E by linear least squares over unit-E curves, ``experiments.phantoms.study``)
and predict the B series; bonded plates are added only if they predict the B series
better than chance, on both discretisations, by more than the load cell's noise
(docs/experiments.md, "Silicone phantoms"). Writes ``diagnosis.json`` (docs/formats.md,
"diagnosis.json of a compression dataset"), ``phantom.json`` (the study's row) and
``report.md``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from experiments.command.options import UsageError
from experiments.data.dataset import Dataset
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.phantoms.study import (
    CHECK_DEGREE,
    CHECK_SHAPE,
    WINDOWS,
    data_folder,
    paired_gain,
    published_row,
    table,
    unit_curves,
    window_entry,
)

EFFECT = "bonded_plates"
"""The candidate's name: the plates hold the ends (no slip), so the cylinder barrels."""


def is_compression(dataset: Dataset) -> bool:
    """A plate pressing specimens whose force is measured (``dvs import compression``),
    with no markers inside."""
    return (
        dataset.plate_motion is not None
        and dataset.markers_rest is None
        and dataset.specimen is not None
    )


def curves_of(dataset: Dataset) -> dict:
    """The dataset's curves as arrays.

    Returns
    -------
    dict
        ``recipe``, ``radius_mm``, ``height_mm``, ``travel_mm`` (K,), ``force_n`` (S, K)
        (compressive > 0), ``series_a`` (S,) bool, ``names`` (S,), ``noise_n``.

    Raises
    ------
    UsageError
        When the specimens were not sampled at the same travels, a force is missing, or
        there is no A or no B series to fit and predict.
    """
    specimen = np.asarray(dataset.specimen)
    count = int(specimen.max()) + 1
    travel = -np.asarray(dataset.plate_motion)[specimen == 0, 2]
    force = np.full((count, len(travel)), np.nan)
    for number in range(count):
        mine = specimen == number
        if not np.allclose(-np.asarray(dataset.plate_motion)[mine, 2], travel):
            raise UsageError("every specimen must be sampled at the same plate travels")
        force[number] = -np.asarray(dataset.forces)[mine, 2]
    if not np.isfinite(force).all():
        raise UsageError("a compression dataset needs every plate force measured (no NaN)")
    names = [str(n) for n in dataset.extra.get("specimen_names", [])]
    series_a = np.array([n.startswith("A") for n in names], dtype=bool)
    if len(names) != count or series_a.all() or not series_a.any():
        raise UsageError(
            "dvs diagnose fits the A series and predicts the others: the dataset needs "
            "specimen_names with A and non-A specimens (dvs import compression writes them)"
        )
    source = str(dataset.extra.get("source", "compression"))
    rest = np.asarray(dataset.outer_rest)
    centre = rest.reshape(-1, 3).mean(axis=0)
    radius = float(np.max(np.hypot(rest[..., 0] - centre[0], rest[..., 1] - centre[1])))
    height = float(rest[..., 2].mean() - np.asarray(dataset.inner_rest)[..., 2].mean())
    return {
        "recipe": source.split()[-1],
        "radius_mm": radius,
        "height_mm": height,
        "travel_mm": travel,
        "force_n": force,
        "series_a": series_a,
        "names": names,
        "noise_n": float(dataset.force_noise_n or 0.0),
    }


def window_samples(travel: np.ndarray, height: float) -> dict:
    """Window name -> the samples within its compression (``WINDOWS``), at least two."""
    chosen = {}
    for window, (strain, _) in WINDOWS.items():
        inside = np.flatnonzero(travel <= strain * height * (1.0 + 1e-9))
        if len(inside) < 2:
            raise UsageError(
                f"the curves have {len(inside)} sample(s) within {strain:.0%} compression, "
                "the window of the E fit needs 2: import with more --samples or a "
                "smaller --strain"
            )
        chosen[window] = inside
    return chosen


def diagnosis_document(row: dict, curves: dict, seconds: float) -> dict:
    """diagnosis.json: the base (sliding plates), the contact candidate (bonded plates),
    then on a sliding final contact the energy candidates (``ENERGY_CANDIDATES``), all
    judged in the widest window; the named energy candidate that predicts the B series
    best is added."""
    entry = row[list(WINDOWS)[-1]]
    contact = "bonded" if entry["named"] == "bonded" else "sliding"
    steps = [{"model": "sliding plates (uniform stress)", **entry["sliding"]}]
    rejected, selected = [], []
    if contact == "bonded":
        steps.append({"model": "bonded plates (3D volume spline)", **entry["bonded"]})
        selected.append(EFFECT)
    else:
        reason = (
            "sliding plates predict the B series better"
            if entry["named"] == "sliding"
            else "does not predict the B series better than chance, on both "
            "discretisations, by more than the load cell's noise"
        )
        rejected.append({"effect": EFFECT, "reason": reason, "stand_in": False})
    # the energy candidates are fitted on the uniform-stress model only
    energy = entry.get("energy", {}) if contact == "sliding" else {}
    named = [n for n in energy if energy[n]["named"]]
    chosen = min(named, key=lambda n: energy[n]["b_prediction_rms_n"]) if named else None
    for name, candidate in energy.items():
        if name == chosen:
            steps.append({"model": f"sliding plates + {name}", **candidate})
            selected.append(name)
        else:
            reason = candidate["reason"] if not candidate["named"] else "another predicts better"
            rejected.append(
                {"effect": name, "reason": reason, "stand_in": "bound" in candidate["reason"]}
            )
    # E: the energy effect's small-strain E (fitted to the widest window), or the
    # contact's E in the small-strain window
    final = energy[chosen] if chosen else row[list(WINDOWS)[0]][contact]
    predicting = energy[chosen] if chosen else entry[contact]
    prediction = predicting["b_prediction_rms_n"]
    # beyond the scatter: the B specimens' squared errors exceed those of the A series'
    # mean curve by more than twice their paired standard error
    excess, spread = paired_gain(predicting["b_sse"], entry["b_scatter_sse"])
    unexplained = excess > 2.0 * spread
    return {
        "schema": "dvs-diagnosis/1",
        "experiment": "compression",
        "recipe": row["recipe"],
        "success": True,
        "observations": {
            "specimens": curves["names"],
            "fitted": [n for n, a in zip(curves["names"], curves["series_a"]) if a],
            "predicted": [n for n, a in zip(curves["names"], curves["series_a"]) if not a],
            "travel_mm": curves["travel_mm"].tolist(),
            "force_noise_n": curves["noise_n"],
            "radius_mm": curves["radius_mm"],
            "height_mm": curves["height_mm"],
        },
        "windows": {w: row[w] for w in WINDOWS},
        "steps": steps,
        "selected": selected,
        "rejected": rejected,
        "final_model": f"{contact} + {chosen}" if chosen else contact,
        "young_kpa": final["E_kPa"],
        "young_std_kpa": final["E_std_kPa"],
        "published_E_kPa": row["published_E_kPa"],
        "aic_best": row["aic_best"],
        "rms_before_n": entry["sliding"]["fit_rms_n"],
        "rms_after_n": steps[-1]["fit_rms_n"],
        "b_prediction_before_n": entry["sliding"]["b_prediction_rms_n"],
        "b_prediction_rms_n": prediction,
        "b_scatter_n": entry["b_scatter_n"],
        "model_error_n": float(np.sqrt(max(prediction**2 - entry["b_scatter_n"] ** 2, 0.0))),
        "unexplained": unexplained,
        "wall_time_s": seconds,
    }


def diagnose_compression(dataset: Dataset, out: Path, log=print) -> dict:
    """Fit the A series with both contact models, predict the B series, name the contact;
    write diagnosis.json, phantom.json and report.md into ``out``.

    Returns
    -------
    dict
        The diagnosis.json document.
    """
    begin = time.perf_counter()
    curves = curves_of(dataset)
    travel, height = curves["travel_mm"], curves["height_mm"]
    chosen = window_samples(travel, height)
    widest = np.unique(np.concatenate(list(chosen.values())))
    log(
        f"{curves['recipe']}: {len(curves['names'])} specimens x {len(travel)} samples; "
        f"unit-E curves at {len(widest)} travels to {travel[widest].max():.3g} mm"
    )
    unit = unit_curves(travel[widest], curves["radius_mm"], height)
    row = published_row(curves["recipe"], data_folder())  # AIC-best: None without the data

    def judged(check):
        entries = {}
        for window, samples in chosen.items():
            where = np.searchsorted(widest, samples)
            entries[window] = window_entry(
                travel[samples],
                curves["force_n"][:, samples],
                curves["series_a"],
                curves["noise_n"],
                tuple(c[where] for c in unit),
                None if check is None else tuple(c[where] for c in check),
                (height, curves["radius_mm"]) if window == list(chosen)[-1] else None,
            )
        return entries

    entries = judged(None)
    if any(entry["named"] != "neither" for entry in entries.values()):
        # the second discretisation can only take a named contact back: computed when needed
        log("  a contact is named: checking it on the second discretisation")
        radius = curves["radius_mm"]
        entries = judged(unit_curves(travel[widest], radius, height, CHECK_SHAPE, CHECK_DEGREE))
    for window, entry in entries.items():
        row[window] = entry
        log(f"  {window}: contact named {entry['named']}")
        for name, candidate in entry.get("energy", {}).items():
            verdict = "named" if candidate["named"] else "not named"
            log(f"  {window}: {name} {verdict} (r = {candidate['ratio']:+.4f})")
    document = diagnosis_document(row, curves, time.perf_counter() - begin)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "phantom.json", row)
    atomic_write_json(out / "diagnosis.json", document)
    atomic_write_text(out / "report.md", report(document, row))
    return document


def report(document: dict, row: dict) -> str:
    """report.md: the verdict in one paragraph and the study's table row."""
    contact, *effects = document["final_model"].split(" + ")
    model = " + ".join([f"{contact} plates", *effects])
    published = document["published_E_kPa"]
    against = f" (published {published[0]:.1f} +- {published[1]:.1f} kPa)" if published else ""
    lines = [
        f"# {document['recipe']}: compression of the A series, B series predicted",
        "",
        f"Final model: {model}; E = {document['young_kpa']:.1f} +- "
        f"{document['young_std_kpa']:.1f} kPa at small strain{against}.",
        f"B series predicted with RMS {document['b_prediction_rms_n']:.3f} N against the "
        f"A/B scatter {document['b_scatter_n']:.3f} N "
        f"({'beyond' if document['unexplained'] else 'within'} it, by the paired test).",
        "",
        table([row]),
    ]
    return "\n".join(lines)
