"""The original authors' fit of the skin extensometer: their set-up, values and data rule.

Source: ``aflahelouneg/inverse_identification_soft_tissue`` on GitHub (MIT, the same
repository as the data), commit ``01eb720`` (2020-01-27), the last commit whose
``invsolve`` package matches ``examples/human_skin/main_v2.py``. Every fact is restated
in our words and re-implemented here; no code of theirs is copied.

* ``examples/human_skin/main_v2.py``: the frames (``linspace_range`` over the frames up
  to a pad travel of 3 mm, or 2 mm), the pad conditions (the fixed pad's hole held at 0,
  the moving pad's hole at (u_x, 0)), the outer edges **free**, the DIC origin, the
  force synchronised to the DIC frames, the cost J = sum_t Q_t + 1/2 L_t^2, and the
  converged parameter values per mesh written there as start values (the tables below).
* ``material/material.py``, class ``NeoHookean``: psi = mu/2 (I1 - d - 2 ln J) +
  lam/2 (ln J)^2 with d = 2 and F = I + grad u (2 x 2): plane strain, with the 3D Lame
  formulas (``symbolic.planar_neohookean``). E is per unit depth [N/mm].
* ``invsolve/functions.py``: Q_t = sum_i integral over the DIC box's cells of
  (u_i - u_msr,i)^2 dA [mm^4]; L_t = integral over the moving pad's edges of
  (P N)_x - f_t [N], the traction integral against the measured force.
* ``invsolve/invsolve.py``, ``InverseSolverBasic``: J summed over the observation
  times; Newton on the parameters (``examples/human_skin/config.py``).
* ``invsolve/project.py``: the DIC values projected onto the P1 nodes by moving least
  squares, quadratic basis, 9 nearest points, weight 1e-4 + (1 - 1e-4)(1 - r / r_max)^2
  (``mls_project``, written here with scipy).
* ``examples/utility.py``: ``linspace_range`` (``frame_rule``) and
  ``mark_rectangular_subdomain`` (the DIC box's cells).
* ``examples/human_skin/{monolithic,bimaterial}/mesh/``: the meshes (tags 1-5), the
  boundary and material ids (bimaterial: material 0 keloid, 1 skin).
* ``.../datafiles_processed``: byte-identical to ``../shared/data/skin-extensometer``.

Units: mm, N; E [N/mm].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.interpolate
from scipy.spatial import cKDTree

from experiments.realskin.data import SkinCase, load_case
from experiments.realskin.geometry import SkinGeometry

SOURCE = {
    "repository": "https://github.com/aflahelouneg/inverse_identification_soft_tissue",
    "commit": "01eb720",
    "license": "MIT",
    "files": [
        "examples/human_skin/main_v2.py",
        "examples/human_skin/config.py",
        "examples/utility.py",
        "material/material.py",
        "invsolve/functions.py",
        "invsolve/invsolve.py",
        "invsolve/project.py",
        "examples/human_skin/monolithic/mesh/mesh.py",
        "examples/human_skin/bimaterial/mesh/mesh.py",
    ],
}
"""Where the facts of this module were read."""

TRAVELS_MM = (3.0, 2.0)
"""The two frame ranges of the authors: pad travel up to 3 mm and up to 2 mm."""

MESH_NODES = {
    "healthy": {1: 4528, 2: 6631, 3: 12023, 4: 26003, 5: 103672},
    "keloid": {1: 4543, 2: 6760, 3: 12125, 4: 26615, 5: 105167},
}
"""Vertices of their gmsh meshes per tag (directory names under ``meshfiles/msh``)."""

HEALTHY = {
    3.0: {
        1: (2.930536e-02, 1.598242e-01),
        2: (2.913111e-02, 1.453632e-01),
        3: (2.807129e-02, 1.566669e-01),
        4: (2.772578e-02, 1.466639e-01),
        5: (2.650264e-02, 1.360912e-01),
    },
    2.0: {
        1: (3.111523e-02, 2.242006e-01),
        2: (3.100804e-02, 2.067513e-01),
        3: (2.988386e-02, 2.168054e-01),
        4: (2.960181e-02, 2.051246e-01),
        5: (2.833093e-02, 1.952619e-01),
    },
}
"""Their healthy fit, (E [N/mm], nu) per travel [mm] and mesh tag (``main_v2.py``)."""

KELOID = {
    3.0: {
        1: (1.238582e-01, 4.040724e-01),
        2: (1.135716e-01, 4.144118e-01),
        3: (1.241487e-01, 3.869594e-01),
        4: (1.204257e-01, 3.680517e-01),
        5: (1.224988e-01, 3.479096e-01),
    },
    2.0: {
        1: (7.627915e-02, 4.115764e-01),
        2: (6.921533e-02, 4.213533e-01),
        3: (7.729406e-02, 3.913648e-01),
        4: (7.539667e-02, 3.701861e-01),
        5: (7.707288e-02, 3.468716e-01),
    },
}
"""Their keloid fit, (E_keloid [N/mm], nu_keloid) per travel and tag, the skin around it
held at their healthy tag-5 values (``HELD_SKIN``)."""

HELD_SKIN = {travel: HEALTHY[travel][5] for travel in TRAVELS_MM}
"""The skin's (E, nu) they hold in the two-material keloid fit."""

