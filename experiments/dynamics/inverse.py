"""The dynamic inverse on the phantom: mu and gamma from marker trajectories (docs/dynamic.md).

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
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.command.options import (
    Command,
    UsageError,
    add_noise_seed_arguments,
    check_noise_seed,
    check_output_dir,
    make_parser,
    not_converged,
    path_argument,
)
from experiments.dynamics.trajectories import (  # noqa: E402
    DEFAULT_SUBSTEPS,
    DYNAMIC_NAMES,
    DYNAMIC_TRUTH,
    build_dynamic_problem,
    simulate_dynamic,
)
from experiments.output.atomic import atomic_savefig, atomic_write_json  # noqa: E402
from experiments.problem.fitting import FitSettings, build_problem  # noqa: E402
from solvers.dynamic.identifiability import analyse_dynamic, contrast, contrast_table  # noqa: E402
from solvers.dynamic.nested import DynamicNestedSolver  # noqa: E402
from solvers.dynamic.problem import DynamicProblem  # noqa: E402
from solvers.dynamic.simultaneous import DynamicSimultaneousSolver  # noqa: E402
from solvers.inverse.identifiability import analyse  # noqa: E402
from solvers.inverse.simultaneous import SimultaneousSolver  # noqa: E402


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
    solved = [static_result, *results.values()]
    summary = {
        "success": all(bool(r.success) for r in solved),
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
    """The options of ``dvs study dynamic``."""
    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=path_argument, default=Path("dynamic-output"), help="directory"
    )
    add_noise_seed_arguments(parser)
    parser.add_argument(
        "--substeps", type=int, default=DEFAULT_SUBSTEPS, help="steps per frame (1-100)"
    )
    parser.add_argument("--no-simultaneous", action="store_true", help="skip the IPOPT NLP")
    parser.add_argument("--bias", action="store_true", help="also the integrator-bias study")
    parser.add_argument("--coverage", type=int, default=0, help="seeds for a coverage study, 0-100")
    return parser


def work(args) -> int:
    """``dvs study dynamic --out DIR``: dynamic.json and dynamic.png."""
    check_noise_seed(args)
    if not 1 <= args.substeps <= 100 or not 0 <= args.coverage <= 100:
        raise UsageError("--substeps must lie in 1-100 and --coverage in 0-100")
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
    if not summary["success"]:
        return not_converged(args.prog, "a solver", out / "dynamic.json")
    return 0


main = Command("experiments.dynamics.inverse", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
