"""The demo's sections: each runs one step, writes its JSON and adds its text and figures.

Every section takes ``(out, report, state, log)``: the output folder, the ``Report``,
a dict shared by the steps (the dataset every section after the images uses, and the
numbers that the abstract quotes, under ``state["numbers"]``) and a progress logger.
Sections 3 to 5 use one dataset, the markers reconstructed from the rendered images of
section 2; section 7 states its own, second dataset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output.atomic import atomic_write_json

PAPER = (
    "Estimation of parameters for dynamic volume spline models. Special Issue Papers, "
    "pp. 499-519, published online 6 April 2010."
)
NAMES = ("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")


def _p(value: float) -> str:
    """A p-value for people: below double precision it is "< 1e-300", not 0."""
    return "< 1e-300" if value < 1e-300 else f"{value:.2g}"


def forward(out: Path, report, state: dict, log) -> None:
    """1. The phantom and its forward solution under 0.25 N."""
    from experiments.phantom import forward as script

    summary = script.run(out, force=0.25, log=log)
    state["numbers"]["forward"] = summary
    report.section(
        "The phantom and the forward solution",
        f"""
The tissue is a 40 x 40 mm patch of a sphere of radius 80 mm (a forehead) with 5 mm of
soft tissue, segmented as 15 x 15 x 2 points and fitted by a 9 x 9 x 2 volume spline of
degrees (3, 3, 1), with the inner layer fixed. Its stiffness follows the D-NURBS energy
of the paper {report.cite(PAPER)} with alpha = (2.6, 0.18, 1.7) N/mm, the paper's data
set 2. A 0.25 N point force at the centre moves the skin there by
{summary["probe_displacement_mm"][2]:.3f} mm along the normal (Figure 1). Newton needed
{summary["newton_iterations"]} step (the model is linear at k0 = 0) to a relative
residual of {summary["relative_residual"]:.1e}.

{
            report.figure(
                "forward.png",
                "The phantom under 0.25 N at the centre: normal displacement "
                "of the skin (left) and the section v = 0.5 at rest and loaded (right).",
            )
        }
""",
    )


def images(out: Path, report, state: dict, log) -> None:
    """2. The experiment on rendered images: calibrate, detect, triangulate."""
    from experiments.data.dataset import save_dataset
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
    numbers = {
        "markers": list(dataset.outer_rest.shape[:2]),
        "calibration_rms_px": list(result.calibration.rms_px),
        "reprojection_rms_px": list(result.reprojection_rms_px),
        "rest_error_mean_um": float(rest_error.mean() * 1e3),
        "loaded_error_rms_um": float(np.sqrt(np.mean(error.reshape(-1, 3) ** 2) * 3) * 1e3),
        "hidden_markers": int((~seen[..., 0]).sum()),
        "noise_mm": float(dataset.noise_mm),
    }
    atomic_write_json(out / "images.json", numbers)
    state["dataset"], state["numbers"]["images"] = dataset, numbers
    report.section(
        "The experiment, on images",
        f"""
As in the paper's experiment, a grid of dots on the skin is filmed before and under
each load. Three virtual cameras (0 and +-25 degrees, 200 mm away, 12.5 px/mm after 2 x 2
binning) film the {numbers["markers"][0]} x {numbers["markers"][1]} dots (0.9 mm, blurred,
with sensor noise, uneven light and the probe in front) at rest and under 0.17 N and
0.25 N (Figure 2). The cameras are calibrated from 12 rendered board images (RMS
{", ".join(f"{v:.3f}" for v in numbers["calibration_rms_px"])} px); the dots are detected,
indexed, matched between views and triangulated (reprojection RMS
{", ".join(f"{v:.3f}" for v in numbers["reprojection_rms_px"])} px). Against the phantom's
truth the reconstructed markers are off by {numbers["rest_error_mean_um"]:.1f} um at rest
(mean) and {numbers["loaded_error_rms_um"]:.1f} um RMS under load;
{numbers["hidden_markers"]} loaded markers are hidden by the probe. The pipeline's own
estimate of the marker noise is {numbers["noise_mm"] * 1e3:.2f} um. **This
image-reconstructed dataset is what sections 3 to 5 use.**

