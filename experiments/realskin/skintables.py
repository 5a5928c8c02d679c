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


def _row(*cells) -> str:
    """One markdown row: ``| a | b |``."""
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def _table(header: str, summary: dict, cases, rows) -> list[str]:
    """A markdown table: ``header`` (the column names joined by " | "), then per case its
    name before each tuple of cells that ``rows(summary[name])`` yields."""
    lines = [f"| {header} |", "|" + "---|" * (header.count("|") + 1)]
    for name in cases:
        lines.extend(_row(name, *cells) for cells in rows(summary[name]))
    return lines


def _errors(case: dict):
    stages = [(stage["label"], stage) for stage in case["stages"]]
    stages += [(f"variant: {stage['label']}", stage) for stage in case["variants"].values()]
    for label, stage in stages:
        yield (
            label,
            f"{stage['rms_displacement_mm']:.4f}",
            f"{case['dic_noise_mm']:.4f}",
            f"{stage['rms_force_N']:.4f}",
            f"{stage['cost']:.1f}",
        )


def errors_table(summary: dict, cases) -> list[str]:
    """RMS errors of every stage, next to the DIC noise."""
    header = "case | model | RMS displacement [mm] | DIC noise [mm] | RMS force [N] | cost [mm^2]"
    return _table(header, summary, cases, _errors)


def _estimates(case: dict):
    for stage in case["stages"]:
        for parameter, value in stage["estimates"].items():
            std = "at bound" if value["at_bound"] else _number(value["std"], 2)
            unit = UNITS.get(parameter, "")
            yield stage["label"], parameter, _number(value["value"], 4), std, unit


def parameters_table(summary: dict, cases) -> list[str]:
    """Estimates with standard errors of every stage."""
    return _table("case | model | parameter | estimate | std | unit", summary, cases, _estimates)


def _score_cells(score: dict) -> tuple[str, ...]:
    """Statistic, p-value, predicted cost decrease and direction of one score test."""
    return (
        _number(score["statistic"]),
        _number(score["p_value"], 2),
        _number(score["predicted_decrease"]),
        f"{score['direction']:+.0f}",
    )


def _scores(case: dict):
    for index, entry in enumerate(case["rounds"], start=1):
        for candidate, score in entry["scores"].items():
            chosen = "yes" if entry["chosen"] == candidate else ""
            yield index, candidate, *_score_cells(score), chosen
    for candidate, score in case["diagnostics"].items():
        yield "final (diagnostic)", candidate, *_score_cells(score), "not a candidate"


def scores_table(summary: dict, cases) -> list[str]:
    """Score tests per round, and the diagnostics at the final model."""
    header = (
        "case | round | candidate | score T | p | predicted decrease [mm^2] | direction | chosen"
    )
    return _table(header, summary, cases, _scores)


def _authors(case: dict):
    e_lo, e_hi = case["authors"]["E"]
    nu_lo, nu_hi = case["authors"]["nu"]
    shear = (e_lo / (2 * (1 + nu_hi)), e_hi / (2 * (1 + nu_lo)))
    for stage in case["stages"]:
        values = stage["physical"]
        yield (
            stage["label"],
            _number(values["tension_N_per_mm"]),
            _number(values.get("tension_inside_N_per_mm")),
            _number(values["k0"]),
            f"{e_lo:g}-{e_hi:g}",
            f"{shear[0]:.3f}-{shear[1]:.3f}",
        )


def authors_table(summary: dict, cases) -> list[str]:
    """Our membrane tensions next to the authors' E and shear modulus E / (2 (1 + nu))."""
    header = (
        "case | model | T outside [N/mm] | T inside [N/mm] | k0 | authors E | authors E/(2(1+nu))"
    )
    return _table(header, summary, cases, _authors)


def _heterogeneity(case: dict):
    found = case.get("heterogeneity")
    if not found:
        yield ("not added" + " |" * 7,)  # the row's seven empty cells, as one
        return
    r, o = found["rect_mm"], found.get("overlap")
    overlap = (
        (
            f"{o['inside_fraction']:.2f}",
            f"{o['iou']:.2f}",
            o["centroid_inside"],
            f"{o['chance']:.2f}",
        )
        if o
        else ("-",) * 4
    )
    region = (f"{r['x0']:.1f}-{r['x1']:.1f}", f"{r['y0']:.1f}-{r['y1']:.1f}")
    yield *region, _number(found["ratio"]), found["candidates"], *overlap


def heterogeneity_table(summary: dict, cases) -> list[str]:
    """The region the scan chose, its ratio and its overlap with the keloid outline."""
    header = (
        "case | found region x [mm] | y [mm] | ratio | rectangles | inside outline | IoU | "
        "centroid inside | chance"
    )
    return _table(header, summary, cases, _heterogeneity)


def _cell_map(case: dict):
    found = case.get("map")
    if found is None:
        return
    cells, outline = found["cells"], found["outline"] or {}
    inside = outline.get("inside_fraction")
    yield (
        found["stage"],
        f"{found['effective_dof']:.1f}",
        f"{cells['stiffer']} / {cells['softer']} of {cells['n_cells']}",
        f"{cells['stiffer_bonferroni']} / {cells['softer_bonferroni']} "
        f"(z > {cells['bonferroni_level']:.2f})",
        f"{inside:.2f} ({outline['chance']:.2f})" if inside is not None else "-",
        _number(outline.get("iou"), 2),
        f"{outline.get('centroid_inside', '-')}, {_number(outline.get('centroid_distance_mm'), 3)}",
        _number(found["strain"]["pearson"], 2),
    )


def map_table(summary: dict, cases) -> list[str]:
    """The cell map: dof, cells departing from the mean, outline overlap, strain."""
    header = (
        "case | stage | dof | stiffer / softer cells (z > 2) | Bonferroni | inside outline "
        "(chance) | IoU | centroid inside, distance [mm] | corr(map, strain)"
    )
    return _table(header, summary, cases, _cell_map)


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
