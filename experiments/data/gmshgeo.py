"""A reader of the subset of gmsh's ``.geo`` language the measured data use (the skin
extensometer's ``geometry.geo``): variables with arithmetic, points, lines, splines, line
loops, plane surfaces and physical groups (https://gmsh.info/doc/texinfo/gmsh.html)."""

from __future__ import annotations

import ast
import math
import operator
import re

import numpy as np

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
