"""Figures of the real-skin study: force curves, residual maps, stiffness map (headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.output.atomic import atomic_savefig  # noqa: E402
from experiments.realskin.geometry import Rect

DPI = 80


def _rect(ax, rect: Rect, **style) -> None:
    xs = [rect.x0, rect.x1, rect.x1, rect.x0, rect.x0]
    ys = [rect.y0, rect.y0, rect.y1, rect.y1, rect.y0]
    ax.plot(xs, ys, **{"color": "k", "lw": 1.0, **style})


def _outline(ax, polygon: np.ndarray | None) -> None:
    if polygon is not None:
        closed = np.vstack([polygon, polygon[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="tab:red", lw=1.0, label="keloid outline")


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=DPI)
    plt.close(fig)
    return path


def _slab_map(ax, region: Rect, pads, pad_color: str, outline, title: str) -> None:
    """Pads, the keloid outline (if any) and the slab's frame on a map of the slab."""
    for pad in pads:
        _rect(ax, pad, color=pad_color)
    _outline(ax, outline)
    ax.set_xlim(region.x0, region.x1)
    ax.set_ylim(region.y0, region.y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(title, fontsize=10)


def plot_force_curves(path: Path, title: str, record: tuple, fitted: tuple, curves: dict) -> Path:
    """Measured force record, fitted frames and model curves |F| against pad travel.

    Parameters
    ----------
    record : tuple of numpy.ndarray
        (travel [mm], |F| [N]) of the force record.
    fitted : tuple of numpy.ndarray
        (travel, |F|, has_dic) of the fitted frames.
    curves : dict
        Label -> (travel, |F|) of each model.
    """
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    ax.plot(*record, color="0.6", lw=2.5, label="measured record")
    travel, force, dic = fitted
    ax.plot(travel[dic], force[dic], "ko", ms=5, mfc="none", label="fitted frames (DIC + force)")
    if (~dic).any():
        ax.plot(travel[~dic], force[~dic], "ks", ms=5, mfc="none", label="fitted (force only)")
    for (label, (t, f)), style in zip(curves.items(), ("--", "-", "-.", ":")):
        ax.plot(t, f, style, lw=1.6, label=label)
    ax.set_xlabel("pad travel [mm]")
    ax.set_ylabel("|force| [N]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_residual_maps(
    path: Path,
    title: str,
    reference: np.ndarray,
    residuals: dict,
    pads: tuple[Rect, Rect],
    outline: np.ndarray | None,
) -> Path:
    """Residual (model - measured) ux and uy at the DIC points, one row per model.

    Parameters
    ----------
    reference : numpy.ndarray
        DIC points (P, 2) [mm], model frame.
    residuals : dict
        Label -> residual (P, 2) [mm].
    """
    rows = len(residuals)
    fig, axes = plt.subplots(rows, 2, figsize=(11, 1.2 + 2.0 * rows), squeeze=False)
    limit = max(float(np.abs(r).max()) for r in residuals.values())
    x0 = min(reference[:, 0].min(), *(p.x0 for p in pads)) - 2
    x1 = max(reference[:, 0].max(), *(p.x1 for p in pads)) + 2
    y0 = min(reference[:, 1].min(), *(p.y0 for p in pads)) - 3
    y1 = max(reference[:, 1].max(), *(p.y1 for p in pads)) + 3
    for row, (label, residual) in enumerate(residuals.items()):
        for col in range(2):
            ax = axes[row, col]
            image = ax.scatter(
                *reference.T,
                c=residual[:, col],
                s=5,
                cmap="RdBu_r",
                vmin=-limit,
                vmax=limit,
                rasterized=True,  # thousands of DIC points: a light PDF twin
            )
            for pad in pads:
                _rect(ax, pad)
            _outline(ax, outline)
            rms = float(np.sqrt(np.mean(residual[:, col] ** 2)))
            ax.set_title(f"{label}: u{'xy'[col]} residual, RMS {rms:.3f} mm", fontsize=9)
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
            ax.set_aspect("equal")
            fig.colorbar(image, ax=ax, shrink=0.8, label="mm")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_stiffness_map(
    path: Path,
    title: str,
    region: Rect,
    tension: np.ndarray,
    grid: tuple[np.ndarray, np.ndarray],
    pads: tuple[Rect, Rect],
    outline: np.ndarray | None,
    reference: np.ndarray,
) -> Path:
    """Membrane tension T(x, y) [N/mm] of the fitted model, log colour scale."""
    fig, ax = plt.subplots(figsize=(7.5, 4.0))
    image = ax.pcolormesh(*grid, np.log10(tension), shading="auto", cmap="viridis")
    fig.colorbar(image, ax=ax, label="log10 T [N/mm]")
    ax.plot(*reference.T, ",", color="w", alpha=0.5)
    _slab_map(ax, region, pads, "w", outline, title)
    return _save(fig, path)


def plot_scan_map(
    path: Path,
    title: str,
    region: Rect,
    x_edges: np.ndarray,
    y_edges: np.ndarray,
    statistic: np.ndarray,
    found: Rect,
    pads: tuple[Rect, Rect],
    outline: np.ndarray | None,
) -> Path:
    """Signed score statistic of every single cell (+: stiffer wanted), the rectangle the
    scan chose, the pads and (for comparison only) the keloid outline."""
    fig, ax = plt.subplots(figsize=(7.5, 4.0))
    limit = float(np.abs(statistic).max()) or 1.0
    image = ax.pcolormesh(
        x_edges, y_edges, statistic.T, cmap="RdBu_r", vmin=-limit, vmax=limit, shading="flat"
    )
    fig.colorbar(image, ax=ax, label="signed score T of one cell (+: stiffer)")
    _rect(ax, found, color="k", lw=2.0, label="found region")
    _slab_map(ax, region, pads, "0.3", outline, title)
    ax.legend(loc="upper right", fontsize=7)
    return _save(fig, path)


def plot_cell_map(
    path: Path,
    title: str,
    region: Rect,
    edges: tuple[np.ndarray, np.ndarray],
    s: np.ndarray,
    z: np.ndarray,
    pads: tuple[Rect, Rect],
    outline: np.ndarray | None,
    dic_xy: np.ndarray,
) -> Path:
    """The cell map (``cellmap.py``): log stiffness ratio to the slab's mean, and s / std
    with the |z| = 2 contour; pads, the DIC points and (for comparison only) the outline."""
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 7.0))
    for ax, values, label in (
        (axes[0], s, "log stiffness ratio s to the slab's mean"),
        (axes[1], z, "s / std (z)"),
    ):
        limit = float(np.abs(values).max()) or 1.0
        image = ax.pcolormesh(
            *edges, values.T, cmap="RdBu_r", vmin=-limit, vmax=limit, shading="flat"
        )
        fig.colorbar(image, ax=ax, label=label)
        ax.plot(*dic_xy.T, ".", color="0.4", ms=1.0, label="DIC points")
        _slab_map(ax, region, pads, "0.3", outline, title if ax is axes[0] else "")
    centres = [0.5 * (e[1:] + e[:-1]) for e in edges]
    if np.abs(z).max() > 2.0:
        axes[1].contour(*centres, np.abs(z).T, levels=[2.0], colors="k", linewidths=1.0)
    axes[0].legend(loc="upper right", fontsize=7)
    return _save(fig, path)
