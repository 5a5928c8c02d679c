"""Markdown tables of the real-skin study (``parameters.md``) from its summary dict."""

from __future__ import annotations

import math

UNITS = {
    "alpha_u": "N/mm",
    "alpha_w": "N/mm",
    "k0": "1",
    "region_ratio": "1",
    "anisotropy": "1",
    "poisson": "1",
}


def _number(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}g}"


def errors_table(summary: dict, cases) -> list[str]:
    """RMS errors of every stage, next to the DIC noise."""
    lines = [
        "| case | model | RMS displacement [mm] | DIC noise [mm] | RMS force [N] | cost [mm^2] |",
        "|---|---|---|---|---|---|",
    ]
    for name in cases:
        case = summary[name]
        for stage in case["stages"]:
            lines.append(
                f"| {name} | {stage['label']} | {stage['rms_displacement_mm']:.4f} | "
                f"{case['dic_noise_mm']:.4f} | {stage['rms_force_N']:.4f} | {stage['cost']:.1f} |"
            )
        for stage in case["variants"].values():
            lines.append(
                f"| {name} | variant: {stage['label']} | {stage['rms_displacement_mm']:.4f} | "
                f"{case['dic_noise_mm']:.4f} | {stage['rms_force_N']:.4f} | {stage['cost']:.1f} |"
            )
    return lines


def parameters_table(summary: dict, cases) -> list[str]:
    """Estimates with standard errors of every stage."""
    lines = ["| case | model | parameter | estimate | std | unit |", "|---|---|---|---|---|---|"]
    for name in cases:
        for stage in summary[name]["stages"]:
            for parameter, value in stage["estimates"].items():
                std = "at bound" if value["at_bound"] else _number(value["std"], 2)
                lines.append(
                    f"| {name} | {stage['label']} | {parameter} | {_number(value['value'], 4)} "
                    f"| {std} | {UNITS.get(parameter, '')} |"
                )
    return lines


def scores_table(summary: dict, cases) -> list[str]:
    """Score tests per round, and the diagnostics at the final model."""
    lines = [
        "| case | round | candidate | score T | p | predicted decrease [mm^2] | "
        "direction | chosen |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in cases:
        rounds = summary[name]["rounds"]
        for index, entry in enumerate(rounds, start=1):
            for candidate, score in entry["scores"].items():
                lines.append(
                    f"| {name} | {index} | {candidate} | {_number(score['statistic'])} | "
                    f"{_number(score['p_value'], 2)} | {_number(score['predicted_decrease'])} | "
                    f"{score['direction']:+.0f} | {'yes' if entry['chosen'] == candidate else ''} |"
                )
        for candidate, score in summary[name]["diagnostics"].items():
            lines.append(
                f"| {name} | final (diagnostic) | {candidate} | {_number(score['statistic'])} | "
                f"{_number(score['p_value'], 2)} | {_number(score['predicted_decrease'])} | "
                f"{score['direction']:+.0f} | not a candidate |"
            )
    return lines


def authors_table(summary: dict, cases) -> list[str]:
    """Our membrane tensions next to the authors' E and shear modulus E / (2 (1 + nu))."""
    lines = [
        "| case | model | T outside [N/mm] | T inside [N/mm] | k0 | authors E | "
        "authors E/(2(1+nu)) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in cases:
        authors = summary[name]["authors"]
        e_lo, e_hi = authors["E"]
        nu_lo, nu_hi = authors["nu"]
        shear = (e_lo / (2 * (1 + nu_hi)), e_hi / (2 * (1 + nu_lo)))
        for stage in summary[name]["stages"]:
            values = stage["physical"]
            lines.append(
                f"| {name} | {stage['label']} | {_number(values['tension_N_per_mm'])} | "
                f"{_number(values.get('tension_inside_N_per_mm'))} | {_number(values['k0'])} | "
                f"{e_lo:g}-{e_hi:g} | {shear[0]:.3f}-{shear[1]:.3f} |"
            )
    return lines


def heterogeneity_table(summary: dict, cases) -> list[str]:
    """The region the scan chose, its ratio and its overlap with the keloid outline."""
    lines = [
        "| case | found region x [mm] | y [mm] | ratio | rectangles | inside outline | "
        "IoU | centroid inside | chance |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in cases:
        found = summary[name].get("heterogeneity")
        if not found:
            lines.append(f"| {name} | not added | | | | | | | |")
            continue
        r, o = found["rect_mm"], found.get("overlap")
        cells = (
            f"{o['inside_fraction']:.2f} | {o['iou']:.2f} | {o['centroid_inside']} | "
            f"{o['chance']:.2f}"
            if o
            else "- | - | - | -"
        )
        lines.append(
            f"| {name} | {r['x0']:.1f}-{r['x1']:.1f} | {r['y0']:.1f}-{r['y1']:.1f} | "
            f"{_number(found['ratio'])} | {found['candidates']} | {cells} |"
        )
    return lines


def map_table(summary: dict, cases) -> list[str]:
    """The cell map: dof, cells departing from the mean, outline overlap, strain."""
    lines = [
        "| case | stage | dof | stiffer / softer cells (z > 2) | Bonferroni | inside outline "
        "(chance) | IoU | centroid inside, distance [mm] | corr(map, strain) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in cases:
        found = summary[name].get("map")
        if found is None:
            continue
        cells, outline = found["cells"], found["outline"] or {}
        inside = outline.get("inside_fraction")
        lines.append(
            f"| {name} | {found['stage']} | {found['effective_dof']:.1f} | "
            f"{cells['stiffer']} / {cells['softer']} of {cells['n_cells']} | "
            f"{cells['stiffer_bonferroni']} / {cells['softer_bonferroni']} "
            f"(z > {cells['bonferroni_level']:.2f}) | "
            + (f"{inside:.2f} ({outline['chance']:.2f})" if inside is not None else "-")
            + f" | {_number(outline.get('iou'), 2)} | {outline.get('centroid_inside', '-')}, "
            f"{_number(outline.get('centroid_distance_mm'), 3)} | "
            f"{_number(found['strain']['pearson'], 2)} |"
        )
    return lines


def report(summary: dict) -> str:
    """The whole ``parameters.md``."""
    cases = [c for c in ("healthy", "keloid") if c in summary]
    parts = [
        "# Real skin: fitted parameters and errors",
        "",
        "Written by `dvs realskin fit`; see docs/realskin.md.",
        "",
        "## Errors before and after",
        "",
        *errors_table(summary, cases),
        "",
        "## Estimates (std from the Gauss-Newton information, residual-based sigma)",
        "",
        *parameters_table(summary, cases),
        "",
        "## Score tests",
        "",
        *scores_table(summary, cases),
        "",
        "## The heterogeneity found by the scan (outline used only for the overlap)",
        "",
        *heterogeneity_table(summary, cases),
        "",
        "## The cell map (outline and strain used only for the comparison)",
        "",
        *map_table(summary, cases),
        "",
        "## Against the original authors (2D neo-Hookean)",
        "",
        *authors_table(summary, cases),
        "",
    ]
    return "\n".join(parts)
