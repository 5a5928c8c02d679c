"""Transient to steady state on the forehead phantom, against the static equilibrium.

Run ``python -m experiments.dynamics.transient --out DIR`` (``--bench`` adds the timing table).
By default the phantom is the *nonlinear* one (k0 = 50) under the 0.25 N probe, so the
Newton path of the time stepper is exercised; mu = 5e-4 t and gamma = 15 N s/mm are the
phantom's values (docs/transient.md, eq. 13, 16, 22). It

1. solves the static equilibrium (EquilibriumSolver) and times one solve;
2. integrates eq. (22) from rest to steady state with the paper's gamma = 15 and
   compares the end state with the equilibrium;
3. finds the damping gamma* that settles the probe fastest (modal analysis of the
   linear model, ``solvers.transient.modal``) and integrates the nonlinear model with it;
4. writes ``DIR/transient.json`` and ``DIR/transient.png``.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.command.options import Command
from experiments.output.atomic import atomic_savefig, atomic_write_json  # noqa: E402
from experiments.phantom.forehead import TRUE_PARAMETERS, forehead_model, probe_loads  # noqa: E402
from solvers.forward.equilibrium import EquilibriumSolver  # noqa: E402
from solvers.transient.modal import (  # noqa: E402
    StepResponse,
    modal_basis,
    optimal_damping,
    probe_observation,
)
from solvers.transient.steadystate import run_to_steady_state  # noqa: E402
from solvers.transient.stepping import transient_solver  # noqa: E402

PAPER_GAMMA = 15.0
"""The paper's damping for its runs to steady state [N s/mm]."""

DEFAULT_K0 = 50.0
"""Stiffening of the default run: the nonlinear phantom."""


def _best_time(function, repeats: int) -> tuple[float, object]:
    """Smallest wall time of ``repeats`` calls [s] and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def _distance_history(result, model, equilibrium) -> np.ndarray:
    """|B(t) - B_eq| / |B_eq - B0| at every step of a transient."""
    target = equilibrium.positions[model.free] - model.rest[model.free]
    gaps = result.displacements - target[None]
    return np.linalg.norm(gaps.reshape(len(gaps), -1), axis=1) / np.linalg.norm(target)


def _plot(path: Path, curves: list, study, paper_settling: float) -> None:
    """Probe displacement, distance to equilibrium (log) and settling time against gamma."""
    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(15, 4.2))
    for (label, times, probe, distance), color in zip(curves, ("C0", "C3")):
        left.semilogx(times[1:], probe[1:], color=color, label=label)
        middle.loglog(times[1:], np.maximum(distance[1:], 1e-16), color=color, label=label)
    left.set(xlabel="t [s]", ylabel="probe displacement along the force [mm]")
    left.set_title("probe, nonlinear model")
    middle.axhline(0.01, color="0.6", lw=0.8, ls=":")
    middle.set(xlabel="t [s]", ylabel="|B(t) - B_eq| / |B_eq - B0|")
    middle.set_title("distance to the static equilibrium")
    right.loglog(study.gammas, study.settling_times, ".-", color="0.4", label="modal, K0")
    right.plot([study.gamma], [study.settling_time], "o", color="C3")
    right.plot([PAPER_GAMMA], [paper_settling], "o", color="C0")
    right.axvline(study.gamma, color="C3", ls="--", label=f"optimum {study.gamma:.3g}")
    right.axvline(PAPER_GAMMA, color="C0", ls="--", label=f"paper {PAPER_GAMMA:g}")
    right.set(xlabel="gamma [N s/mm]", ylabel="1 % settling time of the probe [s]")
    right.set_title("damping and settling (step load)")
    for axis in (left, middle, right):
        axis.legend(fontsize=8)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def run(
    out: Path,
    model=None,
    force_index: int = -1,
    mu: float | None = None,
    method: str = "generalized_alpha",
    log=print,
) -> dict:
    """Transient from rest to steady state against the static equilibrium.

    Parameters
    ----------
    out : Path
        Output directory for ``transient.json`` and ``transient.png``.
    model : TissueModel, optional
        Default: the forehead phantom with k0 = 50 (nonlinear).
    force_index : int
        Which probe load of ``probe_loads`` (default the last, 0.25 N).
    mu : float, optional
        Mass density [t]; default the model's (5e-4 on the phantom).
    method : str
        Time-stepping scheme for the runs to steady state.
    log : callable
        Progress lines.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model = model or forehead_model(parameters={**TRUE_PARAMETERS, "k0": DEFAULT_K0})
    load = probe_loads(model)[force_index]
    force = model.generalized_force(load)
    mu = model.values()["mu"] if mu is None else float(mu)
    direction = load.force / np.linalg.norm(load.force)
    k0 = model.parameters["k0"]
    log(f"[1/5] static equilibrium: k0 = {k0:g}, |f| = {np.linalg.norm(load.force):g} N")
    start = time.perf_counter()
    static = EquilibriumSolver(model)
    static_build = time.perf_counter() - start
    static_time, equilibrium = _best_time(lambda: static.solve(force), 3)

    log(f"[2/5] transient to steady state, gamma = {PAPER_GAMMA:g}, mu = {mu:g} ({method})")
    start = time.perf_counter()
    transient_solver(model, (), method)
    transient_build = time.perf_counter() - start
    paper_overrides = {"mu": mu, "gamma": PAPER_GAMMA}
    transient_time, paper = _best_time(
        lambda: run_to_steady_state(model, force, overrides=paper_overrides, method=method), 2
    )
    distance = _distance_history(paper, model, equilibrium)

    log("[3/5] modal analysis of K0: the damping that settles fastest")
    study = optimal_damping(model, force, overrides={"mu": mu}, bounds=(0.05, 300.0), samples=81)
    response = StepResponse.build(modal_basis(model, {"mu": mu}), force, probe_observation(model))
    paper_modal = response.settling_time(PAPER_GAMMA)

    log(f"[4/5] transient with the optimal gamma = {study.gamma:.4g}")
    fast = run_to_steady_state(
        model, force, overrides={"mu": mu, "gamma": study.gamma}, method=method
    )
    fast_distance = _distance_history(fast, model, equilibrium)

    summary = {
        "model": {"k0": k0, "force_N": float(np.linalg.norm(load.force)), "mu": mu},
        "method": method,
        "relative_distance_to_equilibrium": float(distance[-1]),
        "settling_time_s": paper.settling_time,
        "probe_settling_time_s": paper.probe_settling_time,
        "steady": paper.steady,
        "steady_time_s": paper.steady_time,
        "steps": paper.steps,
        "newton_iterations": paper.newton_iterations,
        "jacobian_evaluations": paper.jacobian_evaluations,
        "static_newton_iterations": equilibrium.iterations,
        "paper_gamma": PAPER_GAMMA,
        "optimal_gamma": study.gamma,
        "critical_gamma": study.critical_gamma,
        "modal_settling_time_paper_gamma_s": paper_modal,
        "modal_settling_time_optimal_gamma_s": study.settling_time,
        "modal_settling_time_ratio": paper_modal / study.settling_time,
        "optimal_probe_settling_time_s": fast.probe_settling_time,
        "optimal_settling_time_s": fast.settling_time,
        "optimal_relative_distance_to_equilibrium": float(fast_distance[-1]),
        "optimal_steps": fast.steps,
        "measured_settling_time_ratio": paper.probe_settling_time / fast.probe_settling_time,
        "wall_time_transient_s": transient_time,
        "wall_time_static_solve_s": static_time,
        "wall_time_ratio": transient_time / static_time,
        "build_time_transient_s": transient_build,
        "build_time_static_s": static_build,
    }
    log("[5/5] figures and summary")
    curves = [
        (f"gamma = {PAPER_GAMMA:g}", paper.times, paper.probe @ direction, distance),
        (f"gamma* = {study.gamma:.3g}", fast.times, fast.probe @ direction, fast_distance),
    ]
    _plot(out / "transient.png", curves, study, paper_modal)
    atomic_write_json(out / "transient.json", summary)
    log(
        f"end state vs equilibrium: {distance[-1]:.1e} relative; settling "
        f"{paper.settling_time:.3g} s (probe {paper.probe_settling_time:.3g} s) with "
        f"gamma = {PAPER_GAMMA:g}, "
        f"{fast.probe_settling_time:.3g} s with gamma* = {study.gamma:.3g}; transient "
        f"{transient_time:.3g} s = {transient_time / static_time:.0f} x one static solve"
    )
    return summary