ACCEPTANCE = {
    ("healthy", 3.0): {"E": 0.028, "nu": 0.15},
    ("healthy", 2.0): {"E": 0.030, "nu": 0.21},
    ("keloid", 3.0): {"E": 0.121},
    ("keloid", 2.0): {"E": 0.075},
}
"""The centre of their published values (issue 41): E within 10 %, nu within 0.03."""

HEALTHY_DIC_ORIGIN = (32.0, 20.0)
"""Healthy: the moving pad's reference point at frame 0 in the mesh frame, a fixed point
of their ``coordinates_of_moving_pad`` (2 mm inside the pad's inner edge at x = 34)."""


def authors_range(case: str, travel: float, name: str) -> tuple[float, float]:
    """(lowest, highest) of their values of ``name`` ("E" or "nu") over the five meshes."""
    table = HEALTHY if case == "healthy" else KELOID
    values = [v[0 if name == "E" else 1] for v in table[travel].values()]
    return min(values), max(values)


def dic_origin(case: str, geometry: SkinGeometry) -> np.ndarray:
    """The DIC frame's origin in the mesh frame [mm] (their placement).

    Healthy: ``HEALTHY_DIC_ORIGIN``. Keloid: the moving pad's inner-edge midpoint (their
    mesh centre minus half the .geo gap), which is also the project's placement.
    """
    if case == "healthy":
        return np.array(HEALTHY_DIC_ORIGIN)
    pad = geometry.pad_moving
    return np.array([pad.x1, 0.5 * (pad.y0 + pad.y1)])


def frame_rule(first: int, last: int, count: int) -> list[int]:
    """Their ``linspace_range``: ``count`` indices from ``last`` (inclusive) back towards
    ``first`` with the integer stride int((n - 1) / (count - 1)), n = last - first + 1,
    returned in ascending order."""
    if count <= 0:
        return []
    if count == 1:
        return [last]
    stride = max(int((last - first) / (count - 1)), 1)
    return list(range(last, first - 1, -stride))[:count][::-1]


@dataclass(frozen=True)
class Frames:
    """The observation frames of one fit.

    Attributes
    ----------
    case : str
        "healthy" or "keloid".
    max_travel_mm : float
        Frames are taken among those with pad travel up to this.
    indices : list of int
        The DIC frame numbers.
    pad_ux_mm : ndarray (K,)
        The moving pad's x displacement [mm] (negative): its hole's condition (u_x, 0).
    force_n : ndarray (K,)
        The measured x force [N] (negative), interpolated at each frame's pad displacement.
    dic_reference_mm : ndarray (P, 2)
        DIC points at frame 0 in the mesh frame [mm].
    dic_displacement_mm : ndarray (K, P, 2)
        Their displacements [mm].
    geometry : SkinGeometry
        The case's ``geometry.geo``.
    """

    case: str
    max_travel_mm: float
    indices: list
    pad_ux_mm: np.ndarray
    force_n: np.ndarray
    dic_reference_mm: np.ndarray
    dic_displacement_mm: np.ndarray
    geometry: SkinGeometry


def synchronised_force(case: SkinCase) -> tuple[np.ndarray, np.ndarray, int]:
    """Their force at every DIC frame: pad x displacement (F,), force (F,) [N] and the
    number of frames kept.

    The two records are cut to end together (the longer one keeps the first sample past
    the other's end, and one more), then the force is interpolated linearly in the force
    record at each frame's pad displacement, extrapolating at the ends.
    """
    pad = case.pad_displacement_mm[:, 0]
    ux, fx = case.force_ux_mm, case.force_fx_n
    frames = len(pad)
    if pad[-1] < ux[-1]:
        frames = int(np.flatnonzero(pad >= ux[-1])[-1]) + 2
    elif ux[-1] < pad[-1]:
        keep = int(np.flatnonzero(ux >= pad[-1])[-1]) + 2
        ux, fx = ux[:keep], fx[:keep]
    pad = pad[:frames]
    curve = scipy.interpolate.interp1d(ux, fx, kind="linear", fill_value="extrapolate")
    return pad, curve(pad), frames


