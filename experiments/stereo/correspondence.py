"""Which dot is which marker: the rest capture's dots labelled on the marker lattice, then
matched in the loaded captures and across cameras along epipolar lines
(docs/reconstruction.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .cameras import Camera
from .lattice import grid_lattice

_AXES = (np.eye(2, dtype=int), np.eye(2, dtype=int)[::-1])


_PERMUTATIONS = [np.diag(s) @ p for p in _AXES for s in ((1, 1), (1, -1), (-1, 1), (-1, -1))]


def _lattice(centres: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lattice coordinates, pixels and affine step matrix (columns: d pixel / d a, d b)."""
    try:
        coords, valid = grid_lattice(centres)
    except ValueError as err:
        raise ValueError(f"{name}: no dot grid found ({err})") from None
    ab, pix = coords[valid], centres[valid]
    design = np.column_stack([np.ones(len(ab)), ab])
    return ab, pix, np.linalg.lstsq(design, pix, rcond=None)[0][1:].T


def _place(ab: np.ndarray, T: np.ndarray, shape: tuple[int, int]) -> np.ndarray | None:
    """Grid indices ``T (a, b) - min``, or None unless they span exactly ``shape``."""
    ij = ab @ T.T
    ij -= ij.min(axis=0)
    return ij if tuple(ij.max(axis=0) + 1) == tuple(shape) else None


def epipolar_px(a: Camera, b: Camera, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance of pixel pairs (n, 2) in cameras a and b [px]."""
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
    xa = np.column_stack([a.undistort_normalized(pa), np.ones(len(pa))])
    xb = np.column_stack([b.undistort_normalized(pb), np.ones(len(pb))])
    lb, la = xa @ E.T, xb @ E
    alg = np.abs(np.sum(xb * lb, axis=1))  # |x_b^T E x_a|, normalised units
    in_b = alg / np.hypot(lb[:, 0], lb[:, 1]) * b.K[0, 0]
    in_a = alg / np.hypot(la[:, 0], la[:, 1]) * a.K[0, 0]
    return 0.5 * (in_a + in_b)


def label_rest(centres, cameras, shape, label_px=2.0, names=None) -> np.ndarray:
    """Index the rest dots of every view: observations (C, U * V, 2) [px] of marker i * V + j.

    Camera 0 takes the signed axis permutation that shows i to the right and j upwards, and
    its lattice must span exactly U x V sites. Every other view takes the one permutation with
    the full extent and camera 0's handedness whose pairs with camera 0 fit the calibrated
    epipolar geometry (median within ``label_px`` [px], the runner-up 10 times worse).

    Raises
    ------
    ValueError
        If a view shows no grid or not all of it, camera 0's grid is turned by about 45
        degrees, or no labelling (or more than one) of a view agrees with camera 0.
    """
    names = names or [f"camera {c}" for c in range(len(cameras))]
    U, V = shape
    obs = np.full((len(cameras), U * V, 2), np.nan)
    ab, pix, M = _lattice(centres[0], names[0])
    cos = [
        min(D[0, 0] / np.linalg.norm(D[:, 0]), -D[1, 1] / np.linalg.norm(D[:, 1]))
        for D in (M @ T.T for T in _PERMUTATIONS)
    ]
    T = _PERMUTATIONS[int(np.argmax(cos))]
    if max(cos) < np.cos(np.radians(40)):
        raise ValueError(
            f"{names[0]}: the grid is turned by about 45 degrees; camera 0 must see "
            "i to the right and j upwards"
        )
    ij = _place(ab, T, shape)
    if ij is None:
        span = np.ptp(ab @ T.T, axis=0) + 1
        raise ValueError(
            f"{names[0]}: the dot lattice spans {span[0]} x {span[1]} sites, not "
            f"{U} x {V}: the whole grid must be visible in every rest image"
        )
    obs[0, ij[:, 0] * V + ij[:, 1]] = pix
    handed = np.sign(np.linalg.det(M @ T.T))
    for c in range(1, len(cameras)):
        ab, pix, M = _lattice(centres[c], names[c])
        options = []
        for T in _PERMUTATIONS:
            ij = _place(ab, T, shape)
            if ij is None or np.sign(np.linalg.det(M @ T.T)) != handed:
                continue
            flat = ij[:, 0] * V + ij[:, 1]
            both = np.isfinite(obs[0, flat, 0])
            if both.sum() >= 8:
                err = epipolar_px(cameras[0], cameras[c], obs[0, flat[both]], pix[both])
                options.append((float(np.median(err)), flat))
        options.sort(key=lambda o: o[0])
        if not options or options[0][0] > label_px:
            best = f"{options[0][0]:.3g} px" if options else "none spans the whole grid"
            raise ValueError(
                f"{names[c]}: no labelling of its dot grid agrees with camera 0 "
                f"(best epipolar error {best}): the calibration does not match "
                "these images, or the grid is not wholly in view"
            )
        if len(options) > 1 and options[1][0] <= 10 * max(options[0][0], 0.1):
            raise ValueError(f"{names[c]}: two labellings of its grid fit camera 0 equally well")
        obs[c, options[0][1]] = pix
    return obs


def match_loaded(centres: np.ndarray, rest: np.ndarray, tol: float = 0.25) -> np.ndarray:
    """Loaded observations (n, 2) [px]: the dot (of ``centres``) nearest each rest position.

    Accepted within ``tol`` local spacings (distance to the nearest other rest dot) if no
    other dot lies within ``2 tol`` spacings and no other marker claims it; otherwise NaN.
    """
    out = np.full(rest.shape, np.nan)
    seen = np.flatnonzero(np.isfinite(rest[:, 0]))
    if len(centres) == 0 or seen.size < 2:
        return out
    spacing = np.full(len(rest), np.nan)
    spacing[seen] = cKDTree(rest[seen]).query(rest[seen], k=2)[0][:, 1]
    dist, idx = cKDTree(centres).query(rest[seen], k=2)
    dist, idx = dist.reshape(-1, 2), idx.reshape(-1, 2)
    ok = (dist[:, 0] <= tol * spacing[seen]) & (dist[:, 1] > 2 * tol * spacing[seen])
    claimed, counts = np.unique(idx[ok, 0], return_counts=True)
    ok &= ~np.isin(idx[:, 0], claimed[counts > 1])
    out[seen[ok]] = centres[idx[ok, 0]]
    return out
