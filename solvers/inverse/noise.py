"""The noise model of a dataset's marker residual, and its whitening (docs/inverse.md, eq. 24).

Every marker coordinate, rest and loaded, is measured with standard deviation sigma.
The rest markers define the geometry and are shared by all load cases, so the
residual r = W (S B - Y) of the cases has

    Cov(r) = sigma^2 (D + P P^T),

with D = diag(w^2) (the loaded noise; w = 1 for datasets) and P the map of the
rest-marker noise into every residual (``rest_noise_map``). With unit weights the
whitening is closed form: every row of P picks one rest-marker coordinate, so
N = P^T P is diagonal and

    W = (I + P P^T)^-1/2 = I - P diag(d) P^T,   d_j = (1 - (1 + N_jj)^-1/2) / N_jj

(W^2 = I - P (I + N)^-1 P^T = (I + P P^T)^-1 by Woodbury). Under pure noise
rho = W r has covariance sigma^2 I, and |rho|^2 / sigma^2 ~ chi^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


def rest_noise_map(
    cases, rest_noise: bool = True, observed: tuple[int, ...] = (0, 1, 2)
) -> sp.csr_matrix | None:
    """P, mapping rest-marker coordinate noise into the stacked residual of ``cases``.

    Parameters
    ----------
    cases : list of LoadCase
        Cases with ``marker_index`` (which rest marker each observation is) and weights.
    rest_noise : bool
        False when the rest geometry is exact (then there is no P).
    observed : tuple of int
        The components the markers are observed in (``InverseProblem.observed``); a
        case's force rows (``LoadCase.force_rows``) follow its markers' and carry no
        rest-marker noise.

    Returns
    -------
    scipy.sparse.csr_matrix or None
        (sum of len(observed) n_obs + n_F, 3 n_markers), or None without rest noise.
    """
    if not rest_noise or any(c.marker_index is None for c in cases):
        return None
    seen = [int(c.marker_index.max()) for c in cases if c.marker_index.size]
    n_markers = 1 + max(seen, default=-1)
    select = sp.identity(3, format="csr")[list(observed)]
    blocks = []
    for case in cases:
        n = case.n_observations
        pick = sp.csr_matrix(
            (case.weights, (np.arange(n), case.marker_index)), shape=(n, n_markers)
        )
        blocks.append(sp.kron(select, pick))
        if getattr(case, "force_rows", None) is not None:
            blocks.append(sp.csr_matrix((case.force_rows.shape[0], 3 * n_markers)))
    return sp.vstack(blocks).tocsr()


@dataclass(frozen=True)
class Whitening:
    """W = (I + P P^T)^-1/2 of ``n`` residuals, and the mean variance of a marker row.

    Attributes
    ----------
    matrix : scipy.sparse.csr_matrix
        W, (n, n).
    trace_factor : float
        tr(I + P P^T) / m over the m marker rows: the mean variance of one marker
        residual over sigma^2.
    """

    matrix: sp.csr_matrix
    trace_factor: float

    @classmethod
    def of(cls, p_map: sp.spmatrix | None, n: int, markers: int | None = None) -> Whitening:
        """The whitening of ``n`` residuals with rest-noise map ``p_map`` (None: W = I),
        ``markers`` of them marker rows (default all; the others are force rows, which P
        does not reach)."""
        if p_map is None:
            return cls(sp.identity(n, format="csr"), 1.0)
        counts = np.asarray(p_map.multiply(p_map).sum(axis=0)).ravel()
        shrink = np.zeros_like(counts)
        seen = counts > 0
        shrink[seen] = (1.0 - 1.0 / np.sqrt(1.0 + counts[seen])) / counts[seen]
        matrix = sp.identity(n, format="csr") - p_map @ sp.diags(shrink) @ p_map.T
        markers = n if markers is None else markers
        return cls(matrix.tocsr(), float(markers + counts.sum()) / max(markers, 1))

    @staticmethod
    def root(p_map: sp.spmatrix | None, n: int) -> sp.csr_matrix:
        """W^-1 = (I + P P^T)^1/2 = I + P diag(e) P^T, e_j = ((1 + N_jj)^1/2 - 1) / N_jj:
        what undoes the whitening, so that the rows of some cases can be whitened on
        their own (a subset of the load cases shares fewer rest-marker rows)."""
        if p_map is None:
            return sp.identity(n, format="csr")
        counts = np.asarray(p_map.multiply(p_map).sum(axis=0)).ravel()
        grow = np.zeros_like(counts)
        seen = counts > 0
        grow[seen] = (np.sqrt(1.0 + counts[seen]) - 1.0) / counts[seen]
        return (sp.identity(n, format="csr") + p_map @ sp.diags(grow) @ p_map.T).tocsr()

    def noise_rms(self, sigma: float, components: int = 3) -> float:
        """Expected RMS marker distance of a pure-noise residual over the ``components``
        observed coordinates of a marker: sigma sqrt(components tr / m) [mm]."""
        return float(sigma * np.sqrt(components * self.trace_factor))
