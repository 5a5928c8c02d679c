"""P1 triangle meshes of the extensometer, built from ``geometry.geo`` (no gmsh needed).

The authors meshed the rectangle minus the two pad holes with gmsh (their ``.msh``
files are not used here). ``build_mesh`` triangulates the same domain with scipy's
Delaunay on a graded point set:

* every pad edge and the outer rectangle sampled at the local size, so the pad holes'
  edges are mesh edges (checked: the moving pad's boundary edges add up to its
  perimeter);
* a hexagonal lattice of spacing ``h_near`` in a box around the pads and the gap, and
  ``h_far`` (default 4 ``h_near``) elsewhere, kept 0.6 of the local size away from every
  boundary;
* the keloid outline (if any) resampled at ``h_near`` and inserted, so the material
  interface follows it to within the local size; a triangle's material is that of its
  centroid (0 skin, 1 keloid).

Also: uniform red ``refine``, ``warp_gap`` (the pads moved apart by a piecewise-linear
map of x), the scalar P1 mass matrix over a set of triangles (``p1_mass``), the
triangles inside a box (``cells_in_box``) and the P1 interpolation at points
(``interpolation_matrix``). Lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay, cKDTree

from experiments.realskin.geometry import Rect, SkinGeometry, points_in_polygon


@dataclass
class Mesh2D:
    """A P1 mesh of the extensometer.

    Attributes
    ----------
    points : ndarray (N, 2)
        Nodes [mm], model (gmsh) frame.
    triangles : ndarray (M, 3)
        Counter-clockwise node indices.
    region : ndarray (M,)
        Material per triangle: 0 skin, 1 keloid.
    outer, pad_moving, pad_fixed : Rect
        The modelled rectangle and the two pad holes.
    moving, fixed, exterior : ndarray
        Boundary nodes on the moving pad, the fixed pad and the outer rectangle.
    moving_edges : ndarray (K, 2)
        The moving pad hole's boundary edges (node pairs) ...
    moving_owner : ndarray (K,)
        ... and the triangle each belongs to.
    info : dict
        How it was made (sizes).
    """

    points: np.ndarray
    triangles: np.ndarray
    region: np.ndarray
    outer: Rect
    pad_moving: Rect
    pad_fixed: Rect
    moving: np.ndarray
    fixed: np.ndarray
    exterior: np.ndarray
    moving_edges: np.ndarray
    moving_owner: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.points)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def edge_length_in(self, box: tuple | None = None) -> float:
        """Mean edge length [mm] of the triangles whose centroid lies in ``box``
        (x0, y0, x1, y1); all triangles when None."""
        tris = self.triangles
        if box is not None:
            c = self.points[tris].mean(axis=1)
            inside = (
                (c[:, 0] > box[0]) & (c[:, 0] < box[2]) & (c[:, 1] > box[1]) & (c[:, 1] < box[3])
            )
            tris = tris[inside]
        edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        return float(np.mean(np.linalg.norm(np.diff(self.points[edges], axis=1)[:, 0], axis=1)))

    def moving_normals(self) -> np.ndarray:
        """Length-weighted normals (K, 2) [mm] of ``moving_edges``, pointing out of the skin
        (into the pad hole): away from the owning triangle's third node."""
        a, b = self.points[self.moving_edges[:, 0]], self.points[self.moving_edges[:, 1]]
        normal = np.c_[b[:, 1] - a[:, 1], a[:, 0] - b[:, 0]]
        third = self.points[self.triangles[self.moving_owner]].sum(axis=1) - a - b
        inward = np.einsum("ki,ki->k", normal, third - a) > 0
        normal[inward] *= -1.0
        return normal


