"""The stiffness map of real skin: one log-ratio per cell, a smoothness prior, Laplace.

The rectangle scan (``scan.py``) asks whether one stiffer rectangle explains the data.
The map asks how the stiffness varies, cell by cell, with its uncertainty. Every cell c
(one knot span, ``CellGrid``) gets s_c = log of its stiffness ratio: every tension term
and the coupling inside it are multiplied by exp(s_c). At a fitted stage of the model
without a second material (parameters x, weighted residual r, n of them), the exact
columns J_c = dr/ds_c of ``scan.cell_columns`` with the fitted parameters profiled out,
J = (I - Q_x Q_x^T) J_c, give the regularised Gauss-Newton step from s = 0:

    s = argmin_s |r + J s|^2 / (2 sigma^2) + 1/2 s^T Q s,                           (R1)
    Q = n_cells / (A tau^2) (diag(a_c) + ell^2 A L),

with sigma^2 = |r|^2 / (n - p) (the stage's residual variance, model error included),
a_c the cells' areas (A their sum), L the form of the area mean <|grad s|^2> by
difference quotients between neighbouring cell centres, ell the mean cell size and
tau = 0.5: eq. (F2) of the loop's ``stiffness_field``, on cells. The mean of s is not
identifiable (the fitted tensions carry it), so s is relative to the slab's mean:
s = Z t, Z an orthonormal basis of the zero-mean maps.

**Choices.**
- One step, linearised at the stage (the model is not refitted with the map): a map of
  where and how much, not a refit; ``docs/realskin.md`` says where it falls short.
- The weight is the prior's, not chosen from the data. Morozov's principle needs the
  residual to reach the DIC noise, which no fit of real skin does (0.19 against
  0.018 mm for the keloid). Generalised cross-validation over a factor on Q is
  reported (``gcv_scale``, searched over 1e-6..1e4): on the real keloid it runs to the
  smallest factor (1e-6) and on healthy skin nearly so (3e-5), where the map fits the
  model error; on the keloid twin (docs/realskin.md) it chooses 1e4 without a stiffer
  material and 0.06 with one.
- The Laplace covariance C = (J^T J / sigma^2 + Z^T Q Z)^-1 on t, mapped to s; the
  effective number of parameters tr(C J^T J) / sigma^2.

``compare_outline`` puts the map beside the keloid outline of ``geometry.geo`` (which
the map never saw); ``compare_strain`` beside the model-free axial strain
(``strain.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy import stats

from experiments.realskin.scan import CellGrid, CellTerms, overlap, profiled_cell_columns
from experiments.realskin.strain import segment_strain

PRIOR_RMS = 0.5
"""tau of eq. (R1): the prior's RMS of s (as ``symbolic.effects.fieldeffect.PRIOR_RMS``)."""

Z_LEVEL = 2.0
"""|s| / std above which a cell counts as departing from the slab's mean (about 5 %
two-sided per cell)."""


@dataclass(frozen=True)
class CellMap:
    """The map of one stage.

    Attributes
    ----------
    s : numpy.ndarray
        log stiffness ratio of every cell to the slab's mean, (n_x, n_y).
    std : numpy.ndarray
        Its Laplace standard deviation, (n_x, n_y).
    effective_dof : float
        Parameters the data determine, of ``n_cells - 1``: tr(C J^T J) / sigma^2.
    gcv_scale : float
        The factor on Q that generalised cross-validation would choose (1: the prior's).
    gcv : list of (float, float)
        (factor on Q, GCV) along the searched path.
    cost_before, cost_after : float
        1/2 |r|^2 and 1/2 |r + J s|^2 (the linearised cost after the step) [mm^2].
    """

    s: np.ndarray
    std: np.ndarray
    effective_dof: float
    gcv_scale: float
    gcv: list
    cost_before: float
    cost_after: float

    @property
    def z(self) -> np.ndarray:
        """s / std per cell."""
        return self.s / self.std