def load_frames(
    case: str | SkinCase, max_travel: float = 3.0, count: int = 10, origin=None
) -> Frames:
    """Their observation frames: ``count`` frames by ``frame_rule`` among frames 1 ... n-1,
    n the first frame whose pad travel exceeds ``max_travel`` [mm].

    Parameters
    ----------
    case : str or SkinCase
        "healthy" / "keloid" (read by ``experiments.realskin.data.load_case``) or a case.
    max_travel : float
        Largest pad travel [mm] (3 or 2 for theirs; 3.83 takes every healthy DIC frame).
    count : int
        Number of frames (theirs: 10).
    origin : array-like (2,), optional
        The DIC origin in the mesh frame [mm]; default theirs (``dic_origin``).
    """
    case = load_case(case) if isinstance(case, str) else case
    pad, force, frames = synchronised_force(case)
    beyond = np.flatnonzero(np.abs(pad) > max_travel)
    n = int(beyond[0]) if beyond.size else frames
    picked = frame_rule(1, n - 1, min(n, count))
    start = np.asarray(dic_origin(case.name, case.geometry) if origin is None else origin, float)
    positions = case.dic_positions_mm
    return Frames(
        case=case.name,
        max_travel_mm=float(max_travel),
        indices=picked,
        pad_ux_mm=pad[picked],
        force_n=force[picked],
        dic_reference_mm=positions[0] + start,
        dic_displacement_mm=positions[picked] - positions[0],
        geometry=case.geometry,
    )


def mls_project(
    points: np.ndarray, values: np.ndarray, targets: np.ndarray, k: int = 9
) -> np.ndarray:
    """Moving least squares of scattered values at target points (their DIC-to-node step).

    At each target x, the quadratic p(d) = c0 + c1 dx + c2 dy + c3 dx^2 + c4 dx dy + c5 dy^2
    is fitted by weighted least squares to the ``k`` nearest points (d = x_j - x), with
    weights 1e-4 + (1 - 1e-4)(1 - r_j / r_max)^2, r_max the farthest of the k; the value
    is c0. Where the normal matrix is near singular (det below 1e-6 of its diagonal's
    product), the weighted mean is taken.

    Parameters
    ----------
    points : ndarray (P, 2)
        Where the values are given [mm].
    values : ndarray (..., P, C)
        The values (e.g. displacements of K frames: (K, P, 2)).
    targets : ndarray (Q, 2)
        Where they are wanted [mm].
    k : int
        Neighbours (theirs: 9).

    Returns
    -------
    ndarray (..., Q, C)
    """
    distance, near = cKDTree(points).query(targets, k=k)
    d = points[near] - targets[:, None, :]
    dx, dy = d[..., 0], d[..., 1]
    basis = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=2)  # (Q, k, 6)
    weight = 1e-4 + (1 - 1e-4) * (1 - distance / distance.max(axis=1, keepdims=True)) ** 2
    normal = np.einsum("qkb,qk,qkc->qbc", basis, weight, basis)
    diagonal = np.prod(np.diagonal(normal, axis1=1, axis2=2), axis=1)
    regular = np.linalg.det(normal) > 1e-6 * diagonal
    stacked = np.moveaxis(np.asarray(values, dtype=float), -2, 0)  # (P, ..., C)
    tail = stacked.shape[1:]
    near_values = stacked[near].reshape(len(targets), k, -1)  # (Q, k, R)
    out = np.empty((len(targets), near_values.shape[2]))
    if regular.any():
        rhs = np.einsum("qkb,qk,qkr->qbr", basis[regular], weight[regular], near_values[regular])
        out[regular] = np.linalg.solve(normal[regular], rhs)[:, 0]
    if (~regular).any():
        w = weight[~regular]
        out[~regular] = np.einsum("qk,qkr->qr", w, near_values[~regular]) / w.sum(1)[:, None]
    return np.moveaxis(out.reshape((len(targets), *tail)), 0, -2)