# ------------------------------------------------------------------------ topology
def oriented(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles with their nodes in counter-clockwise order."""
    d = points[triangles]
    twice_area = (d[:, 1, 0] - d[:, 0, 0]) * (d[:, 2, 1] - d[:, 0, 1]) - (
        d[:, 2, 0] - d[:, 0, 0]
    ) * (d[:, 1, 1] - d[:, 0, 1])
    out = np.array(triangles, dtype=np.int64)
    out[twice_area < 0] = out[twice_area < 0][:, [0, 2, 1]]
    return out


def boundary_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges (E, 2) that belong to one triangle only, and that triangle's index (E,)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(len(triangles)), 3)
    _, inverse, count = np.unique(
        np.sort(edges, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    once = count[inverse.ravel()] == 1
    return edges[once], owner[once]


def on_rect_boundary(points: np.ndarray, rect: Rect, tol: float = 1e-6) -> np.ndarray:
    """Mask (N,) of points on the boundary of ``rect`` (within ``tol`` mm)."""
    x, y = points[:, 0], points[:, 1]
    in_x = (x > rect.x0 - tol) & (x < rect.x1 + tol)
    in_y = (y > rect.y0 - tol) & (y < rect.y1 + tol)
    horizontal = in_x & ((np.abs(y - rect.y0) < tol) | (np.abs(y - rect.y1) < tol))
    vertical = in_y & ((np.abs(x - rect.x0) < tol) | (np.abs(x - rect.x1) < tol))
    return horizontal | vertical


def assemble(points, triangles, region, outer, pad_moving, pad_fixed, info=None) -> Mesh2D:
    """A ``Mesh2D``: orient the triangles, find the boundary node sets from the rectangles
    and collect the moving pad's edges."""
    triangles = oriented(points, triangles)
    edges, owner = boundary_edges(triangles)
    on_boundary = np.zeros(len(points), dtype=bool)
    on_boundary[edges.ravel()] = True
    sets = [
        np.flatnonzero(on_boundary & on_rect_boundary(points, r))
        for r in (pad_moving, pad_fixed, outer)
    ]
    on_moving = np.zeros(len(points), dtype=bool)
    on_moving[sets[0]] = True
    pad_edge = on_moving[edges[:, 0]] & on_moving[edges[:, 1]]
    return Mesh2D(
        points, triangles, np.asarray(region, dtype=np.int64), outer, pad_moving, pad_fixed,
        *sets, edges[pad_edge], owner[pad_edge], dict(info or {}),
    )  # fmt: skip


# -------------------------------------------------------------------------- mesher
def _lattice(h: float, box: tuple) -> np.ndarray:
    """Hexagonal lattice of spacing h inside box (x0, y0, x1, y1), half a step from its edges."""
    x0, y0, x1, y1 = box
    rows = np.arange(y0 + h * np.sqrt(3) / 4, y1, h * np.sqrt(3) / 2)
    columns = np.arange(x0 + h / 2, x1 + h / 2, h)
    x = columns[None, :] + 0.5 * h * (np.arange(len(rows)) % 2)[:, None]
    y = np.broadcast_to(rows[:, None], x.shape)
    points = np.c_[x.ravel(), y.ravel()]
    return points[points[:, 0] < x1]


def _rect_points(rect: Rect, h: float) -> np.ndarray:
    """The boundary of ``rect`` sampled at a spacing of at most h (corners included)."""
    nx = max(int(np.ceil(rect.width / h)), 1)
    ny = max(int(np.ceil(rect.height / h)), 1)
    xs, ys = np.linspace(rect.x0, rect.x1, nx + 1), np.linspace(rect.y0, rect.y1, ny + 1)
    sides = [
        np.c_[xs, np.full_like(xs, rect.y0)],
        np.c_[xs, np.full_like(xs, rect.y1)],
        np.c_[np.full_like(ys, rect.x0), ys],
        np.c_[np.full_like(ys, rect.x1), ys],
    ]
    return np.unique(np.round(np.concatenate(sides), 12), axis=0)


def _distance_to_rect_boundary(points: np.ndarray, rect: Rect) -> np.ndarray:
    dx = np.maximum(np.maximum(rect.x0 - points[:, 0], points[:, 0] - rect.x1), 0.0)
    dy = np.maximum(np.maximum(rect.y0 - points[:, 1], points[:, 1] - rect.y1), 0.0)
    inside = np.minimum.reduce(
        [
            points[:, 0] - rect.x0,
            rect.x1 - points[:, 0],
            points[:, 1] - rect.y0,
            rect.y1 - points[:, 1],
        ]
    )
    return np.where((dx > 0) | (dy > 0), np.hypot(dx, dy), np.abs(inside))


def _inside(points: np.ndarray, rect: Rect, tol: float = 0.0) -> np.ndarray:
    x, y = points[:, 0], points[:, 1]
    return (x > rect.x0 - tol) & (x < rect.x1 + tol) & (y > rect.y0 - tol) & (y < rect.y1 + tol)


def _resample(polygon: np.ndarray, h: float) -> np.ndarray:
    """A closed polygon resampled at arc-length spacing of about h (at least 8 points)."""
    closed = np.vstack([polygon, polygon[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], max(int(np.ceil(arc[-1] / h)), 8), endpoint=False)
    return np.c_[np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])]


