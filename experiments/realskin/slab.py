"""The extensometer's slab: its volume and the glued pads.

Geometry (model frame of ``geometry.geo``, units mm, N):

- the slab covers the modelled rectangle (100 x 50 mm), outer surface (the skin, w = 1)
  at z = 0, inner surface (w = 0) at z = -thickness; the map from (u, v) to (x, y) is
  linear, so a material point's (u, v) is its position scaled to the rectangle;
- each pad is a k x k grid of prescribed skin points covering its 8 x 8 mm square: the
  fixed pad's displacement is 0, the moving pad's the measured pad displacement.

The model built on them is ``symbolic.skin_slab.SkinSlabModel``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.realskin.geometry import Rect
from symbolic.loads import PrescribedDisplacement
from symbolic.volume import VolumeSpline


def slab_volume(region: Rect, thickness: float, grid: tuple[int, int] = (31, 17)) -> VolumeSpline:
    """A flat slab over ``region``: bicubic in-plane, linear through the thickness.

    Parameters
    ----------
    region : Rect
        Modelled rectangle in the model frame [mm].
    thickness : float
        Slab thickness [mm]; outer surface z = 0, inner z = -thickness.
    grid : tuple of int
        Control points (M, N) in u (x) and v (y); L = 2 layers.

    Returns
    -------
    VolumeSpline
        The fitted rest volume (exact: the slab is a trilinear shape).
    """
    if thickness <= 0:
        raise ValueError(f"thickness must be > 0 mm, got {thickness}")
    m, n = (int(g) for g in grid)
    x = np.linspace(region.x0, region.x1, 2 * m + 1)
    y = np.linspace(region.y0, region.y1, 2 * n + 1)
    points = np.zeros((x.size, y.size, 2, 3))
    points[..., 0] = x[:, None, None]
    points[..., 1] = y[None, :, None]
    points[:, :, 0, 2] = -thickness
    volume, _ = VolumeSpline.fit(points, (m, n, 2), (3, 3, 1), parameterization="uniform")
    return volume


def surface_uv(region: Rect, points_xy: np.ndarray) -> np.ndarray:
    """(u, v) on the slab's skin of points (n, 2) [mm] in the model frame."""
    points_xy = np.atleast_2d(np.asarray(points_xy, dtype=float))
    uv = np.column_stack(
        [
            (points_xy[:, 0] - region.x0) / region.width,
            (points_xy[:, 1] - region.y0) / region.height,
        ]
    )
    if np.any(uv < -1e-9) or np.any(uv > 1 + 1e-9):
        raise ValueError("points lie outside the modelled region; enlarge the region")
    return np.clip(uv, 0.0, 1.0)


def pad_points(pad: Rect, per_side: int = 4) -> np.ndarray:
    """A per_side x per_side grid of points (n, 2) [mm] covering a pad, edges included."""
    if per_side < 2:
        raise ValueError(f"per_side must be >= 2, got {per_side}")
    t = np.linspace(0.0, 1.0, per_side)
    return np.array([[pad.x0 + a * pad.width, pad.y0 + b * pad.height] for a in t for b in t])


@dataclass(frozen=True)
class Pads:
    """The prescribed skin points of both pads.

    Attributes
    ----------
    prescribed : PrescribedDisplacement
        All pad points, the moving pad's first.
    n_moving : int
        Number of moving-pad points.
    """

    prescribed: PrescribedDisplacement
    n_moving: int

    @classmethod
    def build(cls, region: Rect, moving: Rect, fixed: Rect, per_side: int = 4) -> Pads:
        """Pads from their rectangles [mm] (model frame)."""
        points = np.vstack([pad_points(moving, per_side), pad_points(fixed, per_side)])
        return cls(PrescribedDisplacement(surface_uv(region, points)), per_side**2)

    @property
    def moving_index(self) -> np.ndarray:
        """Indices of the moving pad's points in ``prescribed.uv``."""
        return np.arange(self.n_moving)

    def displacement(self, moving_mm: np.ndarray) -> np.ndarray:
        """d (m, 3) [mm]: the moving pad's in-plane displacement (2,), the fixed pad 0."""
        d = np.zeros((len(self.prescribed.uv), 3))
        d[: self.n_moving, :2] = np.asarray(moving_mm, dtype=float)[:2]
        return d
