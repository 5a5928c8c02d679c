"""report.md of ``dvs design``: the chosen presses, and their figures beside the
dataset's own design."""

from __future__ import annotations

import numpy as np

from experiments.output.tables import table_lines


def _press_rows(presses: list) -> list[str]:
    cells = []
    for k, press in enumerate(presses, 1):
        contact = ", ".join(f"{v:.2f}" for v in press["contact_mm"])
        force = ", ".join(f"{v:+.3f}" for v in press["force_N"])
        size = float(np.linalg.norm(press["force_N"]))
        cells.append((k, contact, force, f"{size:.3f}", f"{press.get('tilt_deg', 0):.0f}"))
    return table_lines("# | contact [mm] | force [N] | abs force [N] | tilt [deg]", cells)


def _number(value) -> str:
    return "singular" if value is None else f"{value:.4g}"


def _figure_rows(document: dict) -> list[str]:
    new, own = document["predicted"], document["dataset_design"]["predicted"]
    rows = ["| figure | this design | dataset's design |", "|---|---|---|"]
    for name in new["standard_errors"]:
        rows.append(
            f"| std error of {name} (D1) | {_number(new['standard_errors'][name])} | "
            f"{_number(own['standard_errors'][name])} |"
        )
    rows.append(f"| det(F)^(1/p) | {new['det_root']:.4g} | {own['det_root']:.4g} |")
    rows.append(
        f"| sum of squared relative std errors | {_number(new['relative_variance'])} | "
        f"{_number(own['relative_variance'])} |"
    )
    for name, p in new["powers"].items():
        q = own["powers"][name]
        rows.append(
            f"| power for {name} at {p['magnitude']:g} (lambda) | {p['power']:.3f} "
            f"({p['noncentrality']:.3g}) | {q['power']:.3f} ({q['noncentrality']:.3g}) |"
        )
    return rows


def report_text(document: dict) -> str:
    """The whole report.md."""
    candidates, found = document["candidates"], document["search"]
    lines = [
        f"# Design: {document['criterion']}-optimal for {', '.join(document['target'])}",
        "",
        f"{len(document['presses'])} presses"
        + (" (the dataset's, then the new ones)" if document["augment"] else "")
        + f", noise {document['noise_mm']:g} mm, level {document['level']:g}.",
        "",
        *_press_rows(document["presses"]),
        "",
        "## Predicted figures (docs/design.md, eqs. D1-D3)",
        "",
        *_figure_rows(document),
        "",
    ]
    if document.get("det_root_ratio") is not None:
        lines += [
            f"det(F)^(1/p) against the dataset's design: x{document['det_root_ratio']:.3g}.",
            "",
        ]
    for name, goal in document["power_goal"].items():
        if goal["reached"]:
            lines.append(f"- {name}: power reaches 0.9.")
        else:
            more = goal["presses_needed_estimate"]
            hint = (
                f" About {more} such presses would (lambda grows with the presses)." if more else ""
            )
            lines.append(
                f"- {name}: **no design of this budget within the force range reaches power "
                f"0.9**; it needs lambda {goal['noncentrality_needed']:.3g}.{hint} Raise the "
                "budget or the force range, or accept that the effect is not separable here."
            )
    lines += [
        "",
        "## How it was chosen",
        "",
        f"- {candidates['count']} candidate presses: {candidates['contacts']} contacts, the "
        f"normal and {candidates['azimuths']} tilts of {candidates['tilt_deg']:g} deg, forces "
        f"{', '.join(f'{f:g}' for f in candidates['forces_N'])} N; markers within "
        f"{candidates['occlusion_radius_mm']:.2f} mm of a contact count as hidden (the "
        "dataset's rule).",
        f"- Greedy then exchange: score {found['greedy_score']:.5g} -> {found['score']:.5g} "
        f"({found['swaps']} swaps, {found['evaluations']} evaluations, {found['seconds']:.2f} s).",
        f"- Wall time {document['wall_time_s']:.1f} s. The map (design_map.png) shows what one "
        "more press at each contact adds to the dataset's design.",
        "",
    ]
    return "\n".join(lines)
