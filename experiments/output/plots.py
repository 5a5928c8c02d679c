"""Figures shared by the research scripts and the CLI (matplotlib, headless)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.output.atomic import atomic_savefig  # noqa: E402
from symbolic.volume import VolumeSpline  # noqa: E402


def surface_grid(volume: VolumeSpline, positions: np.ndarray, count: int = 41) -> np.ndarray:
    """The outer surface of the volume with control points ``positions``, (count, count, 3)."""
    t = np.linspace(0.0, 1.0, count)
    uu, vv = np.meshgrid(t, t, indexing="ij")
    params = volume.outer_params(np.column_stack([uu.ravel(), vv.ravel()]))
    return (volume.collocation(params) @ positions).reshape(count, count, 3)


def plot_deformation(volume: VolumeSpline, deformed: np.ndarray, path, title: str = "") -> None:
    """Normal displacement map of the skin and a mid-section, rest against deformed.

    Parameters
    ----------
    volume : VolumeSpline
        The rest volume (its control points are B0).
    deformed : numpy.ndarray
        Deformed control points B, (n, 3) [mm].
    path : str or Path
        Output file; the format follows the suffix (png, pdf).
    """
    rest = surface_grid(volume, volume.control_points)
    moved = surface_grid(volume, deformed)
    count = rest.shape[0]
    t = np.linspace(0, 1, count)
    normals = volume.outer_normal(np.column_stack([np.repeat(t, count), np.tile(t, count)]))
    normal_disp = np.sum((moved - rest).reshape(-1, 3) * normals, axis=1).reshape(count, count)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2))
    image = left.contourf(rest[..., 0], rest[..., 1], normal_disp, levels=20, cmap="viridis")
    fig.colorbar(image, ax=left, label="normal displacement [mm]")
    left.set(xlabel="x [mm]", ylabel="y [mm]", title="skin displacement", aspect="equal")
    section = np.column_stack([t, np.full(count, 0.5)])
    for w, style in ((1.0, "-"), (0.0, "--")):
        params = np.column_stack([section, np.full(count, w)])
        before = volume.collocation(params) @ volume.control_points
        after = volume.collocation(params) @ deformed
        label = "skin" if w == 1.0 else "inner surface"
        right.plot(before[:, 0], before[:, 2], style, color="0.6", label=f"{label}, rest")
        right.plot(after[:, 0], after[:, 2], style, color="C3", label=f"{label}, loaded")
    right.set(xlabel="x [mm]", ylabel="z [mm]", title="section v = 0.5")
    right.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def residual_panel(
    ax, case, error: np.ndarray, top: float, title: str = "", size: int = 70, compact=False
):
    """One map of marker residuals [um] on the rest skin; returns the scatter for a colorbar.

    ``compact``: a two-line title in small type and no axis labels (the caller labels
    the outer panels of a grid).
    """
    image = ax.scatter(
        case.rest_points[:, 0],
        case.rest_points[:, 1],
        c=error * 1e3,
        s=size,
        cmap="magma_r",
        vmin=0,
        vmax=top,
    )
    rms = np.sqrt(np.mean(error**2)) * 1e3
    if compact:
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        ax.set_title(f"{case.label}\nRMS {rms:.0f}, max {error.max() * 1e3:.0f} um", fontsize=8)
        return image
    heading = f"{title}\n" if title else ""
    ax.set(
        xlabel="x [mm]",
        ylabel="y [mm]",
        aspect="equal",
        title=f"{heading}{case.label}: RMS {rms:.1f} um, max {error.max() * 1e3:.0f} um",
    )
    return image


def plot_residual_maps(problem, states, path, title: str = "") -> None:
    """Marker residuals |S B - Y| on the rest skin, one panel per load case.

    Parameters
    ----------
    problem : InverseProblem
        The fitted problem (its cases know which markers were seen).
    states : list of numpy.ndarray
        Equilibrium states at the estimate.
    path : str or Path
        Output file.
    """
    errors = problem.point_errors(states)
    count = len(problem.cases)
    fig, axes = plt.subplots(
        1, count, figsize=(4.8 * count, 4.2), squeeze=False, layout="constrained"
    )
    top = max(float(e.max()) for e in errors) * 1e3 or 1.0
    for ax, case, error in zip(axes[0], problem.cases, errors):
        image = residual_panel(ax, case, error, top)
    for ax in axes[0][1:]:
        ax.set_ylabel("")
    fig.colorbar(image, ax=axes[0].tolist(), label="marker residual [um]")
    if title:
        fig.suptitle(title)
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def _row_near_contact(case, measured: np.ndarray) -> np.ndarray:
    """Mask of the markers in the row (along x) through the largest measured displacement."""
    center_y = case.rest_points[np.argmax(np.linalg.norm(measured, axis=1)), 1]
    spacing = np.ptp(case.rest_points[:, 1]) / max(np.sqrt(len(case.rest_points)) - 1, 1)
    return np.abs(case.rest_points[:, 1] - center_y) < 0.25 * spacing


def plot_fitted_section(problem, states, path) -> None:
    """Measured marker displacement along the marker row through the dent, and the fitted
    skin along the same line (the spline, sampled densely: its tip lies between markers)."""
    model = problem.model
    fig, axes = plt.subplots(
        1, len(problem.cases), figsize=(4.8 * len(problem.cases), 3.8), squeeze=False
    )
    for ax, case, state in zip(axes[0], problem.cases, states):
        delta = state[: 3 * model.n_free].reshape(3, -1).T
        measured = -case.offset  # Y - S B0
        row = _row_near_contact(case, measured)
        order = np.argsort(case.rest_points[row, 0])
        uv, _ = model.volume.project_to_outer(case.rest_points[row])
        u = np.linspace(uv[:, 0].min(), uv[:, 0].max(), 400)
        dense = model.volume.collocation(
            model.volume.outer_params(np.column_stack([u, np.full(u.size, np.median(uv[:, 1]))]))
        )
        rest = dense @ model.rest
        moved = dense @ model.full_positions(delta)
        ax.plot(case.rest_points[row, 0][order], measured[row, 2][order], "o", label="measured")
        ax.plot(rest[:, 0], moved[:, 2] - rest[:, 2], "-", label="fitted skin")
        low = float(np.min(moved[:, 2] - rest[:, 2]))
        ax.axhline(low, color="0.7", lw=0.8, ls=":")
        ax.set(
            xlabel="x [mm]",
            ylabel="z displacement [mm]",
            title=f"{case.label}: fitted dent {low:.3f} mm",
        )
        ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)