def _distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance (N,) from points to a closed polygon's edges."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    rel = points[:, None, :] - a[None]
    t = np.clip(
        np.einsum("nsi,si->ns", rel, ab) / np.maximum(np.einsum("si,si->s", ab, ab), 1e-30), 0, 1
    )
    return np.min(np.linalg.norm(rel - t[..., None] * ab[None], axis=2), axis=1)


def near_box(geometry: SkinGeometry, margin: tuple = (6.0, 12.0)) -> Rect:
    """The refined box: both pads and the gap, plus ``margin`` (x, y) [mm]."""
    pm, pf = geometry.pad_moving, geometry.pad_fixed
    return Rect(pm.x0 - margin[0], pm.y0 - margin[1], pf.x1 + margin[0], pf.y1 + margin[1])


def build_mesh(
    geometry: SkinGeometry, h_near: float, h_far: float | None = None, keloid: bool = True
) -> Mesh2D:
    """Triangulate ``geometry``'s rectangle minus its two pads.

    Parameters
    ----------
    geometry : SkinGeometry
        From ``geometry.geo`` (``experiments.realskin.geometry``).
    h_near : float
        Element size [mm] around the pads and in the gap (``near_box``).
    h_far : float, optional
        Element size [mm] elsewhere; default 4 ``h_near``.
    keloid : bool
        Insert the keloid outline (if the geometry has one) and mark its triangles 1.

    Raises
    ------
    RuntimeError
        If the triangulation missed a pad edge (it has not on the sizes tried).
    """
    h_far = 4.0 * h_near if h_far is None else h_far
    outer, pads = geometry.region, (geometry.pad_moving, geometry.pad_fixed)
    box = near_box(geometry)
    coarse = _lattice(h_far, (outer.x0, outer.y0, outer.x1, outer.y1))
    grown = Rect(box.x0 - h_far / 2, box.y0 - h_far / 2, box.x1 + h_far / 2, box.y1 + h_far / 2)
    interior = np.concatenate(
        [coarse[~_inside(coarse, grown)], _lattice(h_near, (box.x0, box.y0, box.x1, box.y1))]
    )
    local = np.where(_inside(interior, box), h_near, h_far)
    keep = np.ones(len(interior), dtype=bool)
    for rect in (outer, *pads):
        keep &= _distance_to_rect_boundary(interior, rect) > 0.6 * local
    for rect in pads:
        keep &= ~_inside(interior, rect)
    interior, local = interior[keep], local[keep]
    parts = [_rect_points(outer, h_far), *(_rect_points(r, h_near) for r in pads)]
    outline = geometry.keloid if keloid else None
    if outline is not None:
        ring = _resample(np.asarray(outline, dtype=float), h_near)
        for rect in pads:
            ring = ring[
                ~_inside(ring, rect, 1e-9) & (_distance_to_rect_boundary(ring, rect) > 0.4 * h_near)
            ]
        far = _distance_to_polygon(interior, ring) > 0.5 * local
        interior = interior[far]
        parts.append(ring)
    points = np.unique(np.round(np.concatenate([*parts, interior]), 10), axis=0)
    triangles = Delaunay(points).simplices
    centroid = points[triangles].mean(axis=1)
    hole = _inside(centroid, pads[0]) | _inside(centroid, pads[1])
    triangles, centroid = triangles[~hole], centroid[~hole]
    region = np.zeros(len(triangles), dtype=np.int64)
    if outline is not None:
        region = points_in_polygon(centroid, np.asarray(outline, dtype=float)).astype(np.int64)
    used = np.unique(triangles)
    renumber = np.full(len(points), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    info = {"h_near_mm": h_near, "h_far_mm": h_far}
    mesh = assemble(points[used], renumber[triangles], region, outer, *pads, info=info)
    _check_pad_edges(mesh)
    return mesh


def _check_pad_edges(mesh: Mesh2D) -> None:
    """The moving pad hole must be closed by boundary edges along its whole perimeter."""
    pad = mesh.pad_moving
    length = np.linalg.norm(np.diff(mesh.points[mesh.moving_edges], axis=1)[:, 0], axis=1).sum()
    perimeter = 2 * (pad.width + pad.height)
    if abs(length - perimeter) > 1e-6 * perimeter or len(mesh.fixed) < 4:
        raise RuntimeError(f"the mesh missed a pad edge ({length:.4f} of {perimeter:g} mm)")


# ------------------------------------------------------------------ refine, warp
def refine(mesh: Mesh2D) -> Mesh2D:
    """Uniform red refinement: each triangle into four, new nodes at edge midpoints."""
    t = mesh.triangles
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    unique, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
    mid = len(mesh.points) + inverse.ravel().reshape(3, -1)  # ab, bc, ca per triangle
    points = np.vstack([mesh.points, mesh.points[unique].mean(axis=1)])
    a, b, c = t.T
    ab, bc, ca = mid
    children = np.vstack([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]])
    info = {**mesh.info, "refined": mesh.info.get("refined", 0) + 1}
    return assemble(
        points, children, np.tile(mesh.region, 4), mesh.outer, mesh.pad_moving, mesh.pad_fixed, info
    )


