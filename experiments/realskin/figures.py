"""The real-skin study's figures: the force along the travel, the DIC residual maps of the
base and the final model, and the skin with its pads, the keloid's outline and the stiffer
rectangle the loop found (``experiments.realskin.skinfit``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.realskin.cases import FrameData, load_cases
from solvers.diagnosis.extended import ExtendedProblem
from solvers.inverse.problem import PlanarProblem
from symbolic.loads import FrameLoad

CURVE_POINTS = 12
"""Travels at which the models' force curves are solved."""


def force_curve(setup, fit, travels: np.ndarray) -> np.ndarray:
    """|F| [N] of a fitted model (an ``EffectFit`` of the study's problem) at pad travels
    [mm]: force-only frames at those travels, solved with the fit's parameters."""
    data = setup.data
    pad = np.column_stack([-travels, np.full(travels.size, data.pad_mm[-1, 1])])
    curve = FrameData(
        [f"{t:.2f} mm" for t in travels],
        pad,
        np.zeros(travels.size),
        [None] * travels.size,
        data.reference_mm,
        [None] * travels.size,
    )
    base = setup.base
    cases = load_cases(base.model, setup.pads, curve, setup.weight)
    planar = PlanarProblem(base.model, cases, base.space, noise_mm=setup.noise_mm)
    problem = ExtendedProblem(planar, [FrameLoad(c.label) for c in cases], fit.problem.effects)
    return np.abs(problem.residual(fit.p)) / setup.weight


def _residual_field(setup, fit, position: int) -> np.ndarray | None:
    """Model minus measured (ux, uy) [mm] of the DIC points at one frame (P, 2)."""
    rows = fit.problem.case_rows()
    start = int(np.sum(rows[:position]))
    n = len(setup.data.reference_mm)
    if setup.data.displacement_mm[position] is None:
        return None
    block = fit.residual[start : start + 2 * n]
    return block.reshape(2, n).T


def case_figures(setup, diagnosis, region: dict | None, folder: Path) -> list[Path]:
    """force.png, residuals.png and skin.png of one case (with PDF twins); their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig

    first, last = diagnosis.steps[0].fit, diagnosis.steps[-1].fit
    final = " + ".join(diagnosis.selected) or "nothing added"
    case, data = setup.case, setup.data
    paths = []

    fig, ax = plt.subplots(figsize=(5.2, 3.6), layout="constrained")
    ax.plot(-case.force_ux_mm, -case.force_fx_n, color="0.6", lw=2.5, label="measured")
    ax.plot(data.travel_mm, -data.force_n, "ko", mfc="none", label="fitted frames")
    travels = np.linspace(0.2, data.travel_mm.max(), CURVE_POINTS)
    for label, fit, style in (("base model", first, "--"), (final, last, "-")):
        ax.plot(travels, force_curve(setup, fit, travels), style, lw=1.6, label=label)
    ax.set(xlabel="pad travel [mm]", ylabel="|force| [N]", title=f"{case.name}: force")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    paths.append(atomic_savefig(fig, folder / "force.png", dpi=110))
    plt.close(fig)

    position = max(k for k, d in enumerate(data.displacement_mm) if d is not None)
    fields = {"base model": _residual_field(setup, first, position), final: None}
    fields[final] = _residual_field(setup, last, position)
    limit = max(float(np.abs(f).max()) for f in fields.values())
    fig, axes = plt.subplots(2, 2, figsize=(11, 5.2), squeeze=False)
    for row, (label, field) in enumerate(fields.items()):
        for col in range(2):
            ax = axes[row, col]
            image = ax.scatter(
                *data.reference_mm.T,
                c=field[:, col],
                s=5,
                cmap="RdBu_r",
                vmin=-limit,
                vmax=limit,
                rasterized=True,
            )
            rms = float(np.sqrt(np.mean(field[:, col] ** 2)))
            ax.set_title(f"{label}: u{'xy'[col]} residual, RMS {rms:.3f} mm", fontsize=9)
            ax.set_aspect("equal")
            fig.colorbar(image, ax=ax, shrink=0.8, label="mm")
    fig.suptitle(f"{case.name}, {data.labels[position]}: model minus DIC", fontsize=10)
    paths.append(atomic_savefig(fig, folder / "residuals.png", dpi=110))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7.0, 3.8))
    area = case.geometry.region
    ax.add_patch(plt.Rectangle((area.x0, area.y0), area.width, area.height, fill=False))
    for pad in setup.pad_rects:
        ax.add_patch(plt.Rectangle((pad.x0, pad.y0), pad.width, pad.height, color="0.3"))
    ax.plot(*data.reference_mm.T, ".", ms=1, color="0.6", label="DIC points")
    if case.geometry.keloid is not None:
        outline = np.vstack([case.geometry.keloid, case.geometry.keloid[:1]])
        ax.plot(*outline.T, "g-", label="keloid outline")
    if region is not None:
        x0, x1, y0, y1 = region["rect_mm"]
        state = "named" if region["named"] else "not named"
        ax.add_patch(
            plt.Rectangle(
                (x0, y0),
                x1 - x0,
                y1 - y0,
                fill=False,
                ec="r",
                lw=2,
                label=f"stiffer rectangle ({state})",
            )
        )
    ax.set(
        xlim=(area.x0, area.x1),
        ylim=(area.y0, area.y1),
        aspect="equal",
        xlabel="x [mm]",
        ylabel="y [mm]",
        title=f"{case.name}: the skin",
    )
    ax.legend(fontsize=7, loc="upper right")
    paths.append(atomic_savefig(fig, folder / "skin.png", dpi=110))
    plt.close(fig)
    return paths
