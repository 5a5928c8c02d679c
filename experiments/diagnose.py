"""``dvs diagnose``: find what the base model is missing, and synthetic data to test it.

- ``run(dataset_or_path, out)`` runs the discrepancy loop of ``solvers.diagnosis``
  and writes ``diagnosis.json``, ``report.md`` and residual maps before/after.
- ``simulate_with_effects({"rigid_motion": 0.05}, ...)`` makes a dataset from the
  forehead phantom with effects the dataset does not declare (``dvs simulate
  --effect NAME[=VALUE]``; ``parse_effect_specs`` reads those options), either
  with the paper's two central loads or with the diagnosis design
  (``contacts=DIAGNOSIS_CONTACTS, tilt_deg=DIAGNOSIS_TILT_DEG``: five contacts,
  each pressed along the normal and with a tilted probe).
- ``benchmark()`` measures the cost of the score tests in forward solves;
  ``study(seeds)`` runs every effect alone over several seeds (docs/diagnosis.md).

Run as ``python -m experiments.diagnose FILE.npz --out DIR`` (or ``--benchmark``,
``--study 1,2,3,4 [--design paper] [--effects a,b]``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from experiments.dataset import Dataset, DatasetError, load_dataset
from experiments.simulate import SimulationSettings
from experiments.synthetic import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from solvers.diagnosis_report import report, verdict
from solvers.problem import InverseProblem, ParameterSpace, observation_case
from symbolic.effects import EFFECT_NAMES, make_effect
from symbolic.effects_base import surface_frame
from symbolic.loads import PointForce, ProbeForce

BASE_NAMES = ("alpha_u", "alpha_v", "alpha_w")
"""The base model's estimated parameters (static data cannot see mu and gamma)."""


# ------------------------------------------------------------------ synthetic data
def parse_effect_specs(specs) -> dict[str, float]:
    """``["rigid_motion=0.05", "bending"]`` -> {name: magnitude} (defaults for bare names).

    Raises
    ------
    ValueError
        For an unknown name, a repeated name or a value that is not a finite number.
    """
    effects: dict[str, float] = {}
    for spec in specs or []:
        name, _, value = str(spec).partition("=")
        name = name.strip()
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r}; choose from {', '.join(EFFECT_NAMES)}")
        if name in effects:
            raise ValueError(f"effect {name} given twice")
        if value.strip():
            try:
                magnitude = float(value)
            except ValueError:
                raise ValueError(f"--effect {spec!r}: the value must be a number") from None
            if not np.isfinite(magnitude):
                raise ValueError(f"--effect {spec!r}: the value must be finite")
        else:
            magnitude = make_effect(name).default_magnitude
        effects[name] = magnitude
    return effects


def _truth_states(truth, loads, uv, effects: dict[str, float]):
    """Marker positions under every load of the phantom with the effects switched on."""
    from solvers.diagnosis_problem import ExtendedProblem

    rest = truth.volume.collocation(truth.volume.outer_params(uv)) @ truth.rest
    cases = [observation_case(truth, load, rest, uv) for load in loads]
    space = ParameterSpace.create(BASE_NAMES, {n: TRUE_PARAMETERS[n] for n in BASE_NAMES})
    base = InverseProblem(truth, cases, space)
    active = [make_effect(n) for n in EFFECT_NAMES if n in effects and n != "contact_patch"]
    problem = ExtendedProblem(base, loads, active)
    p = problem.start()
    for effect in active:
        p[problem.slice_of(effect.name)] = effect.true_parameters(effects[effect.name], len(loads))
    r, _, _ = problem.evaluate(p)
    m = len(uv)
    return [rest + r[3 * m * k : 3 * m * (k + 1)].reshape(3, m).T for k in range(len(loads))]


DIAGNOSIS_CONTACTS = ((0.5, 0.5), (0.3, 0.3), (0.7, 0.3), (0.3, 0.7), (0.7, 0.7))
"""Contact points (u, v) of the diagnosis design: the centre and four points 8 mm
along u and v off it on the 40 mm forehead patch (docs/diagnosis.md)."""

