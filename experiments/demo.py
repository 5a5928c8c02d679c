"""The main job, ``dvs demo`` / ``make demo``: the paper, end to end, on the phantom.

Each step prints a progress line and adds a section to ``DIR/report.md``
(figures beside it, JSON for every number). The steps:

1. the forehead phantom and its forward solution under 0.25 N;
2. the experiment: markers measured before and under 0.17 N and 0.25 N;
3. the inverse by both formulations, separately and jointly (Table 1);
4. the identifiability report;
5. simultaneous vs nested, side by side;
6. the transient from rest against the static equilibrium, and the best damping;
7. the diagnosis loop on data with an undeclared effect.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from experiments.atomic import atomic_write_json, atomic_write_text


class Report:
    """Markdown sections collected in order, written once at the end."""

    def __init__(self, title: str) -> None:
        self.parts = [f"# {title}\n"]

    def section(self, heading: str, text: str) -> None:
        """Append a section."""
        self.parts.append(f"\n## {heading}\n\n{text.strip()}\n")

    def write(self, path: Path) -> None:
        """Write report.md atomically."""
        atomic_write_text(path, "".join(self.parts))


def _forward(out: Path, report: Report, log) -> dict:
    from experiments.phantom import forward

    summary = forward.run(out, force=0.25, log=log)
    report.section(
        "1. The phantom and the forward solution",
        f"""
A 40 x 40 mm patch of a sphere of radius 80 mm with 5 mm of soft tissue, segmented as
15 x 15 x 2 points and fitted by a 9 x 9 x 2 volume spline of degrees (3, 3, 1); the
inner layer is fixed. With alpha = (2.6, 0.18, 1.7) N/mm, a 0.25 N point force at the
centre moves the skin there by {summary["probe_displacement_mm"][2]:.3f} mm along the
normal. Newton needed {summary["newton_iterations"]} step (the model is linear at k0 = 0)
to reach a relative residual of {summary["relative_residual"]:.1e}; building the model took
{summary["build_time_s"]:.3f} s and the solve {summary["solve_time_s"]:.3f} s.

![forward](forward.png)
""",
    )
    return summary


def _images(out: Path, report: Report, log) -> dict:
    from experiments.dataset import save_dataset
    from experiments.phantom.simulate import SimulationSettings, simulate
    from experiments.stereo.reconstruct import reconstruct
    from experiments.stereo.render import write_synthetic_experiment
    from experiments.stereo.rig import RigSettings

    folder = out / "experiment"
    write_synthetic_experiment(folder, rig=RigSettings(scale=0.5))
    log("rendered the rig's images (3 cameras, 12 board poses, rest and two loads)")
    result = reconstruct(folder, progress=log)
    dataset = result.dataset
    save_dataset(out / "reconstructed.npz", dataset)
    truth = simulate(measurement=SimulationSettings(noise_mm=0.0, missing_fraction=0.0))
    seen = np.isfinite(dataset.outer_loaded)
    error = dataset.outer_loaded[seen] - truth.outer_loaded[seen]
    rest_error = np.linalg.norm(dataset.outer_rest - truth.outer_rest, axis=-1)
    rms = float(np.sqrt(np.mean(error.reshape(-1, 3) ** 2) * 3))
    _STATE["dataset"] = dataset
    report.section(
        "2. The experiment, on images",
        f"""
Three virtual cameras (0 and +-25 degrees, 200 mm away, 12.5 px/mm after 2 x 2 binning)
film the 9 x 9 dots (0.9 mm, blurred, with sensor noise, uneven light and the probe in
front) before and under each load. The cameras are calibrated from 12 rendered board
images (RMS {", ".join(f"{v:.3f}" for v in result.calibration.rms_px)} px); the dots are
detected, indexed, matched between views and triangulated
(reprojection RMS {", ".join(f"{v:.3f}" for v in result.reprojection_rms_px)} px).
Against the truth, the reconstructed markers are off by {rest_error.mean() * 1e3:.1f} um at rest
(mean) and {rms * 1e3:.1f} um RMS under load; {int((~seen[..., 0]).sum())} loaded markers are
hidden by the probe. This dataset is what the inverse below sees.

