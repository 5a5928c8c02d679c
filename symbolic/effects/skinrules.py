"""Geometry of the skin that effects integrate over: the surface frame at a contact and the
quadrature rules on the model's faces and skin (docs/effects.md, "The effects")."""

from __future__ import annotations

import numpy as np

from symbolic.effects.base import per_model
from symbolic.model import TissueModel

_FRAMES: dict = {}


def surface_frame(model: TissueModel, uv: np.ndarray) -> tuple[np.ndarray, ...]:
    """At (u, v) on the rest skin: V_u, V_v [mm], unit tangents e1, e2 and normal n."""
    key = tuple(np.asarray(uv, dtype=float).ravel())
    return per_model(_FRAMES, model, key, lambda: _surface_frame(model, uv))


def _surface_frame(model: TissueModel, uv: np.ndarray) -> tuple[np.ndarray, ...]:
    params = model.volume.outer_params(np.asarray(uv, dtype=float)[None])
    du = model.volume.evaluate(params, (1, 0, 0))[0]
    dv = model.volume.evaluate(params, (0, 1, 0))[0]
    normal = model.volume.outer_normal(np.asarray(uv, dtype=float)[None])[0]
    e1 = du / np.linalg.norm(du)
    e2 = np.cross(normal, e1)
    return du, dv, e1, e2, normal


def face_rule(model: TissueModel, axis: int, value: float, points_per_span: int | None = None):
    """Gauss points on the face where parameter ``axis`` equals ``value``.

    Returns the points (n, 3), their physical area weights [mm^2] and the two
    tangent derivatives of the volume along the face's parameters, in (u, v, w) order.
    """
    from symbolic.basis import gauss_rule

    first, second = (a for a in range(3) if a != axis)
    bases = model.volume.basis.bases
    (s, ws), (t, wt) = (gauss_rule(bases[a], points_per_span) for a in (first, second))
    ss, tt = np.meshgrid(s, t, indexing="ij")
    params = np.empty((ss.size, 3))
    params[:, axis], params[:, first], params[:, second] = value, ss.ravel(), tt.ravel()
    d_first, d_second = (
        model.volume.evaluate(params, tuple(int(a == b) for b in range(3))) for a in (first, second)
    )
    area = np.linalg.norm(np.cross(d_first, d_second), axis=1)
    return params, np.outer(ws, wt).ravel() * area, d_first, d_second


def surface_rule(model: TissueModel, w: float, points_per_span: int | None = None):
    """Gauss points (u, v, w) on the surface w = const with physical area weights [mm^2],
    and V_u, V_v there."""
    return face_rule(model, 2, w, points_per_span)
