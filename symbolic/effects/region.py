"""``stiffer_region``: every stiffness scaled up inside a rectangle of cells the data choose.

The skin is cut into cells, one knot span of the model's volume in (u, v) each (the
fields inside a span are polynomials, so a cell's terms are exact with the span-wise
Gauss rule), and a candidate region R is an axis-aligned rectangle of cells that does
not touch the edge of the volume (a region and its complement are the same model up
to the scale of the base stiffness, and a region at the edge would stand for the
boundary). Inside R every stiffness of the base model is multiplied by the ratio
1 + s:

    K(s) = K + s K_R,        K_R = the base stiffness integrated with the weight chi_R,  (R1)

chi_R(u, v) the indicator of R. On the paper's model K_R scales the alpha of eq. (18),
on the linear-elastic one both moduli of eq. (C3) (``weighted_stiffness``). The force
is linear in s and in the state; s >= 0 (a stiffer inclusion, a scar: the score test
is one-sided) and s <= 99 (ratio 100).

Which rectangle is a choice the data make, not a parameter: the score test scores the
family of all rectangles at once (``solvers.diagnosis.stats.family_score_test``). It
linearises once with one column per cell (``CellStiffness``, the cells' indicators as
the fields of eq. R1), sums the cells' columns over every rectangle, takes the best,
corrects its p-value for the number of rectangles (Bonferroni), and chooses that
rectangle in the effect (``StiffnessRegion.choose``). The refit is then the ordinary
one-parameter fit of s.

The effect is not in the default library (``symbolic.effects.library``): a stiffer
rectangle explains a gradient in part too, and its many rectangles would be searched on
every dataset. Ask for it by name (``dvs diagnose --candidates``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.effects.base import Effect, per_model
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.stiffness import FieldStiffness
from symbolic.model import TissueModel

DEFAULT_RECT = (0.25, 0.5, 0.5, 0.75)
"""The rectangle (u0, u1, v0, v1) of an effect whose rectangle the data have not chosen
yet (synthetic data, the library's checks): a quarter of the skin's width, off centre."""


@dataclass(frozen=True)
class CellGrid:
    """The cells of a volume: its knot spans in u and v.

    Attributes
    ----------
    u_edges, v_edges : numpy.ndarray
        Cell boundaries along u (n_u + 1,) and v (n_v + 1,) [1]: the volume's distinct
        knots. Cell (i, j) spans [u_i, u_i+1) x [v_j, v_j+1) and has index i n_v + j.
    """

    u_edges: np.ndarray
    v_edges: np.ndarray

    @classmethod
    def of(cls, model: TissueModel) -> CellGrid:
        """One cell per knot span of ``model.volume`` in u and v."""
        u, v = model.volume.basis.bases[:2]
        return cls(u.breakpoints, v.breakpoints)

    @property
    def shape(self) -> tuple[int, int]:
        """(n_u, n_v)."""
        return (self.u_edges.size - 1, self.v_edges.size - 1)

    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1]

    def cell_of(self, params: np.ndarray) -> np.ndarray:
        """The cell index of parameter points (n, 2 or 3) (u = 1 in the last cell)."""
        params = np.asarray(params, dtype=float)
        i = np.searchsorted(self.u_edges, params[:, 0], side="right") - 1
        j = np.searchsorted(self.v_edges, params[:, 1], side="right") - 1
        n_u, n_v = self.shape
        return np.clip(i, 0, n_u - 1) * n_v + np.clip(j, 0, n_v - 1)

    def indicator(self, cell: int):
        """chi of one cell as a callable of parameter points (n, 3) -> (n,)."""
        return lambda p: (self.cell_of(p) == cell).astype(float)

    def boxes(self) -> np.ndarray:
        """Every rectangle of cells that does not touch the edge, (n_boxes, 4) of
        (i0, i1, j0, j1): cells i0 <= i < i1, j0 <= j < j1, with 1 <= i0 and
        i1 <= n_u - 1 (and so along v)."""
        n_u, n_v = self.shape
        rows = [
            (i0, i1, j0, j1)
            for i0 in range(1, n_u - 1)
            for i1 in range(i0 + 1, n_u)
            for j0 in range(1, n_v - 1)
            for j1 in range(j0 + 1, n_v)
        ]
        return np.array(rows, dtype=int).reshape(-1, 4)

    def mask(self, box) -> np.ndarray:
        """The 0/1 weight of every cell for a rectangle of cells, (n_cells,)."""
        i0, i1, j0, j1 = (int(k) for k in box)
        out = np.zeros(self.shape)
        out[i0:i1, j0:j1] = 1.0
        return out.reshape(-1)

    def rect(self, box) -> tuple[float, float, float, float]:
        """The rectangle (u0, u1, v0, v1) of a rectangle of cells [1]."""
        i0, i1, j0, j1 = (int(k) for k in box)
        u, v = self.u_edges, self.v_edges
        return (float(u[i0]), float(u[i1]), float(v[j0]), float(v[j1]))

    def box_sums(self, values: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """sum over the cells of every box of ``values`` (n_cells,), (n_boxes,): by a
        2-D cumulative sum, S[i, j] = the sum over cells i' < i, j' < j."""
        table = _cumulative(np.asarray(values, dtype=float).reshape(self.shape), 2)
        i0, i1, j0, j1 = boxes.T
        return table[i1, j1] - table[i0, j1] - table[i1, j0] + table[i0, j0]

    def box_forms(self, gram: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """w_b^T G w_b of every box's mask w_b with a (n_cells, n_cells) matrix G,
        (n_boxes,): by a 4-D cumulative sum of G over (i, j, i', j'), 16 corners a box."""
        n_u, n_v = self.shape
        table = _cumulative(np.asarray(gram, dtype=float).reshape(n_u, n_v, n_u, n_v), 4)
        i0, i1, j0, j1 = boxes.T
        total = np.zeros(len(boxes))
        for a, sa in ((i1, 1.0), (i0, -1.0)):
            for b, sb in ((j1, 1.0), (j0, -1.0)):
                for c, sc in ((i1, 1.0), (i0, -1.0)):
                    for d, sd in ((j1, 1.0), (j0, -1.0)):
                        total += sa * sb * sc * sd * table[a, b, c, d]
        return total


def _cumulative(array: np.ndarray, axes: int) -> np.ndarray:
    """The cumulative sum over the first ``axes`` axes, with a leading zero on each."""
    out = np.pad(array, [(1, 0)] * axes)
    for axis in range(axes):
        out = np.cumsum(out, axis=axis)
    return out


def rect_indicator(rect):
    """chi of a rectangle (u0, u1, v0, v1) as a callable of parameter points (n, 3).

    Half-open, as the cells (``CellGrid.cell_of``): the indicator of a rectangle of
    cells is the sum of its cells' indicators at every point inside the volume.
    """
    u0, u1, v0, v1 = (float(r) for r in rect)

    def chi(p):
        p = np.asarray(p, dtype=float)
        u, v = p[:, 0], p[:, 1]
        return ((u >= u0) & (u < u1) & (v >= v0) & (v < v1)).astype(float)

    return chi


class CellStiffness(FieldStiffness, Effect):
    """Every stiffness times 1 + theta_c in cell c, one parameter per cell of ``grid``:
    the per-cell linearisation of ``stiffer_region`` (never fitted). Its column for cell
    c is d r / d theta_c; a rectangle's column is the sum over its cells (eq. R1 is
    linear in the field)."""

    energies = ("dnurbs", "linear-elastic")
    linear = True
    name = "stiffer_region_cells"
    equation = "(1 + theta_c) times every stiffness in cell c (eq. 18 / C3)"

    def __init__(self, grid: CellGrid) -> None:
        super().__init__()
        self.grid = grid
        n_u, n_v = grid.shape
        self.parameter_names = tuple(f"s_{i}_{j}" for i in range(n_u) for j in range(n_v))
        n = grid.n_cells
        self.units, self.scales = ("1",) * n, (1.0,) * n
        self.lower, self.upper = (0.0,) * n, (99.0,) * n

    def shapes(self, model: TissueModel):
        return [self.grid.indicator(c) for c in range(self.grid.n_cells)]

    def stiffness_terms(self, model: TissueModel) -> list:
        """The assembled terms on both energies. A cell's terms are local (the rows and
        columns of its support), so products with them are cheap; the continuum's
        matrix-free products (``field_products``) pass over every quadrature point for
        each cell (196 cells at 17 x 17 x 3: 20 of the score test's 23 s)."""
        return self.terms(model)


@dataclass(frozen=True)
class RegionFamily:
    """The rectangles ``stiffer_region`` chooses from on one model.

    Attributes
    ----------
    grid : CellGrid
        The cells.
    boxes : numpy.ndarray
        The rectangles of cells, (n_boxes, 4) (``CellGrid.boxes``).
    cells : CellStiffness
        The per-cell effect whose columns the score test sums.
    """

    grid: CellGrid
    boxes: np.ndarray
    cells: CellStiffness


class StiffnessRegion(FieldStiffness, Effect):
    """Every stiffness times 1 + s inside a rectangle R of cells (eq. R1); s = ratio - 1.

    The rectangle, in (u, v), is the effect's state: ``DEFAULT_RECT`` until
    ``choose`` sets the one the family score test found. s >= 0 makes the test
    one-sided; the upper bound 99 is a ratio of 100. Realistic magnitude 2: a scar
    three times as stiff as the skin around it.
    """

    energies = ("dnurbs", "linear-elastic")
    linear = True
    name = "stiffer_region"
    parameters = (Parameter("s_region", "1", 1.0, 0.0, 99.0),)
    magnitude = Magnitude(2.0, "1 (ratio - 1)")
    equation = "(1 + s chi_R(u, v)) times every stiffness (eq. 18 / C3), R a rectangle of cells"

    def __init__(self, rect=DEFAULT_RECT) -> None:
        super().__init__()
        self.rect = tuple(float(r) for r in rect)

    def choose(self, rect) -> None:
        """Set the rectangle (u0, u1, v0, v1) [1] (``RegionFamily``: ``grid.rect(box)``).

        A problem built with this effect keeps the stiffness of the rectangle it was
        built with: the shared store of derived problems keys its Functions by the
        effects' identity. Choose before building (the loop refits after the score
        test that chose); the effect's own terms are kept per rectangle.
        """
        u0, u1, v0, v1 = (float(r) for r in rect)
        if not (0.0 <= u0 < u1 <= 1.0 and 0.0 <= v0 < v1 <= 1.0):
            raise ValueError(f"a rectangle is 0 <= u0 < u1 <= 1, 0 <= v0 < v1 <= 1: {rect}")
        self.rect = (u0, u1, v0, v1)

    def cached(self, model: TissueModel, key, build):
        """``Effect.cached`` per rectangle: the terms of every rectangle chosen are kept."""
        return super().cached(model, (key, self.rect), build)

    def shapes(self, model: TissueModel):
        """chi_R of the chosen rectangle."""
        return [rect_indicator(self.rect)]

    def least_modulus(self, theta: np.ndarray) -> float:
        """min(0, s): inside R the modulus is 1 + s."""
        return min(0.0, float(np.min(theta)))

    def family(self, model: TissueModel) -> RegionFamily:
        """The cells and rectangles of ``model`` (built once per model)."""

        def build():
            grid = CellGrid.of(model)
            return RegionFamily(grid, grid.boxes(), CellStiffness(grid))

        return per_model(self._cache, model, "family", build, weak=False)