![camera 0 under 0.25 N](experiment/cam0_load1.png)
""",
    )
    return {"marker_rms_mm": rms}


_STATE: dict = {}


def _inverse(out: Path, report: Report, log) -> dict:
    from experiments.fitting import FitSettings, fit_dataset, write_fit_outputs
    from experiments.inverse import paper
    from experiments.phantom.simulate import simulate

    dataset = _STATE.get("dataset") or simulate()
    fits = {}
    for method in ("simultaneous", "nested"):
        problem, result, analysis, document = fit_dataset(
            dataset, FitSettings(names=("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")), method
        )
        fits[method] = document
        if method == "simultaneous":
            write_fit_outputs(out, problem, result, document)
            lines = analysis.summary_lines()
    agree = max(
        abs(
            fits["simultaneous"]["parameters"][n]["value"]
            / fits["nested"]["parameters"][n]["value"]
            - 1
        )
        for n in ("alpha_u", "alpha_v", "alpha_w")
    )
    table = paper.run(out / "paper", log=log, dataset=dataset)
    atomic_write_json(out / "inverse.json", fits)
    report.section(
        "3. The inverse solution",
        f"""
The geometry is rebuilt from the reconstructed rest markers; the inverse matches the
markers measured under 0.17 N and 0.25 N.

Both formulations solve the same problem: the **simultaneous** one poses the equilibrium
K(B)B = F_B of both load cases as equality constraints of one IPOPT problem, the
**nested** one solves the equilibrium inside every residual evaluation and differentiates
it by the implicit function theorem. They agree to {agree:.1e} (relative) on alpha.

| method | build + solve [s] | iterations | forward solves | RMS [um] |
|---|---|---|---|---|
"""
        + "\n".join(
            f"| {m} | {d['solver']['wall_time_s']:.3f} | {d['solver']['iterations']} | "
            f"{d['solver']['forward_solves']} | {d['rms_mm'] * 1e3:.1f} |"
            for m, d in fits.items()
        )
        + f"""