def gradient_form(grid: CellGrid) -> np.ndarray:
    """L with s^T L s = <|grad s|^2>: the area mean of the squared difference quotients
    between the centres of neighbouring cells, (n_cells, n_cells) [1/mm^2]."""
    n_x, n_y = grid.shape
    index = np.arange(grid.n_cells).reshape(n_x, n_y)
    area = np.outer(np.diff(grid.x_edges), np.diff(grid.y_edges))
    centre_x = 0.5 * (grid.x_edges[1:] + grid.x_edges[:-1])
    centre_y = 0.5 * (grid.y_edges[1:] + grid.y_edges[:-1])
    form = np.zeros((grid.n_cells, grid.n_cells))
    neighbours = (
        (index[:-1], index[1:], 0.5 * (area[:-1] + area[1:]) / np.diff(centre_x)[:, None] ** 2),
        (index[:, :-1], index[:, 1:], 0.5 * (area[:, :-1] + area[:, 1:]) / np.diff(centre_y) ** 2),
    )
    for a, b, w in neighbours:
        a, b, w = a.ravel(), b.ravel(), w.ravel() / area.sum()
        np.add.at(form, (a, a), w)
        np.add.at(form, (b, b), w)
        np.add.at(form, (a, b), -w)
        np.add.at(form, (b, a), -w)
    return form


def prior_precision(grid: CellGrid, rms: float = PRIOR_RMS) -> np.ndarray:
    """Q of eq. (R1): eq. (F2) of the loop's ``stiffness_field`` on the cells,
    n_cells / (A tau^2) (diag(area) + ell^2 A L), ell the mean cell size [mm]."""
    area = np.outer(np.diff(grid.x_edges), np.diff(grid.y_edges)).ravel()
    spacing = 0.5 * (np.mean(np.diff(grid.x_edges)) + np.mean(np.diff(grid.y_edges)))
    total = area.sum()
    return (
        grid.n_cells / (total * rms**2) * (np.diag(area) + spacing**2 * total * gradient_form(grid))
    )


def estimate_map(
    model, cases, names, x, bounds, grid: CellGrid, cells: CellTerms | None = None, states=None
) -> CellMap:
    """The map (R1) at the stage (names, x) of ``model`` (no second material; ``states``:
    the equilibria at x, if known)."""
    cells = cells if cells is not None else CellTerms.build(model, grid)
    r, columns = profiled_cell_columns(model, cases, names, x, bounds, cells, states)
    n = r.size
    sigma2 = float(r @ r) / max(n - len(names), 1)
    basis = scipy.linalg.null_space(np.ones((1, grid.n_cells)))  # Z: zero-mean maps
    jac = columns @ basis
    data = jac.T @ jac / sigma2
    prior = basis.T @ prior_precision(grid) @ basis
    values, vectors = scipy.linalg.eigh(data, prior)  # data V = prior V diag, V^T prior V = I
    values = np.maximum(values, 0.0)
    projected = vectors.T @ (jac.T @ r) / sigma2

    def step(scale):
        """t, the residual after it and tr(A) with the prior scaled by ``scale``."""
        t = -vectors @ (projected / (values + scale))
        return t, r + jac @ t, float(np.sum(values / (values + scale)))

    path = []
    for scale in np.logspace(-6, 4, 41):
        _, after, trace = step(scale)
        path.append((float(scale), float(n * (after @ after) / (n - trace) ** 2)))
    t, after, trace = step(1.0)
    covariance = (vectors / (values + 1.0)) @ vectors.T
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", basis, covariance, basis), 0.0))
    return CellMap(
        (basis @ t).reshape(grid.shape),
        std.reshape(grid.shape),
        trace,
        min(path, key=lambda p: p[1])[0],
        path,
        0.5 * float(r @ r),
        0.5 * float(after @ after),
    )


def significant_cells(cell_map: CellMap, level: float = Z_LEVEL) -> dict:
    """Cells departing from the slab's mean: per cell |z| > level, and with the
    Bonferroni level for all cells at once (5 % family-wise, two-sided)."""
    z = cell_map.z.ravel()
    family = float(stats.norm.isf(0.025 / z.size))
    return {
        "level": level,
        "stiffer": int(np.sum(z > level)),
        "softer": int(np.sum(z < -level)),
        "bonferroni_level": family,
        "stiffer_bonferroni": int(np.sum(z > family)),
        "softer_bonferroni": int(np.sum(z < -family)),
        "n_cells": int(z.size),
    }