DIAGNOSIS_TILT_DEG = 20.0
"""Tilt of the second (0.25 N) load at every contact of the diagnosis design [deg]:
held by skin friction (coefficient 0.36 needed; skin on steel or plastic 0.2-0.8)."""


def design_loads(truth, phantom: PhantomSettings, contacts, tilt_deg: float = 0.0) -> list:
    """Point loads at every contact, one per phantom force (contact-major order).

    The first force presses along the inward normal; the others are tilted by
    ``tilt_deg`` from it, leaning away from the patch centre (along V_u at the
    centre itself), so that the loads also shear the skin.
    """
    loads = []
    for uv in contacts:
        uv = np.asarray(uv, dtype=float)
        du, dv, e1, e2, normal = surface_frame(truth, uv)
        away = (uv[0] - 0.5) * du + (uv[1] - 0.5) * dv
        away = away - (away @ normal) * normal
        lean = away / np.linalg.norm(away) if np.linalg.norm(away) > 1e-9 else e1
        angle = np.radians(tilt_deg)
        for k, f in enumerate(phantom.forces):
            direction = -normal if k == 0 else -np.cos(angle) * normal + np.sin(angle) * lean
            loads.append(PointForce(f * direction, uv=uv))
    return loads


def simulate_with_effects(
    effects: dict[str, float] | None = None,
    noise_mm: float = 0.02,
    seed: int = 0,
    missing_fraction: float = 0.03,
    phantom: PhantomSettings | None = None,
    contacts=None,
    tilt_deg: float = 0.0,
) -> Dataset:
    """A dataset from the phantom with undeclared effects (``dvs simulate --effect``).

    The measurement is that of ``experiments.simulate.simulate`` (same noise on
    rest and loaded markers, occlusion by the probe, random missing markers,
    same random stream): with no effects the two give the same dataset. The
    dataset declares the nominal loads only: point forces along the inward
    normal at the nominal contact, no probe radius.

    Parameters
    ----------
    effects : dict
        Effect name -> magnitude (``Effect.default_magnitude`` units; see
        ``parse_effect_specs``). ``contact_patch`` is simulated with the
        project's own Gaussian probe (``symbolic.loads.ProbeForce``) of that
        radius [mm], not with the library's expansion.
    noise_mm : float
        Standard deviation of every marker coordinate [mm].
    seed : int
        Random seed.
    missing_fraction : float
        Fraction of loaded markers lost at random.
    contacts : sequence of (u, v), optional
        Probe contact points on the skin; every one is pressed along its inward
        normal with each of the phantom's forces (contact-major order). Default:
        the phantom's single central contact (``probe_loads``);
        ``DIAGNOSIS_CONTACTS`` is the richer design of the diagnosis tests.
    """
    effects = dict(effects or {})
    unknown = set(effects) - set(EFFECT_NAMES)
    if unknown:
        raise ValueError(f"unknown effects {sorted(unknown)}; choose from {EFFECT_NAMES}")
    phantom = phantom or PhantomSettings()
    measurement = SimulationSettings(
        noise_mm=noise_mm, seed=seed, missing_fraction=missing_fraction
    )
    truth = forehead_model(phantom, TRUE_PARAMETERS)
    uv = marker_uv(phantom)
    declared = (
        probe_loads(truth, phantom)
        if contacts is None
        else design_loads(truth, phantom, contacts, tilt_deg)
    )
    loads = declared
    if effects.get("contact_patch", 0.0) > 0:
        radius = float(effects["contact_patch"])
        loads = [ProbeForce(ld.force, radius, uv=ld.uv) for ld in declared]
    positions = _truth_states(truth, loads, uv, effects)
    rest = truth.volume.collocation(truth.volume.outer_params(uv)) @ truth.rest
    contacts = np.array(
        [truth.volume.evaluate(truth.volume.outer_params(ld.uv[None]))[0] for ld in declared]
    )
    inner = np.column_stack([uv, np.zeros(len(uv))])
    return measured_dataset(
        rest,
        truth.volume.collocation(inner) @ truth.rest,
        positions,
        np.array([ld.force for ld in declared]),
        contacts,
        measurement,
        phantom.markers,
    )