{
            report.figure(
                "experiment/cam0_load1.png",
                "Camera 0 under 0.25 N: the dotted skin, "
                "the probe in front, uneven light and sensor noise (rendered).",
            )
        }
""",
    )


def inverse(out: Path, report, state: dict, log) -> None:
    """3. Both formulations, and Table 1 of the paper; 4. identifiability."""
    from experiments.inverse import paper
    from experiments.problem.fitting import FitSettings, fit_dataset, write_fit_outputs

    dataset = state["dataset"]
    fits = {}
    for method in ("simultaneous", "nested"):
        problem, result, analysis, document = fit_dataset(dataset, FitSettings(NAMES), method)
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
        for n in NAMES[:3]
    )
    table = paper.run(out / "paper", log=log, dataset=dataset)
    joint = table["rows"][-1]["parameters"]
    second = table["rows"][1]["parameters"]
    atomic_write_json(out / "inverse.json", {"fits": fits, "agreement": agree})
    state["numbers"]["inverse"] = {"fits": fits, "agreement": agree, "joint": joint}
    rows = "\n".join(
        f"| {m} | {d['solver']['wall_time_s']:.3f} | {d['solver']['iterations']} | "
        f"{d['solver']['forward_solves']} | {d['rms_mm'] * 1e3:.2f} |"
        for m, d in fits.items()
    )
    report.section(
        "The inverse solution",
        f"""
The geometry is rebuilt from the reconstructed rest markers, and the inverse matches the
markers measured under 0.17 N and 0.25 N. Both formulations solve the same problem: the
**simultaneous** one poses the equilibrium K(B)B = F_B of both load cases as equality
constraints of one IPOPT problem, the **nested** one solves the equilibrium inside every
residual evaluation and differentiates it by the implicit function theorem. They agree
to {agree:.1e} (relative) on alpha.

| method | build + solve [s] | iterations | forward solves | RMS [um] |
|---|---|---|---|---|
{rows}