def compare_outline(cell_map: CellMap, grid: CellGrid, polygon: np.ndarray) -> dict:
    """The significantly stiffer cells (z > ``Z_LEVEL``) against the keloid outline:
    ``scan.overlap`` of their union, plus ``cells``, their number."""
    stiff = (cell_map.z > Z_LEVEL).ravel()
    out = overlap(lambda points: stiff[grid.cell_at(points)], polygon, grid.region)
    return {"cells": int(stiff.sum()), **out}


def compare_strain(cell_map: CellMap, grid: CellGrid, case, frame: int) -> dict:
    """The map against the model-free axial strain, column by column of cells.

    Over the cell columns the DIC covers, the map's mean s over the cells the DIC
    points fall in, and the mean axial strain between the column's x edges at ``frame``
    (``strain.segment_strain``). Stiffer skin strains less, so a map that agrees with
    the strain gives a negative correlation.
    """
    cells = grid.cell_at(case.dic_reference_model_mm)
    columns = cells // grid.shape[1]
    strain = segment_strain(case, frame, grid.x_edges)  # per column of cells
    s = cell_map.s.ravel()
    rows = [
        (
            0.5 * (grid.x_edges[c] + grid.x_edges[c + 1]),
            float(np.mean(s[cells[columns == c]])),
            strain[c],
        )
        for c in np.unique(columns)
        if np.isfinite(strain[c])
    ]
    x, map_s, strain = (np.array(v) for v in zip(*rows))
    return {
        "frame": int(frame),
        "x_mm": x.tolist(),
        "map_s": map_s.tolist(),
        "strain": strain.tolist(),
        "pearson": float(np.corrcoef(map_s, strain)[0, 1]) if len(x) > 2 else None,
    }


def map_report(setup, model, stage, bounds: dict, cells, path) -> dict:
    """The map (R1) of ``model`` at a fitted stage, its comparisons and its figure.

    Parameters
    ----------
    setup : experiments.realskin.setup.Setup
        The case (its load cases, cell grid, pads, outline and DIC).
    model : SkinSlabModel or symbolic.continuum_model.NeoHookeanModel
        The model without a second material the stage was fitted with.
    stage : experiments.realskin.stages.StageFit
        The stage (its parameter names and estimates).
    bounds : dict
        Bounds of the stage's parameters (natural units).
    cells : scan.CellTerms or continuum_cells.ContinuumCells
        The cells' terms of ``model`` on ``setup.grid``.
    path : pathlib.Path
        The figure (s, and s / std with the |z| = 2 contour).

    Returns
    -------
    dict
        s and std per cell, the effective dof, the GCV factor, the linearised costs,
        ``significant_cells``, ``compare_strain`` at the last DIC frame and
        ``compare_outline`` (None without a keloid outline).
    """
    from experiments.realskin.skinplots import plot_cell_map

    found = estimate_map(
        model, setup.cases, stage.names, stage.x, bounds, setup.grid, cells, stage.states
    )
    frames = [f for f in setup.data.frames if f is not None]
    keloid = setup.case.geometry.keloid
    out = {
        "stage": stage.label,
        "s": found.s.tolist(),
        "std": found.std.tolist(),
        "effective_dof": found.effective_dof,
        "prior_rms": PRIOR_RMS,
        "gcv_scale": found.gcv_scale,
        "cost_before": found.cost_before,
        "cost_after_linearised": found.cost_after,
        "cells": significant_cells(found),
        "strain": compare_strain(found, setup.grid, setup.case, frames[-1]),
        "outline": None if keloid is None else compare_outline(found, setup.grid, keloid),
    }
    plot_cell_map(
        path,
        f"{setup.case.name}: stiffness map at '{stage.label}' ({found.effective_dof:.1f} dof)",
        setup.grid.region,
        (setup.grid.x_edges, setup.grid.y_edges),
        found.s,
        found.z,
        setup.pad_rects,
        keloid,
        setup.case.dic_reference_model_mm,
    )
    return out