def warp_gap(mesh: Mesh2D, gap: float) -> Mesh2D:
    """The pads moved apart (or together) to a gap of ``gap`` mm, symmetric about the
    old gap's middle, by a piecewise-linear map of x: the outer edges stay, the pads keep
    their width, straight lines stay straight and every triangle its orientation.

    Raises
    ------
    ValueError
        If the pads would leave the rectangle (less than 1 mm from its edge).
    """
    pm, pf, outer = mesh.pad_moving, mesh.pad_fixed, mesh.outer
    middle = 0.5 * (pm.x1 + pf.x0)
    moving_x1, fixed_x0 = middle - gap / 2, middle + gap / 2
    if moving_x1 - pm.width < outer.x0 + 1.0 or fixed_x0 + pf.width > outer.x1 - 1.0 or gap <= 0:
        raise ValueError(f"a pad gap of {gap:g} mm does not fit in the rectangle")
    old = [outer.x0, pm.x0, pm.x1, pf.x0, pf.x1, outer.x1]
    new = [outer.x0, moving_x1 - pm.width, moving_x1, fixed_x0, fixed_x0 + pf.width, outer.x1]
    points = mesh.points.copy()
    points[:, 0] = np.interp(mesh.points[:, 0], old, new)
    moved = (Rect(new[1], pm.y0, new[2], pm.y1), Rect(new[3], pf.y0, new[4], pf.y1))
    info = {**mesh.info, "gap_mm": gap}
    return assemble(points, mesh.triangles, mesh.region, outer, *moved, info)