Table 1 of the paper, next to separate and joint fits on the synthetic data
(simultaneous method, the paper's parameters and start values):

{table["markdown"]}

![residuals](residual_map.png)
""",
    )
    report.section(
        "4. What the data can tell: identifiability",
        "At the joint estimate (simultaneous method):\n\n```\n"
        + "\n".join(lines)
        + "\n```\n\nmu and gamma drop out of the steady state: static surfaces cannot "
        "determine them, and the report says so instead of printing a number as if it were "
        "an estimate. The smallest singular value belongs to alpha_u.",
    )
    return fits


def _compare(out: Path, report: Report, log) -> dict:
    from experiments.fitting import FitSettings, build_problem
    from experiments.inverse import compare
    from experiments.phantom.forehead import TRUE_PARAMETERS
    from experiments.phantom.simulate import simulate

    problem = build_problem(simulate(), FitSettings(names=compare.ALPHAS))
    rows = compare.compare(
        problem, starts=10, truth=TRUE_PARAMETERS, methods=("simultaneous", "nested"), log=log
    )
    atomic_write_json(out / "compare.json", rows)
    report.section(
        "5. Simultaneous against nested, from 10 log-uniform starts",
        compare.table(rows)
        + "\nThe paper-faithful nested method (finite differences over transients to steady "
        "state) is left out of the demo for time: it needs about two minutes for one start. "
        "Run `dvs compare` or `make bench` for it.",
    )
    return rows


def _transient(out: Path, report: Report, log) -> dict:
    from experiments.dynamics import transient

    summary = transient.run(out / "transient", log=log)
    report.section(
        "6. The transient against the equilibrium",
        f"""
The nonlinear phantom (k0 = 50) is integrated from rest under a 0.25 N step
({summary["method"]}, adaptive steps, {summary["steps"]} steps) until velocity and residual
vanish. Its end state equals the static equilibrium from Newton's method to
{summary["relative_distance_to_equilibrium"]:.1e} (relative). With the paper's damping
gamma = 15 the skin needs {summary["settling_time_s"]:.1f} s to stay within 1 % of its final
shape. The damping that settles fastest, from the modal analysis K phi = omega^2 M phi,
is gamma* = {summary["optimal_gamma"]:.4f} N s/mm (critical damping of the lowest mode:
{summary["critical_gamma"]:.4f}); on the linearised model it settles
{summary["modal_settling_time_ratio"]:.0f} times faster than gamma = 15, and
{summary["measured_settling_time_ratio"]:.0f} times faster on the nonlinear model.
The transient costs {summary["wall_time_ratio"]:.0f} static solves.

![transient](transient/transient.png)
""",
    )
    return summary


def _diagnosis(out: Path, report: Report, log) -> dict:
    from experiments.dataset import save_dataset
    from experiments.diagnosis import diagnose
    from experiments.phantom.simulate import simulate_with_effects

    hidden = {"rigid_motion": 0.1}
    dataset = simulate_with_effects(hidden, noise_mm=0.02, seed=1)
    save_dataset(out / "hidden-effect.npz", dataset)
    document = diagnose.run(out / "hidden-effect.npz", out / "diagnosis", log=log)
    steps = "\n".join(
        f"| {step['effect'] or 'base model'} | {step['rms_mm'] * 1e3:.1f} | "
        f"{step['statistic']:.1f} | {step['p_value']:.2g} |"
        for step in document["steps"]
    )
    report.section(
        "7. Closing the loop: a hidden effect",
        f"""
A second dataset hides an effect it does not declare: between the two captures the head
moved by 0.1 mm (a rigid motion). The diagnosis fits the base model, tests the residual
against the noise (chi-square), ranks every candidate effect of the library by a score
test at theta = 0 (no refit per candidate), adds the best significant one, refits, and
stops when the residual is consistent with the noise.

| step | RMS [um] | statistic | p-value |
|---|---|---|---|
{steps}

Selected: **{", ".join(document["selected"]) or "nothing"}**; RMS
{document["rms_before_mm"] * 1e3:.1f} -> {document["rms_after_mm"] * 1e3:.1f} um against a
pure-noise RMS of {0.02 * 6**0.5 * 1e3:.1f} um; unexplained: {document["unexplained"]}.
Full report: [diagnosis/report.md](diagnosis/report.md).

![residuals before and after](diagnosis/residuals.png)
""",
    )
    return document


STEPS = (
    ("forward solution of the phantom", _forward),
    ("the experiment on images: render, calibrate, detect, triangulate", _images),
    ("inverse (simultaneous, nested; separate and joint)", _inverse),
    ("multi-start comparison of the formulations", _compare),
    ("transient from rest against the static equilibrium", _transient),
    ("diagnosis of data with an undeclared effect", _diagnosis),
)


def run(out: Path) -> int:
    """Run the demo into ``out``; returns the exit code."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report = Report("Estimating the parameters of a dynamic volume spline model: the demo")
    start = time.perf_counter()
    timings = {}
    for k, (label, step) in enumerate(STEPS, start=1):
        print(f"[{k}/{len(STEPS)}] {label}", flush=True)
        begin = time.perf_counter()
        step(out, report, lambda *a: print("     ", *a, flush=True))
        timings[label] = time.perf_counter() - begin
    total = time.perf_counter() - start
    report.section(
        "Timing",
        "\n".join(f"- {label}: {seconds:.1f} s" for label, seconds in timings.items())
        + f"\n- total: {total:.1f} s",
    )
    report.write(out / "report.md")
    atomic_write_json(out / "timings.json", {**timings, "total": total})
    print(f"done in {total:.1f} s -> {out / 'report.md'}")
    return 0 if np.isfinite(total) else 1


def build_parser(prog: str = "python -m experiments.demo"):
    """The options of ``dvs demo``."""
    from experiments.options import make_parser, path_argument

    parser = make_parser(prog, "The main job: the paper, end to end, on the phantom.")
    parser.add_argument(
        "--out", type=path_argument, default=Path("demo-output"), help="output directory"
    )
    return parser


def main(argv: list[str] | None = None, prog: str = "python -m experiments.demo") -> int:
    """``dvs demo [--out DIR]``."""
    from experiments.options import check_output_dir, run_guarded

    args = build_parser(prog).parse_args(argv)
    return run_guarded(prog, lambda: run(check_output_dir(args.out)))


if __name__ == "__main__":
    raise SystemExit(main())
