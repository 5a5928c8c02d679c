"""A heterogeneity that the data locate: a score scan over rectangles of grid cells.

The second material is not placed by hand. The slab is cut into cells, one knot span
each (the field inside a span is one polynomial, so a cell's terms are exact with the
usual Gauss rule), and every axis-aligned rectangle of cells is a candidate region R:

    every tension term (and the Poisson coupling) is multiplied by 1 + theta 1_R(x, y).

At a fitted stage the residual's derivative with respect to theta_c of every single
cell c is exact and cheap (one LU per load case): dg/dtheta_c = K_c(B) Delta, with K_c(B)
the cell's part of the stiffened K (eq. 1: spring entries times s(eps), the diagonal the
negative row sum) plus the cell's coupling. A rectangle's column is the sum of its cells'
columns, so the score statistic of every rectangle (``stages.score_test``, with
the fitted parameters profiled out) follows from one n_cells x n_cells Gram matrix.

The best rectangle's p-value is Bonferroni-corrected for the number of rectangles. The
outline in ``geometry.geo`` is not used to choose it; ``overlap`` compares the two
afterwards.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401  (sp.linalg)
from scipy import stats

from experiments.realskin.geometry import Rect, points_in_polygon
from experiments.realskin.stages import Score, stage_solver
from solvers.forward.equilibrium import EquilibriumSolver
from solvers.inverse.problem import PlanarProblem
from solvers.inverse.space import SkinParameterSpace
from symbolic.basis import FIRST_DERIVATIVES
from symbolic.energy import quadrature
from symbolic.skin_slab import ALPHA_TERMS, SkinSlabModel

SCAN = "region_scan"
"""Name of the scanned-heterogeneity candidate in the loop (its parameter is the ratio)."""


# -------------------------------------------------------------------------------- cells
@dataclass(frozen=True)
class CellGrid:
    """Cells of the slab, one knot span each (model frame, mm).

    Attributes
    ----------
    region : Rect
        The slab's rectangle.
    x_edges, y_edges : numpy.ndarray
        Cell boundaries along x (n_x + 1,) and y (n_y + 1,) [mm]; cell (i, j) has index
        i n_y + j.
    """

    region: Rect
    x_edges: np.ndarray
    y_edges: np.ndarray

    @classmethod
    def of(cls, model: SkinSlabModel, region: Rect) -> CellGrid:
        """One cell per in-plane knot span of the model's volume."""
        bu, bv = model.volume.basis.bases[:2]
        u, v = np.unique(bu.knots), np.unique(bv.knots)
        return cls(region, region.x0 + u * region.width, region.y0 + v * region.height)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.x_edges.size - 1, self.y_edges.size - 1)

    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1]

    def rect(self, box: tuple[int, int, int, int]) -> Rect:
        """The rectangle of cells i0 <= i < i1, j0 <= j < j1 [mm]."""
        i0, i1, j0, j1 = box
        return Rect(self.x_edges[i0], self.y_edges[j0], self.x_edges[i1], self.y_edges[j1])

    def cell_of(self, params: np.ndarray) -> np.ndarray:
        """Cell index of parameter points (n, 3) (the nearest cell outside)."""
        x = self.region.x0 + params[:, 0] * self.region.width
        y = self.region.y0 + params[:, 1] * self.region.height
        return self.cell_at(np.column_stack([x, y]))

    def cell_at(self, points_xy: np.ndarray) -> np.ndarray:
        """Cell index of model-frame points (n, 2) [mm] (the nearest cell outside)."""
        x, y = np.asarray(points_xy, dtype=float).T
        i = np.clip(np.searchsorted(self.x_edges, x, side="right") - 1, 0, self.shape[0] - 1)
        j = np.clip(np.searchsorted(self.y_edges, y, side="right") - 1, 0, self.shape[1] - 1)
        return i * self.shape[1] + j

    def boxes(self) -> list[tuple[int, int, int, int]]:
        """Every rectangle of cells that does not touch the slab's edge, (i0, i1, j0, j1).

        A region and its complement are the same model up to the scale of the alphas
        (which the fit profiles out), so only inclusions, regions with healthy skin all
        round, are candidates; a region reaching the edge would stand for a different
        boundary condition.
        """
        n_x, n_y = self.shape
        return [
            (i0, i1, j0, j1)
            for i0 in range(1, n_x - 1)
            for i1 in range(i0 + 1, n_x)
            for j0 in range(1, n_y - 1)
            for j1 in range(j0 + 1, n_y)
        ]

    def mask(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """0/1 weight of every cell for a rectangle of cells."""
        i0, i1, j0, j1 = box
        out = np.zeros(self.shape)
        out[i0:i1, j0:j1] = 1.0
        return out.reshape(-1)


def rect_indicator(region: Rect, rect: Rect):
    """chi(params) = 1 inside ``rect`` (model frame) else 0: a ``Field`` on the slab."""

    def chi(params: np.ndarray) -> np.ndarray:
        x = region.x0 + params[:, 0] * region.width
        y = region.y0 + params[:, 1] * region.height
        return ((x >= rect.x0) & (x < rect.x1) & (y >= rect.y0) & (y < rect.y1)).astype(float)

    return chi


def with_region(model: SkinSlabModel, field) -> SkinSlabModel:
    """A copy of the model whose second material lies where ``field`` is 1."""
    return dataclasses.replace(model, region=field, _fast={})


# ------------------------------------------------------------------------ cell columns
@dataclass(frozen=True)
class CellTerms:
    """The cells' unit terms, stacked for all cells at once.

    Attributes
    ----------
    pairs : numpy.ndarray
        Control-point pairs a < b coupled by any term, (n_pairs, 2).
    edges : dict
        Per alpha term, the sparse (n_pairs, n_cells) matrix of integral 1_c J_t,a J_t,b.
    divergence : scipy.sparse.csr_matrix
        D (n_q, 3n): div_xy u at every quadrature point from vec(Delta).
    weights : scipy.sparse.csr_matrix
        (n_q, n_cells): Gauss weight of each point in its cell's column.
    """

    pairs: np.ndarray
    edges: dict
    divergence: sp.csr_matrix
    weights: sp.csr_matrix

    @classmethod
    def build(cls, model: SkinSlabModel, grid: CellGrid) -> CellTerms:
        basis = model.volume.basis
        points, weights = quadrature(basis)
        cell = grid.cell_of(points)
        n = model.rest.shape[0]
        union = sp.csr_matrix(sum(abs(model.terms[t]) for t in ALPHA_TERMS))
        upper = sp.triu(union, k=1).tocoo()
        order = np.argsort(upper.row * n + upper.col)
        a, b = upper.row[order], upper.col[order]
        keys = a.astype(np.int64) * n + b
        edges = {}
        for t in ALPHA_TERMS:
            d = basis.collocation(points, FIRST_DERIVATIVES[t[-1]]).tocsr()
            rows, cols, vals = [], [], []
            for c in range(grid.n_cells):
                inside = np.flatnonzero(cell == c)
                block = d[inside]
                gram = sp.triu(block.T @ sp.diags(weights[inside]) @ block, k=1).tocoo()
                rows.append(np.searchsorted(keys, gram.row.astype(np.int64) * n + gram.col))
                cols.append(np.full(gram.nnz, c))
                vals.append(gram.data)
            edges[t] = sp.csr_matrix(
                (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                shape=(keys.size, grid.n_cells),
            )
        d_x = basis.collocation(points, (1, 0, 0)) / model.lengths[0]
        d_y = basis.collocation(points, (0, 1, 0)) / model.lengths[1]
        divergence = sp.hstack([d_x, d_y, sp.csr_matrix((len(points), n))]).tocsr()
        onehot = sp.csr_matrix(
            (weights, (np.arange(len(points)), cell)), shape=(len(points), grid.n_cells)
        )
        return cls(np.column_stack([a, b]), edges, divergence, onehot)

    def force_columns(
        self, model: SkinSlabModel, names: tuple, x: np.ndarray, delta: np.ndarray
    ) -> np.ndarray:
        """dg/dtheta_c of every cell at the displacement ``delta`` (n, 3) [mm], on the free
        points in vec(Delta_free) order, (3 n_free, n_cells).

        dg/dtheta_c = K_c(B) Delta: the cell's spring entries (< 0) times s(eps_ab), the
        others as they are, the diagonal the negative row sum; plus the cell's coupling
        C L_x L_y D_c^T W_c D_c vec(Delta).
        """
        if model.region is not None:
            raise ValueError("scan a model without a second material")
        values = model.values(dict(zip(names, x)))
        coefficients = {t: float(model.coefficient(t, values)) for t in ALPHA_TERMS}
        coupling = float(model.coupling_coefficients(values)[0])
        k0 = float(values["k0"])
        strain = ca.SX.sym("eps")
        s = ca.Function("s", [strain], [model.stiffening(strain, k0)])
        a, b = self.pairs.T
        n, n_pairs = model.rest.shape[0], a.size
        incidence = sp.csr_matrix(
            (
                np.r_[np.ones(n_pairs), -np.ones(n_pairs)],
                (np.r_[a, b], np.r_[np.arange(n_pairs), np.arange(n_pairs)]),
            ),
            shape=(n, n_pairs),
        )
        rest_length = np.linalg.norm(model.rest[a] - model.rest[b], axis=1)
        positions = model.rest + delta
        eps = np.linalg.norm(positions[a] - positions[b], axis=1) / rest_length - 1.0
        factor = np.asarray(s(eps.reshape(1, -1)).full()).ravel() if k0 != 0.0 else 1.0
        stiffness = 0
        for t, matrix in self.edges.items():
            springs = matrix.minimum(0.0)
            stiffness = stiffness + coefficients[t] * (
                sp.diags(np.broadcast_to(factor, n_pairs)) @ springs + matrix.maximum(0.0)
            )
        difference = delta[a] - delta[b]  # (n_pairs, 3)
        flat = np.vstack(
            [-(incidence @ (sp.diags(difference[:, i]) @ stiffness)).toarray() for i in range(3)]
        )
        if coupling != 0.0:
            div = self.divergence @ delta.T.reshape(-1)
            flat = flat + coupling * (self.divergence.T @ (sp.diags(div) @ self.weights)).toarray()
        return flat[np.concatenate([model.free + k * n for k in range(3)])]


def cell_columns(model, problem: PlanarProblem, x: np.ndarray, states: list, cells) -> np.ndarray:
    """d(residual)/d(theta_c) of every cell at the fit (x, states), (n_residuals, n_cells).

    theta_c is the relative stiffness change of cell c (ratio 1 + theta_c, estimated in
    log space: at theta = 0 both derivatives agree). ``cells`` gives dg/dtheta_c at each
    equilibrium (``force_columns``): ``CellTerms`` for the paper's energy,
    ``continuum_cells.ContinuumCells`` for the large-strain continuum; the state's
    sensitivity is -(dg/ds)^-1 dg/dtheta_c with dg/ds at the equilibrium.
    """
    names = problem.names
    n, n_free = model.rest.shape[0], model.n_free
    jacobian = EquilibriumSolver(model, names).jacobian
    columns = []
    for case, state in zip(problem.cases, states):
        delta = np.zeros((n, 3))
        delta[model.free] = state[: 3 * n_free].reshape(3, n_free).T
        d_g = np.zeros((state.size, cells.weights.shape[1]))
        d_g[: 3 * n_free] = cells.force_columns(model, names, x, delta)
        d_s = jacobian(state, x, case.force, case.prescribed)
        sensitivity = -sp.linalg.splu(d_s).solve(d_g)
        columns.append(problem.case_residual_jacobian(case) @ sensitivity)
    return np.vstack(columns)


def profiled_cell_columns(
    model, cases: list, names: tuple, x: np.ndarray, bounds: dict, cells, states=None
) -> tuple[np.ndarray, np.ndarray]:
    """The residual r and the cells' columns with the fitted parameters profiled out
    (``states``: the equilibria at x, if known).

    Returns
    -------
    r : numpy.ndarray
        The weighted residual at (names, x), (n_residuals,).
    columns : numpy.ndarray
        (I - Q Q^T) dr/dtheta_c, Q an orthonormal basis of dr/dx: what a cell's change
        does that no refit of x can undo, (n_residuals, n_cells).
    """
    space = SkinParameterSpace.build(names, dict(zip(names, x)), bounds)
    problem = PlanarProblem(model, cases, space)
    solver = stage_solver(problem)
    if states is not None:
        solver.seed(space.start, states)
    r, jac_x = solver.evaluate(space.to_internal(space.start))
    states = solver.states
    columns = cell_columns(model, problem, space.start, states, cells)
    basis, _ = np.linalg.qr(jac_x)
    return r, columns - basis @ (basis.T @ columns)


# ---------------------------------------------------------------------------- the scan
@dataclass(frozen=True)
class ScanResult:
    """The rectangle scan at one fitted stage.

    Attributes
    ----------
    score : Score
        The best rectangle's score test (p-value Bonferroni-corrected).
    box : tuple of int
        Its cells (i0, i1, j0, j1).
    rect : Rect
        Its extent [mm].
    n_candidates : int
        Rectangles scored (with non-zero information).
    cell_statistic : numpy.ndarray
        Signed score statistic of every single cell, (n_x, n_y) (sign: direction).
    """

    score: Score
    box: tuple
    rect: Rect
    n_candidates: int
    cell_statistic: np.ndarray


def scan(
    model: SkinSlabModel,
    cases: list,
    names: tuple,
    x: np.ndarray,
    bounds: dict,
    grid: CellGrid,
    cells: CellTerms | None = None,
    stiffer: bool = True,
    states: list | None = None,
) -> ScanResult:
    """Score every rectangle of cells as the region of a second material at (names, x).

    ``stiffer``: one-sided, as k0 >= 0: the candidate is a stiffer inclusion (a scar),
    and a rectangle whose score asks for a softer one scores 0.
    """
    cells = cells if cells is not None else CellTerms.build(model, grid)
    r, columns = profiled_cell_columns(model, cases, names, x, bounds, cells, states)
    gradient = columns.T @ r
    gram = columns.T @ columns
    sigma2 = float(r @ r) / max(r.size - len(names), 1)
    boxes = grid.boxes()
    masks = np.array([grid.mask(b) for b in boxes])
    g = masks @ gradient
    info = np.einsum("ij,jk,ik->i", masks, gram, masks)
    valid = info > 1e-12 * info.max()
    statistic = np.where(valid, g**2 / (sigma2 * np.where(valid, info, 1.0)), 0.0)
    if stiffer:
        statistic = np.where(g < 0.0, statistic, 0.0)  # -g > 0: theta should grow
    best = int(np.argmax(statistic))
    n_candidates = int(valid.sum())
    one_sided = 0.5 if stiffer else 1.0
    p_value = min(1.0, one_sided * float(stats.chi2.sf(statistic[best], 1)) * n_candidates)
    score = Score(
        SCAN,
        float(statistic[best]),
        p_value,
        0.5 * float(statistic[best]) * sigma2,
        float(-np.sign(g[best])),
    )
    single = np.diag(gram)
    cell_valid = single > 1e-12 * single.max()
    cell_stat = np.where(
        cell_valid, -np.sign(gradient) * gradient**2 / (sigma2 * np.where(cell_valid, single, 1)), 0
    )
    return ScanResult(
        score, boxes[best], grid.rect(boxes[best]), n_candidates, cell_stat.reshape(grid.shape)
    )


# ------------------------------------------------------------------------------ overlap
def overlap(found, polygon: np.ndarray, region: Rect, step: float = 0.1) -> dict:
    """How a found region overlaps a polygon, on a fine grid of points.

    ``found`` is a ``Rect`` or a function of model-frame points (n, 2) [mm] giving a
    mask (n,), e.g. the significant cells of a map.

    Returns
    -------
    dict
        ``inside_fraction`` |R n K| / |R| (how much of the found region lies in the
        outline), ``iou`` |R n K| / |R u K|, ``recall`` |R n K| / |K|,
        ``centroid_inside`` (R's area centroid), ``centroid_mm``,
        ``centroid_distance_mm`` (to K's), ``chance`` |K| / |slab| (the inside fraction
        of a region placed at random), areas [mm^2]; an empty R gives only ``chance``
        and ``area_outline_mm2``.
    """
    x = np.arange(region.x0 + step / 2, region.x1, step)
    y = np.arange(region.y0 + step / 2, region.y1, step)
    grid = np.column_stack([g.ravel() for g in np.meshgrid(x, y, indexing="xy")])
    polygon = np.asarray(polygon, dtype=float)
    in_k = points_in_polygon(grid, polygon)
    in_r = found.contains(grid, tol=0.0) if isinstance(found, Rect) else found(grid)
    cell = step**2
    area_k = float(in_k.sum()) * cell
    out = {"chance": area_k / (region.width * region.height), "area_outline_mm2": area_k}
    if not in_r.any():
        return out
    both = float(np.sum(in_k & in_r)) * cell
    area_r = float(in_r.sum()) * cell
    centroid = grid[in_r].mean(axis=0)
    out.update(
        {
            "inside_fraction": both / area_r,
            "iou": both / (area_r + area_k - both),
            "recall": both / area_k,
            "centroid_mm": centroid.tolist(),
            "centroid_inside": bool(points_in_polygon(centroid[None], polygon)[0]),
            "centroid_distance_mm": float(np.linalg.norm(centroid - grid[in_k].mean(axis=0))),
            "area_found_mm2": area_r,
        }
    )
    return out
