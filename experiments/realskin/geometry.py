"""The extensometer's geometry from gmsh's ``geometry.geo``: region, pads and keloid outline.

All coordinates are in the model frame of ``experiments.realskin.data`` (the gmsh
coordinates: rectangle [0, 100] x [-5, 45] mm, pads centred on y = 20). The .geo text is
read by ``experiments.data.gmshgeo``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.data.gmshgeo import loop_polygon, parse_geo


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle [x0, x1] x [y0, y1] in the model frame [mm]."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def height(self) -> float:
        return self.y1 - self.y0

    def contains(self, points: np.ndarray, tol: float = 1e-3) -> np.ndarray:
        """Mask (N,) of points (N, 2) [mm] lying inside by more than ``tol`` [mm]."""
        x, y = np.asarray(points, dtype=float).T
        return (x > self.x0 + tol) & (x < self.x1 - tol) & (y > self.y0 + tol) & (y < self.y1 - tol)


@dataclass(frozen=True)
class SkinGeometry:
    """Geometry of ``geometry.geo`` in the model frame [mm].

    Attributes
    ----------
    region, pad_moving, pad_fixed : Rect
        Modelled rectangle and the two pads (bounding boxes of their physical lines).
    keloid : ndarray (V, 2) or None
        Closed polygon of the physical surface "keloid" (last vertex not repeated);
        splines are replaced by the polyline through their control points.
    variables : dict
        The evaluated gmsh variables.
    """

    region: Rect
    pad_moving: Rect
    pad_fixed: Rect
    keloid: np.ndarray | None
    variables: dict

    @property
    def pad_gap_mm(self) -> float:
        """Distance between the pads' inner edges [mm]."""
        return self.pad_fixed.x0 - self.pad_moving.x1


def _bbox_of_lines(geo: dict, word: str) -> Rect:
    ids = [c for name, cs in geo["physical"].items() if word in name for c in cs]
    if not ids:
        raise ValueError(f"no physical line named like {word!r} in the .geo file")
    pts = np.array([geo["points"][p] for c in ids for p in geo["curves"][c]])
    return Rect(*(float(v) for v in (*pts.min(axis=0), *pts.max(axis=0))))


def geometry_from_geo(text: str) -> SkinGeometry:
    """The modelled region, pads and (if present) keloid polygon of a ``.geo`` text."""
    geo = parse_geo(text)
    keloid = None
    if "keloid" in geo["physical"]:
        keloid = loop_polygon(geo, geo["surfaces"][geo["physical"]["keloid"][0]][0])
    return SkinGeometry(
        region=_bbox_of_lines(geo, "boundary"),
        pad_moving=_bbox_of_lines(geo, "moving_pad"),
        pad_fixed=_bbox_of_lines(geo, "fixed_pad"),
        keloid=keloid,
        variables=dict(geo["variables"]),
    )


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Mask (N,) of points (N, 2) inside the polygon (V, 2) by the even-odd rule
    (matplotlib's ``Path.contains_points``; the outlines here do not cross themselves)."""
    from matplotlib.path import Path

    points = np.asarray(points, dtype=float).reshape(-1, 2)
    return Path(np.asarray(polygon, dtype=float)).contains_points(points)
