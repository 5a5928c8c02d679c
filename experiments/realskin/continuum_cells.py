"""The cells of the continuum membrane: what a cell's stiffer energy does to the equilibrium.

The cell map of real skin (``cellmap.py``) multiplies the stiffness of every cell c (one
knot span, ``scan.CellGrid``) by exp(s_c). On the paper's energy that scales the cell's
tension terms (``scan.CellTerms``); on the large-strain continuum of
``symbolic.continuum_model`` it scales the cell's whole strain energy density,

    W(X) -> exp(s_c) W(X)   for X in cell c,                                      (M1)

neo-Hookean, exponential and fibre parts alike (eq. C6, C10, C13 of docs/continuum.md; the
foundation under the membrane is not tissue and is not scaled). The internal force of
eq. (C8) is a sum over the Gauss points, so at s = 0

    d g / d s_c = f^c(Delta),   f^c_ai = sum_{q in c} P_ij(F_q) dN_a/dx_j(q) w_q |det G_q|,   (M2)

the part of the internal force that the cell's points contribute, at the equilibrium
Delta. The cells' parts sum to the tissue's internal force (tested). With the state
Jacobian dg/ds at the equilibrium, ds/ds_c = -(dg/ds)^-1 f^c, the same column the scan
and the map take from the paper's energy.

**Choice**: the whole density is scaled, so s_c is a cell's log stiffness at every
strain (E and k1 together), the continuum's counterpart of scaling every tension term
of a cell; a cell whose collagen is recruited earlier (k2) is not what the map asks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from experiments.realskin.scan import CellGrid
from symbolic.hyperelastic import piola_stress


@dataclass(frozen=True)
class ContinuumCells:
    """The Gauss points of a large-strain continuum model, assigned to the map's cells.

    Attributes
    ----------
    weights : scipy.sparse.csr_matrix
        (n_q, n_cells): w_q |det G_q| [mm^3] of each point in its cell's column.
    """

    weights: sp.csr_matrix

    @classmethod
    def build(cls, model, grid: CellGrid) -> ContinuumCells:
        """Assign every Gauss point of ``model.gradient`` to the cell it lies in."""
        gradient = model.gradient
        cell = grid.cell_of(gradient.points)
        n_q = len(gradient.volume)
        weights = sp.csr_matrix(
            (gradient.volume, (np.arange(n_q), cell)), shape=(n_q, grid.n_cells)
        )
        return cls(weights)

    def force_columns(self, model, names: tuple[str, ...], x: np.ndarray, delta: np.ndarray):
        """dg/ds_c of eq. (M2) for every cell, on the free points, (3 n_free, n_cells).

        Parameters
        ----------
        model : symbolic.continuum_model.NeoHookeanModel
            The model (neo-Hookean or exponential energy).
        names, x : tuple of str, numpy.ndarray
            The estimated parameters and their values (natural units).
        delta : numpy.ndarray
            The displacement of every control point at the equilibrium, (n, 3) [mm].

        Rows are vec(Delta_free) order (x components of the free points first), as the
        state of ``model.state_residual``.
        """
        operators = model.gradient.operators
        coefficients = model._energy_coefficients(model.values(dict(zip(names, np.ravel(x)))))
        # H_q, row-major: H[3 i + j, q] = d u_i / d x_j at point q
        h = np.array([operators[j] @ delta[:, i] for i in range(3) for j in range(3)])
        stress = piola_stress(model.exponential, model.fibres).map(h.shape[1])
        p = np.asarray(stress(h, *[float(c) for c in coefficients]).full())  # (9, n_q)
        blocks = []
        for i in range(3):
            part = sum(operators[j].T @ (sp.diags(p[3 * i + j]) @ self.weights) for j in range(3))
            blocks.append(sp.csr_matrix(part)[model.free].toarray())
        return np.vstack(blocks)
