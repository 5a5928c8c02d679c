"""The Truth Cube study's tables as Markdown (``report.md``; docs/truthcube.md)."""

from __future__ import annotations


def _row(cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _mm(values) -> list[str]:
    return [f"{v:.3f}" for v in values]


def report_text(result: dict) -> str:
    """The study's tables: noise, fits, loop, leave-one-state-out, checks."""
    states = result["states"]
    noise = result["noise"]
    lines = [
        "# Truth Cube: nu from the beads, through the shared models and loop",
        "",
        f"Grid {result['settings']['shape']}, degree {result['settings']['degree']}; "
        f"study {result['seconds']:.0f} s.",
        "",
        "## Bead-location noise (rest lattice scatter)",
        "",
        _row(["map of the bead index", "x [mm]", "y [mm]", "z [mm]"]),
        _row(["---"] * 4),
        _row(["affine", *_mm(noise["affine_mm"])]),
        _row(["quadratic", *_mm(noise["quadratic_mm"])]),
        "",
        f"Noise RMS bead distance (quadratic map): {noise['rms_distance_mm']:.3f} mm; "
        f"2x: {2 * noise['rms_distance_mm']:.3f} mm.",
        "",
        "## Fits to all three states",
        "",
        _row(
            [
                "energy, plate",
                "nu",
                "SE(nu)",
                *[f"RMS {s} [mm]" for s in states],
                "plate, last state",
            ]
        ),
        _row(["---"] * (4 + len(states))),
    ]
    for fit in result["fits"]:
        plate = ", ".join(f"{v:.3g}" for v in fit["plate"][-1])
        name = f"{fit['energy']}, {fit['contact']}"
        lines.append(
            _row(
                [name, f"{fit['nu']:.4f}", f"{fit['nu_se']:.4f}", *_mm(fit["rms_mm"]), f"({plate})"]
            )
        )
    measured = result["fits"][0]["bulge_measured"]
    lines += [
        "",
        "Plate: t_x, t_y, t_z [mm, model frame: z from the base up], and b [1] when slipping.",
        "",
        f"## Lateral expansion per bead layer, {states[-1]} (slope of u_h on x_h) [%]",
        "",
        _row(["layer (1: base side, 7: plate side)", *range(1, len(measured) + 1)]),
        _row(["---"] * (1 + len(measured))),
        _row(["measured", *[f"{100 * b:.2f}" for b in measured]]),
    ]
    for fit in result["fits"]:
        name = f"{fit['energy']}, {fit['contact']}"
        lines.append(_row([name, *[f"{100 * b:.2f}" for b in fit["bulge_model"]]]))
    loop = result["loop"]
    lines += [
        "",
        f"## The loop ({loop['energy']} base, {loop['contact']} plate; "
        f"sigma {loop['sigma_mm']:.3f} mm, estimated)",
        "",
        _row(["model", "nu", *[f"RMS {s} [mm]" for s in states], "RMS all [mm]"]),
        _row(["---"] * (3 + len(states))),
    ]
    for step in loop["steps"]:
        nu = "-" if step["nu"] is None else f"{step['nu']:.4f}"
        lines.append(_row([step["effect"], nu, *_mm(step["rms_mm"]), f"{step['rms_all_mm']:.3f}"]))
    lines += [
        "",
        "## Leave one state out (RMS bead distance of the held-out state [mm])",
        "",
        _row(["model", *[f"{s} held out" for s in states]]),
        _row(["---"] * (1 + len(states))),
    ]
    for fit in result["fits"]:
        folds = fit["leave_one_out"]
        if not folds:
            continue
        name = f"{fit['energy']}, {fit['contact']}"
        lines.append(_row([f"{name}, plate fitted", *_mm(f["rms_plate_fitted_mm"] for f in folds)]))
        if folds[0].get("rms_plate_split_mm") is not None:
            halves = _mm(f["rms_plate_split_mm"] for f in folds)
            lines.append(_row([f"{name}, plate from the other half", *halves]))
        lines.append(
            _row(
                [f"{name}, plate extrapolated", *_mm(f["rms_plate_extrapolated_mm"] for f in folds)]
            )
        )
        lines.append(_row([f"{name}, nu of the fold", *[f"{f['nu']:.4f}" for f in folds]]))
    lines.append(_row(["loop's final model", *_mm(loop["final_left_out_rms_mm"])]))
    if "contact" in result:
        lines += ["", "## The plate's contact, decided out of sample", ""]
        lines += contact_lines(result["contact"], states)
    if "twins" in result:
        lines += ["", "## Synthetic twins (scikit-fem P2, planted nu and contact)", ""]
        lines += twin_lines(result["twins"])
    if "fem_comparison" in result:
        lines += [
            "",
            "## Spline against scikit-fem (P2, finest mesh), bead displacements",
            "",
            _row(["nu", "model", "RMS difference [mm]", "max [mm]", "displacement RMS [mm]"]),
            _row(["---"] * 5),
        ]
        for row in result["fem_comparison"]:
            lines.append(
                _row(
                    [
                        row["nu"],
                        row["model"],
                        f"{row['rms_difference_mm']:.3f}",
                        f"{row['max_difference_mm']:.3f}",
                        f"{row['displacement_rms_mm']:.2f}",
                    ]
                )
            )
        lines += [
            "",
            "## nu by grid (linear energy)",
            "",
            _row(["grid", "nu", "SE", *[f"RMS {s}" for s in states], "s"]),
            _row(["---"] * (4 + len(states))),
        ]
        for row in result["grid_study"]:
            lines.append(
                _row(
                    [
                        row["grid"],
                        f"{row['nu']:.4f}",
                        f"{row['nu_se']:.4f}",
                        *_mm(row["rms_mm"]),
                        f"{row['seconds']:.0f}",
                    ]
                )
            )
    return "\n".join(lines) + "\n"


def contact_lines(decision: dict, states: list) -> list[str]:
    """The contact decision: left-out RMS per contact and state, z, the contact named."""
    lines = [
        _row(["contact", *[f"{s} held out [mm]" for s in states], "all [mm]"]),
        _row(["---"] * (2 + len(states))),
    ]
    for contact, rms in decision["left_out_rms"].items():
        lines.append(_row([contact, *_mm(rms["states_mm"]), f"{rms['all_mm']:.3f}"]))
    verdict = "beyond chance" if decision["distinguished"] else "within chance"
    lines += [
        "",
        f"{decision['energy']} energy, plate from the other half of the held state's beads; "
        f"bonded - slip squared distance {decision['difference_mm2']:.4f} +- "
        f"{decision['difference_se_mm2']:.4f} mm^2 over {decision['beads']} beads, "
        f"z = {decision['z']:.2f} ({verdict}): **{decision['named']}** named.",
    ]
    return lines


def twin_lines(twins: list) -> list[str]:
    """Per twin: the contact planted and named, nu +- SE of both contacts, left-out RMS
    of both, the named contact's nu on the noise-free twin."""
    lines = [
        _row(
            [
                "planted",
                "named",
                "z",
                "nu planted",
                "nu bonded",
                "nu slip",
                "left-out bonded [mm]",
                "left-out slip [mm]",
                "nu noise-free (named)",
            ]
        ),
        _row(["---"] * 9),
    ]
    for twin in twins:
        decision, fits = twin["decision"], twin["fits"]
        lines.append(
            _row(
                [
                    twin["planted"],
                    decision["named"],
                    f"{decision['z']:.2f}",
                    f"{twin['nu_planted']:.3f}",
                    *[f"{fits[c]['nu']:.4f} +- {fits[c]['nu_se']:.4f}" for c in ("bonded", "slip")],
                    *[f"{decision['left_out_rms'][c]['all_mm']:.3f}" for c in ("bonded", "slip")],
                    f"{twin['nu_noise_free']:.4f}",
                ]
            )
        )
    noise = ", ".join(f"{v:.3f}" for v in twins[0]["noise_mm"])
    lines += [
        "",
        f"Noise per component ({noise}) mm on rest and loaded beads; FE mesh "
        f"{twins[0]['cells']}^3 cells; {twins[0]['energy']} energy.",
    ]
    return lines
