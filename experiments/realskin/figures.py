"""What one case's study reports: physical numbers of a fit, stage summaries, figures."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from experiments.realskin.skinplots import (
    plot_force_curves,
    plot_residual_maps,
    plot_scan_map,
    plot_stiffness_map,
)
from experiments.realskin.stages import LABELS, StageFit, force_curve
from symbolic.skin_slab import POISSON, REGION_RATIO

if TYPE_CHECKING:
    from experiments.realskin.setup import Setup


def physical(setup: Setup, fit: StageFit) -> dict:
    """Membrane tensions [N/mm], foundation stiffness [N/mm^3], k0, ratio of a fit.

    T = alpha_u L_x / L_y (isotropic in the plane); k_f = alpha_w / (L_x L_y): the
    in-plane force per unit area and displacement of the layer under the skin.
    """
    model = fit.problem.model if fit.problem is not None else setup.model
    values = model.values(fit.as_dict())
    tension_x, tension_y = model.membrane_tension(values)
    extent = np.ptp(model.rest, axis=0)
    out = {
        "tension_N_per_mm": tension_x,
        "tension_y_N_per_mm": tension_y,
        "k0": values["k0"],
        "foundation_N_per_mm3": values["alpha_w"] / (extent[0] * extent[1])
        if model.boundary.fix_inner
        else None,
    }
    if POISSON in fit.names:
        out["poisson_c"] = values[POISSON]
        out["poisson_nu"] = values[POISSON] / (1.0 + values[POISSON])
    if REGION_RATIO in fit.names:
        out["region_ratio"] = values[REGION_RATIO]
        out["theta"] = values[REGION_RATIO] - 1.0
        out["tension_inside_N_per_mm"] = tension_x * values[REGION_RATIO]
    return out


def stage_summary(setup: Setup, fit: StageFit) -> dict:
    """A fitted stage as plain numbers (``summary.json``)."""
    return {
        "label": fit.label,
        "estimates": {
            n: {"value": float(v), "std": float(s), "at_bound": bool(b)}
            for n, v, s, b in zip(fit.names, fit.x, fit.std, fit.at_bound)
        },
        "physical": physical(setup, fit),
        "rms_displacement_mm": fit.rms_displacement_mm,
        "rms_force_N": fit.rms_force_n,
        "cost": fit.cost,
        "sigma_mm": fit.sigma,
        "success": fit.success,
        "evaluations": fit.evaluations,
        "seconds": fit.seconds,
    }


def _curves(setup: Setup, stages: list[StageFit]) -> tuple[np.ndarray, dict]:
    """Model force curves of the first and last stage over the record's travel."""
    case = setup.case
    travel_max = float(-case.force_ux_mm.min())
    travels = np.linspace(travel_max / 24, travel_max, 24)
    frame_travel = -case.pad_displacement_mm[:, 0]
    drift = np.interp(travels, frame_travel, case.pad_displacement_mm[:, 1])
    curves = {}
    for fit in (stages[0], stages[-1]) if len(stages) > 1 else stages[:1]:
        force = force_curve(fit.problem.model, setup.pads, fit, travels, drift)
        name = (
            "linear"
            if fit is stages[0]
            else "final: " + ", ".join(LABELS[n] for n in fit.names if n in LABELS)
        )
        curves[name] = (travels, -force)
    return travels, curves


def case_figures(
    out: Path, name: str, setup: Setup, stages: list[StageFit], found=None
) -> list[Path]:
    """Force curves, residual maps and (with a second material) the stiffness map."""
    case, data = setup.case, setup.data
    paths = []
    _, curves = _curves(setup, stages)
    record = (-case.force_ux_mm, -case.force_fx_n)
    has_dic = np.array([d is not None for d in data.displacement_mm])
    paths.append(
        plot_force_curves(
            out / f"force_{name}.png",
            f"{name}: force against pad travel",
            record,
            (data.travel_mm, -data.force_n, has_dic),
            curves,
        )
    )
    last = int(np.flatnonzero(has_dic)[-1])
    residuals = {}
    for fit in (stages[0], stages[-1]) if len(stages) > 1 else stages[:1]:
        label = "before" if fit is stages[0] else "after"
        residuals[label] = fit.problem.marker_errors(fit.states)[last]
    paths.append(
        plot_residual_maps(
            out / f"residual_{name}.png",
            f"{name}: model - measured displacement, {data.labels[last]} "
            f"(pad travel {data.travel_mm[last]:.2f} mm)",
            data.reference_mm,
            residuals,
            setup.pad_rects,
            case.geometry.keloid,
        )
    )
    final = stages[-1]
    if REGION_RATIO in final.names:
        region = case.geometry.region
        x = np.linspace(region.x0, region.x1, 201)
        y = np.linspace(region.y0, region.y1, 101)
        grid = np.meshgrid(x, y, indexing="xy")
        params = np.column_stack(
            [
                ((grid[0] - region.x0) / region.width).ravel(),
                ((grid[1] - region.y0) / region.height).ravel(),
                np.ones(grid[0].size),
            ]
        )
        chi = final.problem.model.region(params).reshape(grid[0].shape)
        values = physical(setup, final)
        tension = values["tension_N_per_mm"] * (1.0 + values["theta"] * chi)
        paths.append(
            plot_stiffness_map(
                out / f"stiffness_{name}.png",
                f"{name}: fitted membrane tension T (outside {values['tension_N_per_mm']:.2g}, "
                f"inside {values['tension_inside_N_per_mm']:.2g} N/mm)",
                region,
                tension,
                grid,
                setup.pad_rects,
                case.geometry.keloid,
                data.reference_mm,
            )
        )
    if found is not None:
        paths.append(
            plot_scan_map(
                out / f"scan_{name}.png",
                f"{name}: scan for a stiffer inclusion (chosen T = {found.score.statistic:.3g})",
                case.geometry.region,
                setup.grid.x_edges,
                setup.grid.y_edges,
                found.cell_statistic,
                found.rect,
                setup.pad_rects,
                case.geometry.keloid,
            )
        )
    return paths
