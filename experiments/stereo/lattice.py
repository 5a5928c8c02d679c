"""Integer lattice coordinates for dots forming a (curved) 2D grid.

:func:`grid_lattice` gives each dot lattice coordinates ``(a, b)`` by
growing a grid from a seed dot. Every new dot must lie within a fraction of
the local spacing of the position predicted by a local polynomial (quadratic
where possible) fitted to the already-labelled dots within 3 steps of it; a
final leave-one-out pass re-predicts every dot from its neighbours and drops
any that disagree. A missing dot therefore leaves a hole: it is never filled
by a neighbouring dot, which sits a whole spacing away from the prediction.
Several seeds are grown and the largest lattice is kept.

Which lattice coordinates are which object indices is decided in
:mod:`.gridlabel`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

_NEIGHBOURS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def _fit_local(offsets: np.ndarray, pixels: np.ndarray):
    """Least-squares polynomial pixel(a, b) around a target at offset (0, 0).

    Uses quadratic terms only in directions with 3+ distinct lattice values.
    Returns (prediction, d/da, d/db) or None when under-determined.
    """
    na = np.unique(offsets[:, 0]).size
    nb = np.unique(offsets[:, 1]).size
    if na < 2 or nb < 2:
        return None
    a, b = offsets[:, 0].astype(float), offsets[:, 1].astype(float)
    cols = [np.ones_like(a), a, b]
    if na >= 3:
        cols.append(a * a)
    if nb >= 3:
        cols.append(b * b)
    if len(cols) + 1 < offsets.shape[0]:
        cols.append(a * b)
    A = np.stack(cols, axis=1)
    if offsets.shape[0] <= A.shape[1] - 1 or np.linalg.matrix_rank(A) < A.shape[1]:
        return None
    coef = np.linalg.lstsq(A, pixels, rcond=None)[0]
    return coef[0], coef[1], coef[2]


class _Lattice:
    """Mutable lattice: coordinate -> dot index, grown from a seed."""

    def __init__(self, centers: np.ndarray, tree: cKDTree, radius: int, tol: float):
        self.centers, self.tree, self.radius, self.tol = centers, tree, radius, tol
        self.index: dict[tuple[int, int], int] = {}
        self.used: set[int] = set()

    def add(self, coord: tuple[int, int], idx: int) -> None:
        self.index[coord] = idx
        self.used.add(idx)

    def window(self, coord: tuple[int, int], exclude_self: bool = True):
        r = self.radius
        offs, pix = [], []
        for da in range(-r, r + 1):
            for db in range(-r, r + 1):
                if exclude_self and da == 0 and db == 0:
                    continue
                idx = self.index.get((coord[0] + da, coord[1] + db))
                if idx is not None:
                    offs.append((da, db))
                    pix.append(self.centers[idx])
        return np.asarray(offs, dtype=int).reshape(-1, 2), np.asarray(pix).reshape(-1, 2)

    def predict(self, coord: tuple[int, int]):
        """Predicted pixel position and acceptance radius [px], or None."""
        offs, pix = self.window(coord)
        if offs.shape[0] < 4:
            return None
        fit = _fit_local(offs, pix)
        if fit is None:
            return None
        pred, da, db = fit
        spacing = min(np.linalg.norm(da), np.linalg.norm(db))
        return pred, self.tol * spacing

    def grow(self) -> None:
        frontier = {(c[0] + d[0], c[1] + d[1]) for c in self.index for d in _NEIGHBOURS}
        while True:
            frontier -= set(self.index)
            added = False
            order = sorted(frontier, key=lambda c: -self.window(c)[0].shape[0])
            for coord in order:
                if coord in self.index:
                    continue
                guess = self.predict(coord)
                if guess is None:
                    continue
                pred, tol = guess
                dist, idx = self.tree.query(pred, k=2)
                if dist[0] > tol or dist[1] <= tol or idx[0] in self.used:
                    continue
                self.add(coord, int(idx[0]))
                frontier |= {(coord[0] + d[0], coord[1] + d[1]) for d in _NEIGHBOURS}
                added = True
            if not added:
                return

    def prune(self, tol: float) -> int:
        """Leave-one-out check: drop the worst dot off its prediction until all agree."""
        dropped = 0
        while self.index:
            worst, worst_ratio = None, 1.0
            for coord, idx in self.index.items():
                guess = self.predict(coord)
                if guess is None:
                    continue
                pred, accept = guess
                ratio = np.linalg.norm(self.centers[idx] - pred) / (accept * tol / self.tol)
                if ratio > worst_ratio:
                    worst, worst_ratio = coord, ratio
            if worst is None:
                return dropped
            self.used.discard(self.index.pop(worst))
            dropped += 1
        return dropped


def _seed_basis(centers: np.ndarray, tree: cKDTree, i: int, tol: float):
    """Two lattice steps at dot i and how many of its 8 neighbours confirm them."""
    k = min(9, centers.shape[0])
    _, nn = tree.query(centers[i], k=k)
    vecs = centers[nn[1:]] - centers[i]
    if vecs.shape[0] < 2:
        return None, 0
    u = vecs[0]
    lengths = np.linalg.norm(vecs, axis=1)
    cos = np.abs(vecs @ u) / (lengths * np.linalg.norm(u) + 1e-12)
    cand = np.flatnonzero(cos < 0.8)
    if cand.size == 0:
        return None, 0
    v = vecs[cand[0]]
    radius = tol * min(np.linalg.norm(u), np.linalg.norm(v))
    score = 0
    for sa, sb in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        d, _ = tree.query(centers[i] + sa * u + sb * v)
        score += d < radius
    return (u, v), score


def grid_lattice(
    centers: np.ndarray, tol: float = 0.3, check_tol: float = 0.2, max_seeds: int = 6
) -> tuple[np.ndarray, np.ndarray]:
    """Integer lattice coordinates of dots forming a (curved) 2D grid.

    Parameters
    ----------
    centers : numpy.ndarray
        Dot centres, shape (n, 2) [px].
    tol : float
        Acceptance radius while growing, as a fraction of the smaller local
        grid spacing.
    check_tol : float
        Tighter radius of the leave-one-out consistency check.
    max_seeds : int
        Number of seeds grown; the largest lattice is kept.

    Returns
    -------
    coords : numpy.ndarray
        (n, 2) int lattice coordinates ``(a, b)`` per dot; ``(-1, -1)`` where
        ``valid`` is False (the values themselves are arbitrary up to one
        signed axis permutation and offset).
    valid : numpy.ndarray
        (n,) bool, dots on the kept lattice.

    Raises
    ------
    ValueError
        If no 3x3 block of dots with a consistent lattice is found.
    """
    pts = np.asarray(centers, dtype=float).reshape(-1, 2)
    if pts.shape[0] < 9:
        raise ValueError(f"found {pts.shape[0]} dots; a grid needs at least 9 (3x3)")
    tree = cKDTree(pts)
    seeds = []
    for i in range(pts.shape[0]):
        basis, score = _seed_basis(pts, tree, i, tol)
        if score == 8:
            seeds.append((i, basis))
    if not seeds:
        raise ValueError("no dot has a complete 3x3 lattice neighbourhood: no grid found")
    best: _Lattice | None = None
    tried = 0
    for i, (u, v) in seeds:
        if tried >= max_seeds:
            break
        if best is not None and i in best.used:
            continue
        lat = _Lattice(pts, tree, radius=3, tol=tol)
        lat.add((0, 0), i)
        for sa in (-1, 0, 1):
            for sb in (-1, 0, 1):
                if sa or sb:
                    _, j = tree.query(pts[i] + sa * u + sb * v)
                    lat.add((sa, sb), int(j))
        lat.grow()
        lat.prune(check_tol)
        tried += 1
        if best is None or len(lat.index) > len(best.index):
            best = lat
    assert best is not None
    coords = np.full((pts.shape[0], 2), -1, dtype=int)
    valid = np.zeros(pts.shape[0], dtype=bool)
    for (a, b), idx in best.index.items():
        coords[idx] = (a, b)
        valid[idx] = True
    return coords, valid