def benchmark(repeats: int = 3, log=print) -> list[dict]:
    """Wall time of a run to steady state against one static solve, side by side.

    For the linear and the nonlinear phantom (0.25 N, gamma = 15, mu = 5e-4), both
    solvers built beforehand; the smallest of ``repeats`` runs is kept.
    """
    rows = []
    log(f"{'k0':>5} {'static s':>9} {'transient s':>12} {'steps':>6} {'ratio':>7}")
    for k0 in (0.0, DEFAULT_K0):
        model = forehead_model(parameters={**TRUE_PARAMETERS, "k0": k0})
        force = model.generalized_force(probe_loads(model)[-1])
        solver = EquilibriumSolver(model)
        transient_solver(model, (), "generalized_alpha")
        static_time, _ = _best_time(lambda: solver.solve(force), repeats)  # noqa: B023
        transient_time, result = _best_time(
            lambda: run_to_steady_state(model, force),  # noqa: B023
            repeats,
        )
        ratio = transient_time / static_time
        log(f"{k0:5g} {static_time:9.4f} {transient_time:12.4f} {result.steps:6d} {ratio:7.1f}")
        rows.append(
            {
                "k0": k0,
                "static_s": static_time,
                "transient_s": transient_time,
                "steps": result.steps,
                "ratio": ratio,
            }
        )
    return rows


def build_parser(prog: str = "python -m experiments.dynamics.transient"):
    """The options of ``dvs transient``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=path_argument, default=Path("transient-output"), help="directory"
    )
    parser.add_argument("--k0", type=float, default=DEFAULT_K0, help="stiffening, 0-1000")
    parser.add_argument("--mu", type=float, default=None, help="mass density [t] (> 0)")
    parser.add_argument("--bench", action="store_true", help="print the timing table too")
    return parser


def work(args) -> int:
    """``dvs transient [--out DIR]``: transient.json and transient.png."""
    from experiments.command.options import UsageError, check_output_dir

    if not 0 <= args.k0 <= 1000 or (args.mu is not None and not 0 < args.mu < 1):
        raise UsageError("--k0 must lie in [0, 1000] and --mu in (0, 1) t")
    out = check_output_dir(args.out)
    model = forehead_model(parameters={**TRUE_PARAMETERS, "k0": args.k0})
    summary = run(out, model, mu=args.mu)
    print(
        f"relative distance to equilibrium "
        f"{summary['relative_distance_to_equilibrium']:.2e}, settling time "
        f"{summary['settling_time_s']:.3g} s -> {out / 'transient.json'}"
    )
    if args.bench:
        benchmark()
    return 0


main = Command("experiments.dynamics.transient", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
