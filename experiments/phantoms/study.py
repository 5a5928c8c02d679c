"""The silicone phantoms: E of every recipe from its A series, the B series predicted.

For each recipe folder of ``phantom-compression`` (docs/experiments.md, "Silicone
phantoms"), the tests are imported (``experiments.data.compression``) and two models of
the same neo-Hookean energy are fitted to the A series (specimens A1-A5):

- sliding plates, uniform stress (the published fits' assumption);
- bonded plates, the 3D volume spline (the cylinder barrels).

With the plate's motion prescribed and nu fixed, every force of either model is E times
the force at E = 1 kPa (the equilibrium of a displacement-driven body does not depend
on the scale of its energy), so each fit is linear least squares in E over the
unit-E curves, computed once for all recipes (the 3D ones by the shared solver:
``solvers.diagnosis.extended``). Two windows: compression up to 10 % of the height
(small strain: E to compare with the published E) and up to 30 % (the curve).

The selection rule is the loop's (docs/diagnosis.md): the contact model that predicts
the **B series**, data it was not fitted on, better is the one named, if it does so
better than chance (``named_contact``), on both discretisations (``CHECK_SHAPE``), and by
more than the load cell's noise in one sample (``force_noise_n``). The B series'
scatter about the A series' mean curve is what no model of the A series can beat.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from experiments.command.options import Command, check_output_dir, make_parser
from experiments.data.compression import compression_dataset, read_recipe
from experiments.data.paths import shared_data_dir
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.phantoms.cylinder import cylinder_model, plate_forces, uniform_force

WINDOWS = {"small strain": (0.10, 8), "curve": (0.30, 10)}
"""Name -> (largest compression / height, samples per test)."""
PUBLISHED_E_KPA = {
    "EF10_0T": (56.27, 2.12),
    "EF10_12_5T": (38.06, 1.28),
    "EF10_25T": (28.16, 0.79),
    "EF10_37_5T": (20.14, 0.83),
    "EF10_50T": (16.29, 0.40),
    "EF10_62_5T": (12.94, 0.52),
    "EF10_75T": (9.58, 0.12),
    "EF10_87_5T": (8.68, 0.26),
    "EF10_100T": (6.19, 0.77),
    "EF30_0T": (103.46, 2.32),
    "EF30_12_5T": (72.58, 2.64),
    "EF30_25T": (50.21, 1.50),
    "EF30_37_5T": (37.16, 0.72),
    "EF30_50T": (31.85, 0.62),
}
"""E [kPa], mean and standard deviation, as published by the dataset's authors (Dawood
et al. 2026; the table of the inverse-design app in
github.com/abubakardawood/tissue-phantom-material-database, MIT)."""
CHECK_SHAPE, CHECK_DEGREE = (9, 9, 6), 2
"""A second discretisation of the bonded model: a contact is named only if both name it
(the loop's discretisation rule, docs/diagnosis.md, eq. D3, in its simplest form)."""
ENERGY_CANDIDATES = {
    "nonlinear_stiffening": ("stiffening", (0.0, 10.0)),
    "yeoh_term": ("yeoh", (-0.2, 0.2)),
}
"""The energy effects tried on the uniform-stress model: name -> (``uniform_force``'s
keyword, bounds of its ratio to E [1]): eq. (C10)'s k1 / E >= 0 (stiffening only), and
Yeoh's second-order c2 / E of either sign (stiffening or softening). A fit at a bound
is a stand-in."""
SHAPE, DEGREE = (9, 9, 7), 3
"""The 3D model's control points and degree: at nu = 0.49 its small-strain stiffness is
scikit-fem's P2 within 0.1 %, where degree 2 on 11 x 11 x 8 is 2.3 % too stiff
(``cylindercheck``; docs/experiments.md, "Locking")."""


def data_folder() -> Path:
    """The recipes' folder in the shared data."""
    return shared_data_dir() / "phantom-compression" / "data"


def unit_curves(travel: np.ndarray, radius: float, height: float, shape=SHAPE, degree=DEGREE):
    """Forces [N] (> 0) at E = 1 kPa: (bonded 3D, sliding uniform), each (K,)."""
    model = cylinder_model(radius, height, 1.0, shape, degree)
    return plate_forces(model, travel), uniform_force(travel, height, radius, 1.0)


@dataclass(frozen=True)
class LinearFit:
    """E of a model F = E f fitted to forces: value, standard error, RMS [kPa, kPa, N].

    The study reports as E's standard error the spread of the A specimens' own E over
    sqrt(5) (``E_std_kPa``): the specimens differ by more than the residual of one
    curve says (``E_residual_std_kPa``, this class's ``std_kpa``)."""

    young_kpa: float
    std_kpa: float
    rms_n: float

    @classmethod
    def of(cls, unit: np.ndarray, force: np.ndarray) -> LinearFit:
        """Least squares over every (unit force, measured force) pair; the standard error
        from the residual's own scatter, s^2 = |r|^2 / (n - 1) (model error included)."""
        gram = float(unit @ unit)
        young = float(unit @ force) / gram
        residual = force - young * unit
        scatter = float(residual @ residual) / max(len(force) - 1, 1)
        return cls(young, np.sqrt(scatter / gram), float(np.sqrt(np.mean(residual**2))))


def paired_gain(base_sse, candidate_sse) -> tuple[float, float]:
    """Mean and standard error of base - candidate over the held-out specimens' squared
    prediction errors [N^2] (> 0: the candidate predicts better). The loop's rule,
    docs/diagnosis.md, with the specimens as the left-out folds: a model is better than
    chance when the mean exceeds twice the standard error."""
    difference = np.subtract(base_sse, candidate_sse)
    spread = difference.std(ddof=1) / np.sqrt(len(difference)) if len(difference) > 1 else 0.0
    return float(difference.mean()), float(spread)


def named_contact(bonded_sse, sliding_sse) -> str:
    """The contact model that predicts the held-out specimens better than chance
    (``paired_gain``), or "neither"."""
    mean, spread = paired_gain(sliding_sse, bonded_sse)  # > 0: bonded predicts better
    if abs(mean) <= 2.0 * spread:
        return "neither"
    return "bonded" if mean > 0 else "sliding"


def model_entry(curve: np.ndarray, force: np.ndarray, series_a: np.ndarray) -> dict:
    """A model F = E ``curve`` fitted to the A series and its prediction of the others:
    ``E_kPa``, ``E_std_kPa`` (the A specimens' own E: spread over sqrt(n)),
    ``E_residual_std_kPa``, ``E_specimen_spread_kPa``, ``fit_rms_n``,
    ``b_prediction_rms_n`` and ``b_sse`` (per held-out specimen [N^2])."""
    fitted = LinearFit.of(np.tile(curve, series_a.sum()), force[series_a].ravel())
    error = force[~series_a] - fitted.young_kpa * curve
    each = [LinearFit.of(curve, f).young_kpa for f in force[series_a]]
    return {
        "E_kPa": fitted.young_kpa,
        "E_std_kPa": float(np.std(each, ddof=1) / np.sqrt(len(each))),
        "E_residual_std_kPa": fitted.std_kpa,
        "E_specimen_spread_kPa": float(np.std(each, ddof=1)),
        "fit_rms_n": fitted.rms_n,
        "b_prediction_rms_n": float(np.sqrt(np.mean(error**2))),
        "b_sse": np.sum(error**2, axis=1).tolist(),
    }


def window_entry(
    travel: np.ndarray,
    force: np.ndarray,
    series_a: np.ndarray,
    noise_n: float,
    unit: tuple,
    check: tuple | None = None,
    geometry: tuple[float, float] | None = None,
) -> dict:
    """One window of one recipe: E of both contact models fitted to the A series, their
    prediction of the B series, and the contact named.

    Parameters
    ----------
    travel : (K,) ndarray
        The plate's compression at the samples [mm].
    force : (S, K) ndarray
        Every test's compressive force at those samples [N] (> 0).
    series_a : (S,) bool ndarray
        The tests fitted (the A series); the others are predicted.
    noise_n : float
        The load cell's noise in one sample [N] (``force_noise_n``).
    unit : (bonded, sliding)
        The models' forces at E = 1 kPa at ``travel`` [N].
    check : (bonded, sliding), optional
        The same on the second discretisation (``CHECK_SHAPE``): a contact is named only
        if both name it.
    geometry : (height, radius), optional
        The cylinder [mm]: with it, the energy candidates too (``energy_entry``), in
        ``entry["energy"]``.
    """
    mean_a = force[series_a].mean(axis=0)
    scatter = float(np.sqrt(np.mean((force[~series_a] - mean_a) ** 2)))
    entry = {
        "travel_mm": travel.tolist(),
        "b_scatter_n": scatter,
        "b_scatter_sse": np.sum((force[~series_a] - mean_a) ** 2, axis=1).tolist(),
    }
    for contact, curve in zip(("bonded", "sliding"), unit):
        entry[contact] = model_entry(curve, force, series_a)
    entry["named"] = named_contact(entry["bonded"]["b_sse"], entry["sliding"]["b_sse"])
    if check is not None:  # the same choice on the second discretisation, or neither
        second = [model_entry(curve, force, series_a)["b_sse"] for curve in check]
        entry["named_check"] = named_contact(*second)
        if entry["named_check"] != entry["named"]:
            entry["named"] = "neither"
    gain = abs(entry["bonded"]["b_prediction_rms_n"] - entry["sliding"]["b_prediction_rms_n"])
    entry["force_noise_n"] = float(noise_n)
    if gain < noise_n:  # below what the load cell resolves in one sample
        entry["named"] = "neither"
    if geometry is not None:
        entry["energy"] = {
            name: energy_entry(travel, force, series_a, noise_n, geometry, name, entry["sliding"])
            for name in ENERGY_CANDIDATES
        }
    return entry


def energy_entry(
    travel: np.ndarray,
    force: np.ndarray,
    series_a: np.ndarray,
    noise_n: float,
    geometry: tuple[float, float],
    name: str,
    base: dict,
) -> dict:
    """One energy candidate of ``ENERGY_CANDIDATES`` on the uniform-stress model, its
    parameter r a ratio to E (so the force stays E times the force at E = 1): fitted to
    the A series (E linear least squares for each r; r from the best of a grid over its
    bounds, then a bounded scalar search between that node's neighbours) and judged by
    the B series against the base (r = 0), by the study's rule.

    Parameters
    ----------
    travel, force, series_a, noise_n
        As ``window_entry``.
    geometry : (height, radius)
        The cylinder [mm].
    name : str
        The candidate.
    base : dict
        The uniform-stress model's ``model_entry`` on the same samples (r = 0).

    Returns
    -------
    dict
        ``ratio`` (r), the keys of ``model_entry``, ``named`` (bool) and ``reason``.
    """
    height, radius = geometry
    keyword, (low, high) = ENERGY_CANDIDATES[name]
    specimens = force[series_a]

    def unit(ratio):
        return uniform_force(travel, height, radius, 1.0, **{keyword: ratio})

    def rms(ratio):
        try:
            curve = unit(ratio)
        except ValueError:  # no lateral stretch balances the stress: the energy fails
            return np.inf
        return LinearFit.of(np.tile(curve, len(specimens)), specimens.ravel()).rms_n

    grid = np.unique(np.concatenate([np.linspace(low, high, 41), [0.0]]))
    best = int(np.argmin([rms(r) for r in grid]))
    left, right = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    ratio = float(minimize_scalar(rms, bounds=(left, right), method="bounded").x)
    candidate = model_entry(unit(ratio), force, series_a)
    mean, spread = paired_gain(base["b_sse"], candidate["b_sse"])
    gain = base["b_prediction_rms_n"] - candidate["b_prediction_rms_n"]
    if abs(ratio) < 1e-3 * (high - low):
        named, reason = False, "fits r about 0 (within 0.1 % of its range): none is asked"
    elif min(ratio - low, high - ratio) <= 0.01 * (high - low):
        named, reason = False, "ends at its bound (a stand-in)"
    elif mean <= 2.0 * spread:
        named, reason = False, "does not predict the B series better than chance"
    elif gain < noise_n:
        named, reason = False, "its gain is below the load cell's noise"
    else:
        named, reason = True, "predicts the B series better than chance, above the noise"
    return {"ratio": ratio, **candidate, "named": named, "reason": reason}


def published_row(recipe: str, folder: Path) -> dict:
    """The published E and AIC-best form of a recipe (``hyperelastic_parameters.json`` in
    ``folder``; the E table ``PUBLISHED_E_KPA``); None where the recipe is not listed."""
    path = folder / "hyperelastic_parameters.json"
    published = json.loads(path.read_text())["engineering"].get(recipe, {}) if path.exists() else {}
    best = min(published, key=lambda k: published[k]["AIC"]) if published else None
    return {"recipe": recipe, "published_E_kPa": PUBLISHED_E_KPA.get(recipe), "aic_best": best}


def recipe_row(folder: Path, curves: dict, windows=None, checks=None) -> dict:
    """The fits and predictions of one recipe (every window of ``windows``, default
    ``WINDOWS``, whose unit-E curves ``curves`` holds; both contact models). ``checks``:
    the unit-E curves of the second discretisation (``CHECK_SHAPE``) by window."""
    checks = checks or {}
    recipe, tests = read_recipe(folder)
    row = published_row(recipe, folder.parent)
    series_a = np.array([t.name.startswith("A") for t in tests])
    for window, (strain, samples) in (windows or WINDOWS).items():
        data = compression_dataset(recipe, tests, samples, strain)
        travel = -data.plate_motion[:samples, 2]
        force = -data.forces[:, 2].reshape(len(tests), samples)
        widest = window == list(windows or WINDOWS)[-1]  # the energy candidates there
        geometry = (tests[0].height_mm, tests[0].diameter_mm / 2.0) if widest else None
        row[window] = window_entry(
            travel,
            force,
            series_a,
            data.force_noise_n,
            curves[window],
            checks.get(window),
            geometry,
        )
    return row


def run(out: Path, recipes=None, log=print) -> dict:
    """Every recipe (default all folders); writes ``phantoms.json`` and ``phantoms.md``."""
    begin = time.perf_counter()
    folders = sorted(p for p in data_folder().iterdir() if p.is_dir())
    if recipes:
        folders = [f for f in folders if f.name in recipes]
    _, first = read_recipe(folders[0])
    radius, height = first[0].diameter_mm / 2.0, first[0].height_mm
    curves, checks = {}, {}
    for window, (strain, samples) in WINDOWS.items():
        travel = np.linspace(0.02, 1.0, samples) * strain * height
        log(f"unit-E curves, {window}: {samples} travels to {strain * height:g} mm")
        curves[window] = unit_curves(travel, radius, height)
        checks[window] = unit_curves(travel, radius, height, CHECK_SHAPE, CHECK_DEGREE)
    rows = []
    for folder in folders:
        rows.append(recipe_row(folder, curves, checks=checks))
        log(f"{folder.name}: done")
    document = {
        "schema": "dvs-phantoms/1",
        "model": {
            "shape": list(SHAPE),
            "degree": DEGREE,
            "check": {"shape": list(CHECK_SHAPE), "degree": CHECK_DEGREE},
            "windows": WINDOWS,
        },
        "recipes": rows,
        "wall_time_s": time.perf_counter() - begin,
    }
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "phantoms.json", document)
    atomic_write_text(out / "phantoms.md", table(rows))
    return document


