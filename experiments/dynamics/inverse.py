"""The dynamic inverse on the phantom: mu and gamma from marker trajectories (MODEL.md 4).

A probe steps onto the phantom's skin at t = 0 and a 1 kHz camera rig records the
markers for 40 ms. Static data (rest and steady state) cannot determine mu or gamma;
these trajectories can. ``run`` simulates such a dataset, fits it statically and
dynamically (nested and simultaneous), and puts both identifiability reports side by
side.

**choice (truth and time window)**: mu = 5e-4 t as in ``TRUE_PARAMETERS`` but
gamma = 0.1 N s/mm, near critical damping of the lowest mode (gamma_c = 2 mu omega_1 =
0.101; docs/transient.md). With the paper's gamma = 15 the transient is a 10 s creep
(zeta_1 = 149) in which inertia acts only for mu/gamma = 33 us and moves the markers by
~1e-5 mm: the relative standard error of mu is then above 200 (0.02 mm noise, 40
frames, any window from 10 ms to 10 s; docs/dynamic.md). Near critical damping the
lowest modes ring within 40 ms and mu, gamma and alpha all come out within a few %.

Run ``python -m experiments.dynamics.inverse --out DIR``.
"""

from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.atomic import atomic_savefig, atomic_write_json  # noqa: E402
from experiments.dataset import Dataset  # noqa: E402
from experiments.fitting import FitSettings, build_problem, dataset_loads, rest_geometry  # noqa: E402
from experiments.phantom.forehead import (  # noqa: E402
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from solvers.dynamic.identifiability import analyse_dynamic, contrast, contrast_table  # noqa: E402
from solvers.dynamic.nested import DynamicNestedSolver  # noqa: E402
from solvers.dynamic.problem import DynamicProblem, TimeGrid, step_profile, trajectory_case  # noqa: E402
from solvers.dynamic.scheme import TrapezoidalScheme  # noqa: E402
from solvers.dynamic.simultaneous import DynamicSimultaneousSolver  # noqa: E402
from solvers.equilibrium import EquilibriumSolver  # noqa: E402
from solvers.identifiability import analyse  # noqa: E402
from solvers.problem import ParameterSpace  # noqa: E402
from solvers.simultaneous import SimultaneousSolver  # noqa: E402
from solvers.transient.loads import Load, ramp_load  # noqa: E402
from solvers.transient.sundials import integrate_casadi  # noqa: E402
from symbolic.model import BoundaryConditions, TissueModel  # noqa: E402

DYNAMIC_TRUTH = {**TRUE_PARAMETERS, "gamma": 0.1}
"""Truth of the dynamic experiment: the phantom's, with gamma near critical damping."""
DYNAMIC_PHANTOM = PhantomSettings(forces=(0.25,))
"""One probe load of 0.25 N (in the linear model a second force adds no new shape)."""
DEFAULT_FRAMES = 1e-3 * np.arange(1, 41)
"""Frame times [s]: 1 kHz for 40 ms after the load onset."""
DEFAULT_SUBSTEPS = 2
"""Scheme steps per frame interval (0.5 ms): bias below 0.5 standard errors."""
DYNAMIC_NAMES = ("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")
"""Estimated parameters."""
RAMP_KEY = "load_ramp_s"
"""Dataset ``extra`` key of the load's rise time [s] (absent: a step at t = 0)."""


def _profile(ramp_s: float | None):
    return step_profile if not ramp_s else ramp_load(np.zeros((1, 3)), ramp_s).profile


def truth_trajectories(
    model: TissueModel, force: np.ndarray, frames, integrator="cvodes", substeps=8, ramp_s=None
) -> np.ndarray:
    """Displacements B_free - B0_free at the frames from rest, (T, n_free, 3) [mm].

    ``integrator`` "cvodes": SUNDIALS BDF at rtol 1e-10 (independent of the fit's
    scheme); "scheme": the trapezoidal scheme with ``substeps`` per frame interval.
    """
    frames = np.asarray(frames, dtype=float)
    profile = _profile(ramp_s)
    if integrator == "cvodes":
        times = frames if frames[0] == 0 else np.concatenate([[0.0], frames])
        path = integrate_casadi(model, Load(force, profile), times, rtol=1e-10, atol=1e-12)
        return path[-frames.size :]
    if integrator != "scheme":
        raise ValueError(f"integrator must be 'cvodes' or 'scheme', got {integrator!r}")
    grid = TimeGrid(frames, substeps)
    scale = np.array([float(profile(t)) for t in grid.nodes])
    loads = scale[:, None] * np.asarray(force).T.reshape(-1)[None, :]
    run = TrapezoidalScheme(model, (), grid).run(loads, [])
    states = run.displacements[grid.frame_nodes]
    return states.reshape(frames.size, 3, -1).transpose(0, 2, 1)


def simulate_dynamic(
    noise_mm: float = 0.02,
    seed: int = 0,
    times=None,
    *,
    parameters: dict | None = None,
    phantom: PhantomSettings | None = None,
    integrator: str = "cvodes",
    substeps: int = 8,
    ramp_s: float | None = None,
    missing_fraction: float = 0.0,
    occlusion_radius_mm: float = 2.0,
) -> Dataset:
    """A dataset v1 with marker trajectories of the phantom under a probe load from rest.

    Parameters
    ----------
    noise_mm : float
        Standard deviation of every marker coordinate [mm]: rest markers, every frame
        and the steady-state capture (``outer_loaded``) each get their own noise.
    seed : int
        Random seed.
    times : array_like, optional
        Frame times [s] (default ``DEFAULT_FRAMES``, 1 kHz for 40 ms).
    parameters : dict, optional
        Truth (default ``DYNAMIC_TRUTH``).
    phantom : PhantomSettings, optional
        Geometry, markers and forces (default ``DYNAMIC_PHANTOM``, one 0.25 N load).
    integrator : {"cvodes", "scheme"}
        How the truth is integrated (see ``truth_trajectories``).
    substeps : int
        Steps per frame interval of the "scheme" integrator.
    ramp_s : float, optional
        Rise time of the load [s] (stored as ``extra["load_ramp_s"]``); default a step.
    missing_fraction : float
        Fraction of markers lost at random in each frame.
    occlusion_radius_mm : float
        Markers closer than this to the contact are hidden in every frame [mm].
    """
    phantom = phantom or DYNAMIC_PHANTOM
    frames = DEFAULT_FRAMES if times is None else np.asarray(times, dtype=float)
    values = tuple(sorted((parameters or DYNAMIC_TRUTH).items()))
    clean = _clean_measurement(phantom, values, tuple(frames), integrator, substeps, ramp_s)
    rng = np.random.default_rng(seed)
    shape = phantom.markers
    rest = clean["rest"]
    series, loaded = [], []
    for path, steady, contact in zip(clean["series"], clean["steady"], clean["contacts"]):
        hidden = np.linalg.norm(rest - contact, axis=1) < occlusion_radius_mm
        moved = path + rng.normal(0.0, noise_mm, path.shape)
        steady = steady + rng.normal(0.0, noise_mm, steady.shape)
        moved[:, hidden] = np.nan
        moved[rng.random(moved.shape[:2]) < missing_fraction] = np.nan
        steady[hidden] = np.nan
        series.append(moved.reshape((frames.size, *shape, 3)))
        loaded.append(steady.reshape((*shape, 3)))
    return Dataset(
        outer_rest=(rest + rng.normal(0.0, noise_mm, rest.shape)).reshape((*shape, 3)),
        inner_rest=clean["inner"].reshape((*shape, 3)),
        forces=clean["forces"],
        contacts=clean["contacts"],
        outer_loaded=np.stack(loaded),
        noise_mm=float(noise_mm),
        probe_radius=np.full(len(clean["forces"]), phantom.probe_radius),
        times=frames,
        outer_series=np.stack(series),
        extra={} if not ramp_s else {RAMP_KEY: np.array(float(ramp_s))},
    )


@lru_cache(maxsize=8)
def _clean_measurement(phantom, parameters, frames, integrator, substeps, ramp_s) -> dict:
    """Noise-free markers of the truth: rest, trajectories, steady state (cached)."""
    frames = np.array(frames)
    truth = forehead_model(phantom, dict(parameters))
    uv = marker_uv(phantom)
    rows = truth.volume.collocation(truth.volume.outer_params(uv))
    rest = rows @ truth.rest
    loads = probe_loads(truth, phantom)
    series, steady, contacts = [], [], []
    for load in loads:
        force = truth.generalized_force(load)
        path = truth_trajectories(truth, force, frames, integrator, substeps, ramp_s)
        series.append(rest[None] + np.einsum("mn,tnc->tmc", rows[:, truth.free].toarray(), path))
        steady.append(rows @ EquilibriumSolver(truth).solve(force).positions)
        contacts.append(truth.volume.evaluate(truth.volume.outer_params(load.uv[None]))[0])
    inner = truth.volume.collocation(np.column_stack([uv, np.zeros(len(uv))])) @ truth.rest
    return {
        "rest": rest,
        "inner": inner,
        "series": series,
        "steady": steady,
        "contacts": np.array(contacts),
        "forces": np.array([load.force for load in loads]),
    }


def build_dynamic_problem(
    dataset: Dataset,
    names=DYNAMIC_NAMES,
    substeps: int = DEFAULT_SUBSTEPS,
    cases: list[int] | None = None,
    start: dict | None = None,
    settings: FitSettings | None = None,
) -> DynamicProblem:
    """The dynamic inverse problem of a dataset's trajectories (geometry as ``fitting``).

    The load is a step at t = 0 unless ``extra["load_ramp_s"]`` gives a rise time.
    """
    if dataset.times is None or dataset.outer_series is None:
        raise ValueError(
            "the dataset has no trajectories (times, outer_series); "
            "simulate one with experiments.dynamics.inverse.simulate_dynamic"
        )
    settings = settings or FitSettings(names=tuple(names))
    volume, uv = rest_geometry(dataset, settings)
    boundary = BoundaryConditions(fix_lateral=settings.fix_lateral)
    model = TissueModel(volume, dict(settings.fixed or {}), boundary)
    loads = dataset_loads(dataset, volume)
    ramp = dataset.extra.get(RAMP_KEY)
    profile = _profile(None if ramp is None else float(ramp))
    frames = dataset.times.size
    problem_cases = [
        trajectory_case(
            model,
            loads[k],
            dataset.outer_series[k].reshape(frames, -1, 3),
            uv,
            profile,
            label=f"{np.linalg.norm(dataset.forces[k]):.3g} N",
        )
        for k in (range(dataset.n_loads) if cases is None else cases)
    ]
    space = ParameterSpace.create(tuple(names), start)
    return DynamicProblem(
        model, problem_cases, space, dataset.times, substeps, dataset.noise_mm, rest_noise=True
    )


def _parameter_rows(report, truth: dict) -> dict:
    rows = {}
    for p in report.parameters:
        z = None if p.std is None else (p.value - truth[p.name]) / p.std
        rows[p.name] = {
            "value": p.value,
            "std": p.std,
            "truth": truth[p.name],
            "z_score": z,
            "identifiable": p.identifiable,
            "note": p.note,
        }
    return rows


def _solver_row(result) -> dict:
    return {
        "estimate": result.as_dict(),
        "cost_mm2": result.cost,
        "success": result.success,
        "status": result.status,
        "iterations": result.iterations,
        "build_time_s": result.build_time_s,
        "solve_time_s": result.solve_time_s,
    }


def run(
    out: Path,
    log=print,
    noise_mm: float = 0.02,
    seed: int = 0,
    frames=None,
    substeps: int = DEFAULT_SUBSTEPS,
    simultaneous: bool = True,
) -> dict:
    """Simulate, fit statically and dynamically, compare; write dynamic.json and dynamic.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log("[1/5] simulate the trajectories (CVODES truth)")
    dataset = simulate_dynamic(noise_mm, seed, frames)
    log("[2/5] static fit (rest and steady state)")
    static_problem = build_problem(dataset, FitSettings(names=DYNAMIC_NAMES))
    static_result = SimultaneousSolver(static_problem).solve()
    static_report = analyse(static_problem, static_result.x, static=True)
    log("[3/5] dynamic fit, nested (single shooting)")
    problem = build_dynamic_problem(dataset, substeps=substeps)
    nested = DynamicNestedSolver(problem).solve()
    results = {"nested": nested}
    if simultaneous:
        log("[4/5] dynamic fit, simultaneous (one IPOPT NLP)")
        results["simultaneous"] = DynamicSimultaneousSolver(problem).solve()
    log("[5/5] identifiability, figure, summary")
    report = analyse_dynamic(problem, nested.x)
    rows = contrast(static_report, report)
    summary = {
        "truth": DYNAMIC_TRUTH,
        "data": {
            "noise_mm": noise_mm,
            "seed": seed,
            "frames": int(problem.frames.size),
            "frame_interval_s": float(np.diff(np.r_[0.0, problem.frames]).mean()),
            "window_s": float(problem.frames[-1]),
            "substeps": substeps,
            "forces_N": np.linalg.norm(dataset.forces, axis=1).tolist(),
        },
        "static": {
            **_solver_row(static_result),
            "parameters": _parameter_rows(static_report, DYNAMIC_TRUTH),
            "singular_values": static_report.singular_values.tolist(),
            "rank": static_report.rank,
        },
        "dynamic": {
            **{name: _solver_row(result) for name, result in results.items()},
            "parameters": _parameter_rows(report, DYNAMIC_TRUTH),
            "singular_values": report.singular_values.tolist(),
            "rank": report.rank,
            "correlation": report.correlation.tolist(),
        },
        "contrast": rows,
    }
    if simultaneous:
        pair = results["simultaneous"].x / nested.x - 1
        summary["dynamic"]["max_relative_difference"] = float(np.abs(pair).max())
    _plot(out / "dynamic.png", problem, nested, static_report, report)
    atomic_write_json(out / "dynamic.json", summary)
    for line in contrast_table(rows).splitlines():
        log(line)
    return summary


def _plot(path, problem: DynamicProblem, result, static_report, dynamic_report) -> None:
    """Probe-region marker trajectories (data and fit) and both singular-value spectra."""
    case = problem.cases[0]
    trajectory = result.extra["trajectories"][0]
    nodes = problem.grid.nodes
    n = problem.model.n_free
    fitted = np.einsum(
        "mn,tnc->tmc", case.rows.toarray(), trajectory.reshape(-1, 3, n).swapaxes(1, 2)
    )
    measured = case.observed - case.rest_points[None]
    direction = -problem.model.volume.outer_normal(np.array([[0.5, 0.5]]))[0]
    rest_uv, _ = problem.model.volume.project_to_outer(case.rest_points)
    distance = np.round(np.linalg.norm(rest_uv - 0.5, axis=1), 2)
    _, first = np.unique(distance, return_index=True)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, marker in enumerate(first[:4]):
        color = f"C{i}"
        left.plot(1e3 * nodes, fitted[:, marker] @ direction, "-", color=color, lw=1)
        left.plot(
            1e3 * problem.frames,
            measured[:, marker] @ direction,
            ".",
            color=color,
            ms=4,
            label="(u, v) - probe = ({:+.2f}, {:+.2f})".format(*(rest_uv[marker] - 0.5)),
        )
    left.set(xlabel="t [ms]", ylabel="displacement along the probe [mm]")
    left.set_title("probe region: data (dots), nested fit (lines)", fontsize=10)
    left.legend(fontsize=7)
    spectra = [("static data", static_report), ("trajectories", dynamic_report)]
    nonzero = [
        r.singular_values[r.singular_values > 1e-10 * r.singular_values.max()] for _, r in spectra
    ]
    floor = 1e-2 * min(values.min() for values in nonzero)
    for offset, (label, report) in enumerate(spectra):
        values = np.zeros(len(report.parameters))
        values[: report.singular_values.size] = report.singular_values
        where = np.arange(values.size) + 0.4 * offset - 0.2
        right.bar(where, np.maximum(values, floor), width=0.4, label=label, color=f"C{offset}")
        for x in where[values <= 1e-10 * values.max()]:
            right.text(x, 1.5 * floor, "0", ha="center", fontsize=8)
    right.set(yscale="log", xlabel="index", ylabel="singular value (relative sensitivity) [mm]")
    right.set_title("singular values of the relative sensitivities", fontsize=10)
    right.legend(fontsize=8)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def bias_study(substeps=(1, 2, 4), log=print) -> list[dict]:
    """Noise-free CVODES data fitted with 1, 2, 4 substeps: the scheme's bias [relative]."""
    dataset = simulate_dynamic(noise_mm=0.0)
    truth = np.array([DYNAMIC_TRUTH[n] for n in DYNAMIC_NAMES])
    rows = []
    for count in substeps:
        begin = time.perf_counter()
        result = DynamicNestedSolver(build_dynamic_problem(dataset, substeps=count)).solve()
        bias = result.x / truth - 1
        log(f"substeps {count}: bias " + " ".join(f"{b:+.2e}" for b in bias))
        rows.append(
            {
                "substeps": count,
                "bias": dict(zip(DYNAMIC_NAMES, bias.tolist())),
                "time_s": time.perf_counter() - begin,
            }
        )
    return rows


def coverage_study(seeds=range(20), noise_mm=0.02, log=print) -> dict:
    """z-scores (estimate - truth) / standard error of the nested fit over seeds."""
    truth = np.array([DYNAMIC_TRUTH[n] for n in DYNAMIC_NAMES])
    scores = []
    for seed in seeds:
        problem = build_dynamic_problem(simulate_dynamic(noise_mm, seed))
        result = DynamicNestedSolver(problem).solve()
        std = np.array([p.std for p in analyse_dynamic(problem, result.x).parameters])
        scores.append((result.x - truth) / std)
    scores = np.array(scores)
    rms = np.sqrt(np.mean(scores**2, axis=0))
    log("RMS z: " + " ".join(f"{n} {v:.2f}" for n, v in zip(DYNAMIC_NAMES, rms)))
    return {
        "z_scores": scores.tolist(),
        "rms_z": dict(zip(DYNAMIC_NAMES, rms.tolist())),
        "within_3_std": float(np.mean(np.abs(scores) < 3)),
    }


def build_parser(prog: str = "python -m experiments.dynamics.inverse"):
    """The options of ``dvs dynamic``."""
    from experiments.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=path_argument, default=Path("dynamic-output"), help="directory"
    )
    parser.add_argument("--noise", type=float, default=0.02, help="marker noise [mm]")
    parser.add_argument("--seed", type=int, default=0, help="random seed (>= 0)")
    parser.add_argument(
        "--substeps", type=int, default=DEFAULT_SUBSTEPS, help="steps per frame (1-100)"
    )
    parser.add_argument("--no-simultaneous", action="store_true", help="skip the IPOPT NLP")
    parser.add_argument("--bias", action="store_true", help="also the integrator-bias study")
    parser.add_argument("--coverage", type=int, default=0, help="seeds for a coverage study")
    return parser


def main(argv: list[str] | None = None, prog: str = "python -m experiments.dynamics.inverse"):
    """``dvs dynamic --out DIR``: dynamic.json and dynamic.png."""
    from experiments.options import UsageError, check_output_dir, check_seed, run_guarded

    args = build_parser(prog).parse_args(argv)

    def work() -> int:
        if not 0 <= args.noise <= 1:
            raise UsageError(f"--noise must be a number in [0, 1] mm, got {args.noise}")
        check_seed(args.seed)
        if not 1 <= args.substeps <= 100 or not 0 <= args.coverage <= 1000:
            raise UsageError("--substeps must lie in 1-100 and --coverage in 0-1000")
        out = check_output_dir(args.out)
        summary = run(
            out,
            noise_mm=args.noise,
            seed=args.seed,
            substeps=args.substeps,
            simultaneous=not args.no_simultaneous,
        )
        if args.bias:
            summary["bias"] = bias_study()
        if args.coverage:
            summary["coverage"] = coverage_study(range(args.coverage), args.noise)
        if args.bias or args.coverage:
            atomic_write_json(out / "dynamic.json", summary)
        return 0

    return run_guarded(prog, work)


if __name__ == "__main__":
    raise SystemExit(main())