Table 1 of the paper next to separate and joint fits of the image-reconstructed data
(simultaneous method, the paper's parameters and start values):

{table["markdown"]}
The joint standard error of alpha_u ({joint["alpha_u"]["std"]:.3f} N/mm) is not smaller
than data set 2's alone ({second["alpha_u"]["std"]:.3f} N/mm): every load case is measured
against the same rest markers, so their noise is shared by both data sets and does not
average out, and data set 1's smaller force adds little signal.

Verdict of the joint fit: {fits["simultaneous"]["verdict"]["summary"]}.

{
            report.figure(
                "residual_map.png",
                "Marker residuals of the joint simultaneous fit on "
                "the rest skin, one panel per load case; the markers hidden by the probe are "
                "missing.",
            )
        }
{
            report.figure(
                "fitted_section.png",
                "Measured marker displacement along the row through "
                "the dent, and the fitted skin sampled densely along it: the fitted dent's tip "
                "lies between markers.",
            )
        }
""",
    )
    report.section(
        "What the data can tell: identifiability",
        "At the joint estimate (simultaneous method):\n\n```\n"
        + "\n".join(lines)
        + "\n```\n\nmu and gamma drop out of the steady state: static surfaces cannot "
        "determine them, and the report says so instead of printing a number as if it were "
        "an estimate. The smallest singular value belongs to alpha_u.",
    )


def compare(out: Path, report, state: dict, log) -> None:
    """5. Simultaneous, nested and paper-faithful from many starts, on the same data."""
    from experiments.inverse import compare as script
    from experiments.phantom.forehead import TRUE_PARAMETERS
    from experiments.problem.fitting import FitSettings, build_problem

    problem = build_problem(state["dataset"], FitSettings(names=script.ALPHAS))
    log("paper-faithful method: one start, finite differences over transients (a few s)")
    rows = script.compare(problem, starts=10, paper_starts=0, truth=TRUE_PARAMETERS, log=log)
    atomic_write_json(out / "compare.json", rows)
    state["numbers"]["compare"] = rows
    report.section(
        "Simultaneous, nested and paper-faithful, from 10 log-uniform starts",
        f"""
On the same image-reconstructed dataset, each exact method is started from the paper's
start and from 10 log-uniform starts in [0.01, 100] N/mm; the paper-faithful method
(nested, finite differences over transients run to steady state) from the paper's start
only. The error is against the phantom's truth.

{script.table(rows)}""",
    )


def transient(out: Path, report, state: dict, log) -> None:
    """6. The transient from rest against the static equilibrium."""
    from experiments.dynamics import transient as script

    s = script.run(out / "transient", log=log)
    state["numbers"]["transient"] = s
    report.section(
        "The transient against the equilibrium",
        f"""
The nonlinear phantom (k0 = 50) is integrated from rest under a 0.25 N step
({s["method"]}, adaptive steps, {s["steps"]} steps) until velocity and residual vanish.
Its end state equals the static equilibrium from Newton's method to
{s["relative_distance_to_equilibrium"]:.1e} (relative). With the paper's damping
gamma = 15 N s/mm the probe point settles (stays within 1 % of its final displacement)
after {s["probe_settling_time_s"]:.2f} s and the whole shape after
{s["settling_time_s"]:.1f} s. The damping that settles fastest, from the modal analysis
K phi = omega^2 M phi, is gamma* = {s["optimal_gamma"]:.4f} N s/mm (critical damping of
the lowest mode: {s["critical_gamma"]:.4f}). With it the probe settles after
{s["optimal_probe_settling_time_s"]:.3f} s and the shape after
{s["optimal_settling_time_s"]:.3f} s: {s["measured_settling_time_ratio"]:.0f} times
faster at the probe on the nonlinear model ({s["modal_settling_time_ratio"]:.0f} times on
the linearised one). The transient costs {s["wall_time_ratio"]:.0f} static solves.

{
            report.figure(
                "transient/transient.png",
                "Transient from rest under a 0.25 N step: probe "
                "displacement, distance to the equilibrium (log scale), and the probe's "
                "settling time against gamma.",
            )
        }
""",
    )


def diagnosis(out: Path, report, state: dict, log) -> None:
    """7. A second dataset with an undeclared rigid motion, diagnosed."""
    from experiments.data.dataset import save_dataset
    from experiments.diagnosis import diagnose
    from experiments.phantom.simulate import simulate_with_effects

    dataset = simulate_with_effects({"rigid_motion": 0.1}, noise_mm=0.02, seed=1)
    save_dataset(out / "hidden-effect.npz", dataset)
    document = diagnose.run(out / "hidden-effect.npz", out / "diagnosis", log=log)
    state["numbers"]["diagnosis"] = document
    rows = "\n".join(
        f"| {step['effect'] or 'base model'} | {step['rms_mm'] * 1e3:.1f} | "
        f"{step['residual_statistic']:.0f} / {step['residual_dof']} | "
        f"{_p(step['residual_p_value'])} | "
        + ("-" if step["effect"] is None else f"{step['statistic']:.0f} (p {_p(step['p_value'])})")
        + " |"
        for step in document["steps"]
    )
    outcome = (
        "the residual is consistent with the noise"
        if not document["unexplained"]
        else "the residual is still significantly above the noise"
    )
    report.section(
        "Closing the loop: a hidden effect",
        f"""
**A second dataset**, simulated (not rendered) with 20 um of marker noise, hides an
effect it does not declare: between the two captures the head moved by 0.1 mm (a rigid
motion). The diagnosis fits the base model, tests the residual against the noise
(chi-square), ranks every candidate effect of the library by a score test at theta = 0
(no refit per candidate), adds the best significant one, refits, and stops when nothing
more is significant.

| step | RMS [um] | residual chi^2 / dof | residual p | selecting score statistic |
|---|---|---|---|---|
{rows}

The score statistic selects the effect; the residual test after the refit is what
justifies the verdict. Selected: **{", ".join(document["selected"]) or "nothing"}**;
RMS {document["rms_before_mm"] * 1e3:.1f} -> {document["rms_after_mm"] * 1e3:.1f} um
against {document["noise_rms_mm"] * 1e3:.1f} um of noise alone, so {outcome}. This design
(two loads at one contact) could not have separated every effect:
{document["design"]["note"]}. Full report: [diagnosis/report.md](diagnosis/report.md).

{
            report.figure(
                "diagnosis/residuals.png",
                "Marker residuals of the hidden-effect dataset "
                "before (base model, left) and after the diagnosis (right), per load case.",
            )
        }
""",
    )