def table(rows: list) -> str:
    """The markdown tables of docs/experiments.md."""
    lines = [
        "| recipe | published E | AIC-best | E sliding (10 %) | E bonded (10 %) | "
        "B rms sliding / bonded / scatter (10 %) | same, to 30 % | named (10 %, 30 %) | "
        "energy named (30 %): r, E, B rms |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        small, curve = row["small strain"], row["curve"]
        published = row["published_E_kPa"]
        shown = f"{published[0]:.1f} +- {published[1]:.1f}" if published else "-"

        def e(w, c):
            return f"{w[c]['E_kPa']:.1f} +- {w[c]['E_std_kPa']:.1f}"

        def energy(w):
            named = [(n, c) for n, c in w.get("energy", {}).items() if c["named"]]
            if not named:
                return "none"
            name, c = min(named, key=lambda item: item[1]["b_prediction_rms_n"])
            return f"{name} {c['ratio']:+.4f}, {c['E_kPa']:.1f}, {c['b_prediction_rms_n']:.2f}"

        def b(w):
            sliding, bonded = (w[c]["b_prediction_rms_n"] for c in ("sliding", "bonded"))
            return f"{sliding:.2f} / {bonded:.2f} / {w['b_scatter_n']:.2f}"

        lines.append(
            f"| {row['recipe']} | {shown} | {row['aic_best']} | {e(small, 'sliding')} | "
            f"{e(small, 'bonded')} | {b(small)} | {b(curve)} | {small['named']}, "
            f"{curve['named']} | {energy(curve)} |"
        )
    return "\n".join(lines) + "\n"


def build_parser(prog: str = "python -m experiments.phantoms.study"):
    """The options of ``dvs study phantoms``."""
    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--recipes", default="", help="comma list (default: every folder)")
    return parser


def work(args) -> int:
    """Run the study and print its table."""
    check_output_dir(args.out)
    recipes = [r for r in args.recipes.split(",") if r]
    known = {p.name for p in data_folder().iterdir() if p.is_dir()}
    unknown = sorted(set(recipes) - known)
    if unknown:
        raise ValueError(f"--recipes: no recipe {unknown[0]}; choose from {sorted(known)}")
    document = run(args.out, recipes or None)
    print(table(document["recipes"]), end="")
    return 0


main = Command("experiments.phantoms.study", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