# ------------------------------------------------------------- fit's geometry
def triangle_areas(mesh: Mesh2D, cells=None) -> np.ndarray:
    """Areas [mm^2] of the triangles ``cells`` (default all)."""
    d = mesh.points[mesh.triangles if cells is None else mesh.triangles[cells]]
    e1, e2 = d[:, 1] - d[:, 0], d[:, 2] - d[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def p1_mass(mesh: Mesh2D, cells: np.ndarray | None = None) -> sp.csr_matrix:
    """Scalar P1 mass matrix (N, N) [mm^2] over the triangles ``cells`` (mask or index):
    M_ab = integral N_a N_b dA, the element matrix A_e (1 + delta_ab) / 12."""
    tris = mesh.triangles if cells is None else mesh.triangles[cells]
    local = triangle_areas(mesh, cells)[:, None, None] * (np.ones((3, 3)) + np.eye(3)) / 12.0
    rows, cols = np.repeat(tris, 3, axis=1).ravel(), np.tile(tris, (1, 3)).ravel()
    shape = (mesh.n_nodes, mesh.n_nodes)
    return sp.coo_matrix((local.ravel(), (rows, cols)), shape=shape).tocsr()


def cells_in_box(mesh: Mesh2D, box: tuple) -> np.ndarray:
    """Mask (M,) of triangles whose three nodes lie strictly inside box (x0, y0, x1, y1)."""
    x, y = mesh.points[mesh.triangles][..., 0], mesh.points[mesh.triangles][..., 1]
    return np.all((x > box[0]) & (x < box[2]) & (y > box[1]) & (y < box[3]), axis=1)


def _barycentric(mesh: Mesh2D, cells: np.ndarray, points: np.ndarray) -> np.ndarray:
    d = mesh.points[mesh.triangles[cells]]
    frame = np.stack([d[:, 1] - d[:, 0], d[:, 2] - d[:, 0]], axis=2)
    local = np.linalg.solve(frame, (points - d[:, 0])[..., None])[..., 0]
    return np.c_[1.0 - local.sum(axis=1), local]


def locate(mesh: Mesh2D, points: np.ndarray, candidates: int = 24, tol: float = 1e-3):
    """Triangle (K,) and barycentric coordinates (K, 3) of points (K, 2) [mm].

    Each point takes, among the ``candidates`` triangles with the nearest centroids, the
    one whose smallest barycentric coordinate is largest (inside: >= 0); a point up to
    ``tol`` (in barycentric units) outside, e.g. a DIC point on a pad edge, is snapped
    onto it.

    Raises
    ------
    ValueError
        If a point lies outside the mesh.
    """
    points = np.asarray(points, dtype=float)
    centroids = mesh.points[mesh.triangles].mean(axis=1)
    _, near = cKDTree(centroids).query(points, k=min(candidates, len(centroids)))
    bary = np.stack([_barycentric(mesh, near[:, j], points) for j in range(near.shape[1])], axis=1)
    best = np.argmax(bary.min(axis=2), axis=1)
    rows = np.arange(len(points))
    chosen, weights = near[rows, best], bary[rows, best]
    if np.any(weights.min(axis=1) < -tol):
        outside = int(np.sum(weights.min(axis=1) < -tol))
        raise ValueError(f"{outside} points lie outside the mesh (in a pad hole or beyond it)")
    weights = np.clip(weights, 0.0, None)
    return chosen, weights / weights.sum(axis=1, keepdims=True)


def interpolation_matrix(mesh: Mesh2D, points: np.ndarray) -> sp.csr_matrix:
    """Sparse (K, N) matrix that evaluates a nodal P1 field at points (K, 2) [mm]."""
    cells, weights = locate(mesh, points)
    rows = np.repeat(np.arange(len(points)), 3)
    shape = (len(points), mesh.n_nodes)
    return sp.csr_matrix((weights.ravel(), (rows, mesh.triangles[cells].ravel())), shape=shape)