def measured_dataset(
    rest: np.ndarray,
    inner: np.ndarray,
    positions: list,
    forces: np.ndarray,
    contacts: np.ndarray,
    measurement: SimulationSettings,
    shape: tuple[int, int],
) -> Dataset:
    """What the camera rig records of true marker positions (as ``simulate`` does).

    Parameters
    ----------
    rest, inner : numpy.ndarray
        True rest markers and inner-surface points, (U V, 3) [mm].
    positions : list of numpy.ndarray
        True marker positions under every load, each (U V, 3) [mm].
    forces, contacts : numpy.ndarray
        Declared force vectors [N] and contact points [mm], (K, 3).
    measurement : SimulationSettings
        Noise, occlusion radius, missing fraction and seed (the random stream
        is that of ``experiments.simulate.simulate``).
    shape : tuple of int
        Marker grid (U, V).
    """
    rng = np.random.default_rng(measurement.seed)
    loaded = []
    for position, contact in zip(positions, contacts):
        observed = position + rng.normal(0.0, measurement.noise_mm, rest.shape)
        hidden = np.linalg.norm(rest - contact, axis=1) < measurement.occlusion_radius_mm
        hidden |= rng.random(len(rest)) < measurement.missing_fraction
        observed[hidden] = np.nan
        loaded.append(observed.reshape(shape + (3,)))
    noisy_rest = rest + rng.normal(0.0, measurement.noise_mm, rest.shape)
    return Dataset(
        outer_rest=noisy_rest.reshape(shape + (3,)),
        inner_rest=np.asarray(inner).reshape(shape + (3,)),
        forces=np.asarray(forces, dtype=float),
        contacts=np.asarray(contacts, dtype=float),
        outer_loaded=np.stack(loaded),
        noise_mm=float(measurement.noise_mm),
        probe_radius=np.zeros(len(forces)),
    )


# ---------------------------------------------------------------------- diagnosis
def diagnose_dataset(dataset: Dataset, settings=None, log=None):
    """Build the base problem of a dataset and run the loop; returns the Diagnosis."""
    from experiments.fitting import FitSettings, build_problem, dataset_loads
    from solvers.diagnosis import diagnose

    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    loads = dataset_loads(dataset, base.model.volume)
    return diagnose(base, loads, settings, log)


def run(dataset_or_path, out: Path, log=print, settings=None) -> dict:
    """Diagnose a dataset (object or ``.npz`` path); write diagnosis.json, report.md, figures.

    Returns
    -------
    dict
        The diagnosis.json document (schema ``dvs-diagnosis/1``).
    """
    from experiments.atomic import atomic_write_json, atomic_write_text

    dataset = dataset_or_path
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset_or_path)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log(
        f"diagnosing {dataset.n_loads} load cases, {dataset.outer_rest.shape[0]}x"
        f"{dataset.outer_rest.shape[1]} markers"
    )
    begin = time.perf_counter()
    diagnosis = diagnose_dataset(dataset, settings, log=lambda line: log("  " + line))
    document = diagnosis.document()
    document["wall_time_s"] = time.perf_counter() - begin
    plot_residuals(diagnosis, out / "residuals.png")
    atomic_write_json(out / "diagnosis.json", document)
    atomic_write_text(out / "report.md", report(diagnosis, document))
    log(
        f"rms {document['rms_before_mm'] * 1e3:.1f} -> {document['rms_after_mm'] * 1e3:.1f} um; "
        f"{verdict(document)} -> {out / 'diagnosis.json'}"
    )
    return document


