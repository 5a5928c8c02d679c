"""The extensometer's geometry from gmsh's ``geometry.geo``: region, pads and keloid outline.

All coordinates are in the model frame of ``experiments.realskin.data`` (the gmsh
coordinates: rectangle [0, 100] x [-5, 45] mm, pads centred on y = 20). Only the
subset of the .geo language the data use is read: variables with arithmetic,
points, lines, splines, line loops and physical groups.
"""

from __future__ import annotations

import ast
import math
import operator
import re
from dataclasses import dataclass

import numpy as np


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


_OPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
}
_FUNCS = {"Sqrt": math.sqrt, "Sin": math.sin, "Cos": math.cos, "Fabs": math.fabs}


def _evaluate(expr: str, env: dict) -> float:
    """Value of a gmsh arithmetic expression using the variables in ``env``."""

    def ev(node: ast.AST) -> float:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return float(node.value)
        if isinstance(node, ast.Name):
            if node.id == "Pi":
                return math.pi
            if node.id not in env:
                raise ValueError(f"gmsh variable {node.id!r} used before it is defined")
            return env[node.id]
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.operand))
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in _FUNCS:
            return _FUNCS[node.func.id](*[ev(a) for a in node.args])
        raise ValueError(f"unsupported gmsh expression {expr!r}")

    return ev(ast.parse(expr.strip().replace("^", "**"), mode="eval").body)


_COMMENTS = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
_DELETE = re.compile(r"(?:Recursive\s+)?Delete\s*\{(?:[^{}]|\{[^{}]*\})*\}")
_ENTITY = re.compile(  # [Physical] Kind [Kind2] (tag) = {values}
    r"^(Physical\s+)?([A-Za-z]+(?:\s+[A-Za-z]+)?)\s*\(([^)]*)\)\s*=\s*\{([^}]*)\}$"
)
_ASSIGN = re.compile(r"^([A-Za-z_]\w*)\s*=\s*(.+)$", re.S)


def parse_geo(text: str) -> dict:
    """Parse the gmsh subset used here: variables, Point, Line, (B)Spline, Line/Curve Loop,
    Plane Surface and Physical groups; ``Delete`` blocks and other statements are skipped.

    Returns
    -------
    dict
        ``variables`` {name: value}, ``points`` {id: (x, y)} [mm], ``curves`` {id: [point
        ids]}, ``loops`` {id: [signed curve ids]}, ``surfaces`` {id: [loop ids]} and
        ``physical`` {name: [entity ids]}.
    """
    geo = {key: {} for key in ("variables", "points", "curves", "loops", "surfaces", "physical")}
    text = _DELETE.sub(";", _COMMENTS.sub("", text))
    for statement in (s.strip() for s in text.split(";")):
        match = _ENTITY.match(statement)
        if match:
            physical, kind, tag, body = match.groups()
            kind = " ".join(kind.split())
            values = [_evaluate(v, geo["variables"]) for v in body.split(",") if v.strip()]
            if physical:
                names = re.findall(r'"([^"]*)"', tag)
                key = names[0] if names else tag.strip()
                geo["physical"][key] = [int(v) for v in values]
                continue
            ident = int(_evaluate(tag, geo["variables"]))
            if kind == "Point":
                geo["points"][ident] = (values[0], values[1])
            elif kind in ("Line", "Spline", "BSpline"):
                geo["curves"][ident] = [int(v) for v in values]
            elif kind in ("Line Loop", "Curve Loop"):
                geo["loops"][ident] = [int(v) for v in values]
            elif kind == "Plane Surface":
                geo["surfaces"][ident] = [int(v) for v in values]
        elif (match := _ASSIGN.match(statement)) is not None:
            geo["variables"][match.group(1)] = _evaluate(match.group(2), geo["variables"])
    return geo


def loop_polygon(geo: dict, loop_id: int) -> np.ndarray:
    """Vertices (V, 2) [mm] of a closed curve loop; ValueError if it is not closed."""
    chain: list[int] = []
    for cid in geo["loops"][loop_id]:
        ids = geo["curves"][abs(cid)][:: 1 if cid > 0 else -1]
        if chain and chain[-1] != ids[0]:
            raise ValueError(f"curve loop {loop_id} is broken at curve {cid}; check the .geo")
        chain.extend(ids[1:] if chain else ids)
    if chain[0] != chain[-1]:
        raise ValueError(f"curve loop {loop_id} is not closed; check the .geo file")
    return np.array([geo["points"][p] for p in chain[:-1]], dtype=float)


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
