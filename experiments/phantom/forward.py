"""Forward solution on the default forehead phantom: the deformed shape under a known force.

Run ``python -m experiments.phantom.forward --out DIR``. It builds the phantom, solves
the static equilibrium under 0.25 N at the centre, prints the probe
displacement and writes ``DIR/forward.png`` and ``DIR/forward.json``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.output.atomic import atomic_write_json
from experiments.output.plots import plot_deformation
from experiments.phantom.forehead import PhantomSettings, forehead_model, probe_loads
from solvers.forward.equilibrium import EquilibriumSolver


def run(out: Path, force: float = 0.25, k0: float = 0.0, log=print) -> dict:
    """Solve the phantom under ``force`` [N] and write the figure and summary."""
    start = time.perf_counter()
    settings = PhantomSettings(forces=(force,))
    model = forehead_model(settings)
    if k0:
        model = forehead_model(settings, {**model.parameters, "k0": k0})
    solver = EquilibriumSolver(model)
    load = probe_loads(model, settings)[0]
    built = time.perf_counter()
    result = solver.solve(model.generalized_force(load))
    solved = time.perf_counter()
    center = model.volume.outer_params(np.array([[0.5, 0.5]]))
    probe = (model.volume.collocation(center) @ (result.positions - model.rest))[0]
    summary = {
        "force_N": force,
        "k0": k0,
        "probe_displacement_mm": probe.tolist(),
        "max_control_point_displacement_mm": float(np.abs(result.positions - model.rest).max()),
        "newton_iterations": result.iterations,
        "relative_residual": result.residual_history[-1],
        "build_time_s": built - start,
        "solve_time_s": solved - built,
    }
    out.mkdir(parents=True, exist_ok=True)
    plot_deformation(
        model.volume, result.positions, out / "forward.png", f"forehead phantom under {force} N"
    )
    atomic_write_json(out / "forward.json", summary)
    log(
        f"probe displacement under {force} N: {probe[2]:+.4f} mm (normal), "
        f"{result.iterations} Newton step(s), build {summary['build_time_s']:.3f} s, "
        f"solve {summary['solve_time_s']:.3f} s -> {out / 'forward.png'}"
    )
    return summary


def build_parser(prog: str = "python -m experiments.phantom.forward"):
    """The options of ``dvs study forward``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "Forward solve of the forehead phantom under a probe force.")
    parser.add_argument(
        "--out", type=path_argument, default=Path("forward-output"), help="directory"
    )
    parser.add_argument("--force", type=float, default=0.25, help="probe force, 0-5 [N]")
    parser.add_argument("--k0", type=float, default=0.0, help="stiffening parameter, 0-1000")
    return parser


def work(args) -> int:
    """``dvs study forward --out DIR [--force N] [--k0 K]``."""
    from experiments.command.options import UsageError, check_output_dir

    if not 0 < args.force <= 5 or not 0 <= args.k0 <= 1000:
        raise UsageError("--force must lie in (0, 5] N and --k0 in [0, 1000]")
    run(check_output_dir(args.out), args.force, args.k0)
    return 0


main = Command("experiments.phantom.forward", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