def plot_residuals(diagnosis, path: Path) -> None:
    """Marker residual maps of the base model (left) and the final model (right), per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.atomic import atomic_savefig
    from experiments.plots import residual_panel

    first, last = diagnosis.steps[0].fit, diagnosis.steps[-1].fit
    cases = first.problem.cases
    fig, axes = plt.subplots(
        len(cases), 2, figsize=(10, 4.4 * len(cases)), squeeze=False, layout="constrained"
    )
    maps = [first.problem.point_errors(first.residual), last.problem.point_errors(last.residual)]
    top = max(float(e.max()) for errors in maps for e in errors) * 1e3
    titles = ("base model", " + ".join(diagnosis.selected) or "base model (nothing added)")
    for column, (errors, title) in enumerate(zip(maps, titles)):
        for row, (case, error) in enumerate(zip(cases, errors)):
            image = residual_panel(axes[row, column], case, error, top, title, size=60)
    fig.colorbar(image, ax=axes.ravel().tolist(), label="marker residual [um]")
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """``python -m experiments.diagnose FILE.npz --out DIR`` (or ``--benchmark``, ``--study``).

    Exit 0 on success, 2 with one line on stderr for bad input.
    """
    parser = argparse.ArgumentParser(
        prog="python -m experiments.diagnose", description="find what the base model is missing"
    )
    parser.add_argument("dataset", type=Path, nargs="?", help="dataset v1 (.npz)")
    parser.add_argument("--out", type=Path, help="output directory")
    parser.add_argument("--level", type=float, default=0.01, help="significance level")
    parser.add_argument("--max-effects", type=int, default=3, help="most effects added")
    parser.add_argument("--benchmark", action="store_true", help="time the score tests")
    parser.add_argument("--study", default="", help="seeds, e.g. 1,2,3,4: every effect alone")
    parser.add_argument(
        "--design",
        choices=("diagnosis", "paper"),
        default="diagnosis",
        help="experiment of --study: five contacts with a tilted load (default) or the paper's",
    )
    parser.add_argument("--effects", default="", help="--study only these effects (comma list)")
    args = parser.parse_args(argv)
    from solvers.diagnosis import DiagnosisSettings

    try:
        if args.benchmark:
            benchmark()
            return 0
        if args.study:
            names = tuple(n for n in args.effects.split(",") if n) or None
            study(tuple(int(s) for s in args.study.split(",")), design=args.design, names=names)
            return 0
        if args.dataset is None or args.out is None:
            raise ValueError("give a dataset and --out DIR (or --benchmark, --study SEEDS)")
        settings = DiagnosisSettings(level=args.level, max_effects=args.max_effects)
        run(args.dataset, args.out, settings=settings)
    except (DatasetError, ValueError, FileNotFoundError) as error:
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        print(f"diagnose: error: {message}", file=sys.stderr)
        return 2
    return 0


def study(seeds=(1, 2, 3, 4), log=print, design: str = "diagnosis", names=None) -> list[dict]:
    """Every effect alone at its realistic magnitude, plus none, over several seeds.

    ``design``: "diagnosis" (``DIAGNOSIS_CONTACTS``, tilted second load) or
    "paper" (two loads at the centre). ``names``: the effects studied (default
    none and every effect; "none" is the negative control). Prints one line per
    run: selected effects, RMS before/after against the noise level (expected
    RMS of a pure-noise residual) and CPU time.
    """
    options = {"contacts": DIAGNOSIS_CONTACTS, "tilt_deg": DIAGNOSIS_TILT_DEG}
    options = options if design == "diagnosis" else {}
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
    from experiments.fitting import FitSettings, build_problem, dataset_loads
    from solvers.diagnosis_fit import fit
    from solvers.diagnosis_problem import ExtendedProblem
    from solvers.diagnosis_stats import score_test
    from symbolic.effects import effect_library

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


if __name__ == "__main__":
    raise SystemExit(main())
