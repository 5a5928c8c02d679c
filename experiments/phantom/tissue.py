"""FE tissue patches the model was not tuned on (the acceptance data of docs/stepzero.md).

A second reference generator beside ``experiments.phantom.fe``, built to differ from
it wherever tissue may differ from the tuned slab:

- discretisation: triquadratic hexahedra (Q2, ``ElementHex2`` on ``MeshHex``) on a
  mesh uniform over the marked area and geometrically graded beyond it, against
  ``fe``'s P2 tetrahedra on a uniform mesh;
- extent and lateral support: the tissue ends ``extent_mm`` beyond the marked area
  and is held there free, clamped, or on Robin springs; the base is fixed or on
  springs (a compliant base);
- shape: a doubly curved patch, z -= x^2 / (2 R_x) + y^2 / (2 R_y) applied to every
  node (the thickness stays vertical); the skin normal and the probe follow it;
- material: E and nu, optionally a stiffer skin layer over the fat;
- probe: a uniform pressure over a disc (or ``fe``'s Gaussian patch) whose radius the
  dataset need not declare; rectangular marker grids (e.g. 11 x 8).

The dataset path is ``fe``'s: the designs of ``fe.design_cases``, the measurement of
``experiments.phantom.simulate.measured_dataset`` and the departures of
``fe.Departure``. Lengths in mm, forces in N, E in kPa, springs in N/mm^3.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from experiments.data.dataset import Dataset
from experiments.phantom.fe import Departure, design_cases, require_skfem, rigid_departure
from experiments.phantom.simulate import SimulationSettings, measured_dataset
from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.continuum import lame

SUPPORTS = ("free", "clamped", "elastic")
"""How the lateral faces are held: not at all, fixed, or on Robin springs."""

PROBES = ("disc", "gauss")
"""Probe traction: uniform over a disc of the radius, or ``fe``'s Gaussian (sd r / 2)."""


@dataclass(frozen=True)
class TissuePatch:
    """A tissue patch (lengths in mm, E in kPa, springs in N/mm^3).

    Attributes
    ----------
    marked : tuple of float
        Extent of the marked area along x and y, centred on x = y = 0.
    extent_mm : float
        How far the tissue goes on beyond the marked area on every side.
    thickness : float
        Vertical thickness; the flat skin lies at z = thickness, the base at z = 0.
    support : str
        The lateral faces: "free", "clamped" or "elastic" (``lateral_spring``).
    lateral_spring : float
        Robin spring stiffness on the lateral faces when ``support`` is "elastic",
        every direction [N/mm^3] (0.001 N/mm^3 resists like ~1/20 of the tissue's
        E over a 1 mm length).
    curvature_radii : tuple of float or None
        (R_x, R_y): the skin bends down by x^2 / (2 R_x) + y^2 / (2 R_y); None (or
        an infinite radius) is flat in that direction.
    young_kpa, poisson : float
        The fat (or the whole patch when monolayer).
    skin_mm, skin_ratio : float
        Thickness of a top skin layer and its E over the fat's; 0 mm is monolayer.
    gradient : float
        E(x) = E (1 + gradient 2 x / marked_x), at least 0.05 E (an injected
        stiffness gradient, as ``fe.ReferenceSlab``).
    base_spring : float or None
        None fixes the base; a number rests it on Robin springs of this stiffness in
        every direction [N/mm^3] (an injected compliant base: muscle under the fat).
    spacing_mm : float
        Element size over the marked area (x and y); beyond it elements grow by
        ``growth`` per element up to the tissue's edge.
    growth : float
        Ratio of neighbouring element sizes beyond the marked area.
    layers : int
        Elements through the thickness (at least one in the skin layer).
    """

    marked: tuple[float, float] = (40.0, 30.0)
    extent_mm: float = 5.0
    thickness: float = 6.0
    support: str = "clamped"
    lateral_spring: float = 0.001
    curvature_radii: tuple[float | None, float | None] = (None, None)
    young_kpa: float = 20.0
    poisson: float = 0.45
    skin_mm: float = 0.0
    skin_ratio: float = 1.0
    gradient: float = 0.0
    base_spring: float | None = None
    spacing_mm: float = 2.5
    growth: float = 1.5
    layers: int = 3

    def __post_init__(self) -> None:
        if self.support not in SUPPORTS:
            raise ValueError(f"support must be one of {', '.join(SUPPORTS)}")
        if not (0.0 <= self.poisson < 0.5) or self.young_kpa <= 0 or self.skin_ratio <= 0:
            raise ValueError("need E > 0 kPa, 0 <= nu < 0.5 and skin_ratio > 0")
        if self.extent_mm < 0 or self.thickness <= 0 or not 0 <= self.skin_mm < self.thickness:
            raise ValueError("need extent >= 0, thickness > 0 and 0 <= skin_mm < thickness")
        if self.spacing_mm <= 0 or self.growth < 1 or self.layers < 1 or self.lateral_spring < 0:
            raise ValueError("need spacing > 0, growth >= 1, layers >= 1, lateral_spring >= 0")
        if not abs(self.gradient) < 1.0:
            raise ValueError("need |gradient| < 1")
        if self.base_spring is not None and not self.base_spring > 0:
            raise ValueError("need a positive base_spring (or None for a fixed base)")

    @property
    def lengths(self) -> tuple[float, float, float]:
        """Tissue size along x, y and its thickness [mm]."""
        return (*(m + 2 * self.extent_mm for m in self.marked), self.thickness)

    def sag(self, x, y):
        """How far the skin (and every layer) lies below the flat patch at (x, y) [mm]."""
        drop = np.zeros(np.broadcast(x, y).shape)
        for coordinate, radius in zip((x, y), self.curvature_radii):
            if radius is not None and np.isfinite(radius):
                drop = drop + np.asarray(coordinate) ** 2 / (2.0 * radius)
        return drop

    def normal(self, x: float, y: float) -> np.ndarray:
        """Outward unit skin normal at (x, y)."""
        slopes = [
            c / r if r is not None and np.isfinite(r) else 0.0
            for c, r in zip((x, y), self.curvature_radii)
        ]
        vector = np.array([*slopes, 1.0])
        return vector / np.linalg.norm(vector)


def _axis(half_marked: float, extent: float, spacing: float, growth: float) -> np.ndarray:
    """Node coordinates: uniform over [-half, half], graded beyond it to the edge."""
    inner = np.linspace(-half_marked, half_marked, max(2, round(2 * half_marked / spacing)) + 1)
    steps, size, total = [], spacing, 0.0
    while total < extent - 1e-9:
        size = size * growth
        steps.append(size)
        total += size
    if steps:
        steps = np.array(steps) * extent / total
        if len(steps) > 1 and steps[-1] < 0.5 * steps[-2]:
            steps = np.append(steps[:-2], steps[-2] + steps[-1])
    outer = half_marked + np.cumsum(steps)
    return np.concatenate([-outer[::-1], inner, outer])


def _layers(patch: TissuePatch) -> np.ndarray:
    """z nodes of the flat patch; the skin-fat interface is a node plane."""
    if patch.skin_mm == 0:
        return np.linspace(0.0, patch.thickness, patch.layers + 1)
    skin = min(max(1, round(patch.layers * patch.skin_mm / patch.thickness)), patch.layers - 1)
    fat = patch.thickness - patch.skin_mm
    return np.concatenate(
        [
            np.linspace(0.0, fat, patch.layers - skin + 1),
            np.linspace(fat, patch.thickness, skin + 1)[1:],
        ]
    )


def _elasticity(skfem, mesh, factor, mu_l: float, lam: float):
    """Stiffness of isotropic elasticity on Q2 hexahedra, in ``ElementVector``'s order.

    Assembled from the six scalar blocks B_ij = int f d_i(test) d_j(trial) (4x faster
    than the vector form): K_ij = mu (delta_ij sum_k B_kk + B_ji) + lambda B_ij, with
    ``factor`` f(x) the modulus relative to E at the quadrature points ((nel, nqp)
    from (3, nel, nqp)) and mu_l, lam the Lame parameters [N/mm^2]. Vector dof 3 d + c
    is component c of scalar dof d.
    """
    import scipy.sparse as sp

    scalar = skfem.Basis(mesh, skfem.ElementHex2(), intorder=4)
    weight = factor(scalar.global_coordinates().value)
    blocks = {}
    for i in range(3):
        for j in range(i, 3):

            @skfem.BilinearForm
            def block(u, v, w, i=i, j=j):
                return w.f * u.grad[j] * v.grad[i]

            blocks[i, j] = block.assemble(scalar, f=weight).tocsr()
            blocks[j, i] = blocks[i, j].T.tocsr()
    trace = blocks[0, 0] + blocks[1, 1] + blocks[2, 2]
    rows = [
        [
            mu_l * blocks[j, i] + lam * blocks[i, j] + (mu_l * trace if i == j else 0)
            for j in range(3)
        ]
        for i in range(3)
    ]
    order = np.arange(3 * scalar.N).reshape(3, -1).T.ravel()  # interleave the components
    return sp.bmat(rows).tocsr()[order][:, order]


class TissueSolution:
    """The patch's Q2 displacement under probe tractions on the skin, evaluated anywhere."""

    def __init__(self, patch: TissuePatch):
        skfem = self.skfem = require_skfem()
        from skfem.helpers import dot

        if patch.skin_mm > 0 and patch.layers < 2:
            raise ValueError("a skin layer needs layers >= 2")
        self.patch = patch
        (lx, ly, lz), (mx, my) = patch.lengths, patch.marked
        flat = skfem.MeshHex.init_tensor(
            _axis(mx / 2, patch.extent_mm, patch.spacing_mm, patch.growth),
            _axis(my / 2, patch.extent_mm, patch.spacing_mm, patch.growth),
            _layers(patch),
        )
        nodes = flat.p.copy()
        nodes[2] -= patch.sag(nodes[0], nodes[1])
        mesh = self.mesh = skfem.MeshHex(nodes, flat.t)
        self._axes = [np.unique(flat.p[i]) for i in range(3)]
        centre = flat.p[:, flat.t].mean(axis=1)
        ijk = [np.searchsorted(axis, c) - 1 for axis, c in zip(self._axes, centre)]
        self._cells = np.zeros([len(axis) - 1 for axis in self._axes], dtype=int)
        self._cells[ijk[0], ijk[1], ijk[2]] = np.arange(flat.t.shape[1])
        element = skfem.ElementVector(skfem.ElementHex2())
        self.basis = skfem.Basis(mesh, element, intorder=4)

        depth = lz - flat.p[2][flat.t].mean(axis=0)  # element centre below the flat skin
        layer = np.where(depth < patch.skin_mm, patch.skin_ratio, 1.0)

        def factor(x):
            return layer[:, None] * np.maximum(1.0 + patch.gradient * 2 * x[0] / mx, 0.05)

        self.matrix = _elasticity(skfem, mesh, factor, *lame(patch.young_kpa, patch.poisson))

        def on(predicate):
            return np.nonzero(predicate(flat.p[:, flat.facets]).all(axis=0))[0]

        lateral = on(lambda x: np.isclose(np.abs(x[0]), lx / 2) | np.isclose(np.abs(x[1]), ly / 2))
        base = on(lambda x: np.isclose(x[2], 0.0))

        def add_springs(stiffness: float, facets) -> None:
            @skfem.BilinearForm
            def springs(u, v, w):
                return stiffness * dot(u, v)

            self.matrix = self.matrix + springs.assemble(
                skfem.FacetBasis(mesh, element, facets=facets)
            )

        if patch.support == "elastic" and patch.lateral_spring > 0:
            add_springs(patch.lateral_spring, lateral)
        fixed = base
        if patch.base_spring is not None:  # the flat base's facets: nodes at z = 0 before the sag
            add_springs(patch.base_spring, base)
            fixed = np.zeros(0, dtype=int)
        if patch.support == "clamped":
            fixed = np.union1d(fixed, lateral)
        self.free = self.basis.complement_dofs(self.basis.get_dofs(facets=fixed))
        stiffness = self.matrix[self.free][:, self.free].tocsc()
        # symmetric positive definite: CHOLMOD (solvers/linalg/cholmod.py), else SuperLU without
        # pivoting (partial pivoting at nu = 0.49 fills in without bound on a 37k-dof
        # mesh) and a symmetric ordering
        self.factor = factorised(stiffness, symmetric_lu)
        top = on(lambda x: np.isclose(x[2], lz))
        self.top = skfem.FacetBasis(mesh, element, facets=top, intorder=8)

    def skin(self, xy: np.ndarray) -> np.ndarray:
        """Points of the rest skin above (n, 2) horizontal positions, (n, 3) [mm].

        The mesh's skin is the bilinear interpolant of the curved one; a sag that is a
        sum of a function of x and one of y keeps its facets planar, so the point lies
        on the mesh.
        """
        from scipy.interpolate import RegularGridInterpolator

        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        flat_x = np.unique(self.mesh.p[0])
        flat_y = np.unique(self.mesh.p[1])
        grid_x, grid_y = np.meshgrid(flat_x, flat_y, indexing="ij")
        sag = RegularGridInterpolator((flat_x, flat_y), self.patch.sag(grid_x, grid_y))(xy)
        return np.column_stack([xy, self.patch.thickness - sag])

    def load(self, force, contact, radius: float, probe: str = "disc") -> np.ndarray:
        """Load vector of a probe pressing with ``force`` [N] centred at ``contact`` [mm].

        ``probe``: "disc" spreads it uniformly over the skin within ``radius`` [mm] of
        the contact; "gauss" weights it by exp(-d^2 / (2 (r/2)^2)). Either is
        normalised so that the traction sums to ``force`` exactly.
        """
        if probe not in PROBES:
            raise ValueError(f"probe must be one of {', '.join(PROBES)}")
        skfem, force, contact = self.skfem, np.asarray(force, float), np.asarray(contact, float)

        def weight(x):
            d2 = sum((x[i] - contact[i]) ** 2 for i in range(3))
            if probe == "gauss":
                return np.exp(-d2 / (2 * (0.5 * radius) ** 2))
            return (d2 <= radius**2).astype(float)

        @skfem.LinearForm
        def traction(v, w):
            return weight(w.x) * (v[0] * force[0] + v[1] * force[1] + v[2] * force[2])

        @skfem.Functional
        def area(w):
            return weight(w.x)

        covered = area.assemble(self.top)
        if covered <= 0:
            raise ValueError(f"the probe of radius {radius} mm misses every quadrature point")
        return traction.assemble(self.top) / covered

    def solve(self, load: np.ndarray) -> np.ndarray:
        """Nodal displacements [mm] under a load vector."""
        solution = np.zeros(self.basis.N)
        solution[self.free] = self.factor.solve(load[self.free])
        return solution

    def displacement(self, force, contact, radius: float, probe: str = "disc") -> np.ndarray:
        """Nodal displacements [mm] under one probe (``load``'s arguments)."""
        return self.solve(self.load(force, contact, radius, probe))

    def at(self, solution: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The displacement at physical points (n, 3) [mm] in the patch, shape (n, 3).

        The cell is found on the flat tensor mesh (the sag moves nodes vertically
        only), so points on the skin or the sides need no tolerance.
        """
        points = np.atleast_2d(np.asarray(points, dtype=float))
        flat = points.copy()
        flat[:, 2] += self.patch.thickness - self.skin(points[:, :2])[:, 2]
        index = [
            np.clip(np.searchsorted(axis, flat[:, i], side="right") - 1, 0, len(axis) - 2)
            for i, axis in enumerate(self._axes)
        ]
        cells = self._cells[index[0], index[1], index[2]]
        basis = self.basis
        local = basis.mapping.invF(points.T[:, :, None], tind=cells)
        values = np.array(
            [basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0] for k in range(basis.Nbfun)]
        )[..., 0]
        dofs = solution[basis.element_dofs[:, cells]]
        return np.einsum("kcn,kn->nc", values, dofs)


def tissue_cases(design: str, patch: TissuePatch, forces=(0.17, 0.25)):
    """Forces (K, 3) [N] and contacts (K, 2) [mm] of a named design.

    ``paper`` (2 loads) and ``diagnosis`` (10 loads: 5 contacts x 2 forces) are
    ``fe.design_cases``; ``corners`` (8 loads) is ``diagnosis`` without its centre
    contact. Forces are in the flat patch's frame (z along the skin normal).
    """
    if design == "corners":
        all_forces, contacts = design_cases("diagnosis", patch, forces)
        keep = np.linalg.norm(contacts, axis=1) > 1e-9
        return all_forces[keep], contacts[keep]
    return design_cases(design, patch, forces)


def on_skin(patch: TissuePatch, force: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """A force [N] given in the flat frame at ``xy`` [mm], turned by the smallest
    rotation that takes z to the skin normal there."""
    normal = patch.normal(*xy)
    rotation, _ = Rotation.align_vectors([normal], [[0.0, 0.0, 1.0]])
    return rotation.apply(np.asarray(force, dtype=float))


def tissue_dataset(
    patch: TissuePatch,
    forces: np.ndarray,
    contacts_xy: np.ndarray,
    radius: float = 2.5,
    markers: tuple[int, int] = (11, 8),
    probe: str = "disc",
    declare_radius: bool = False,
    measurement: SimulationSettings | None = None,
    departure: Departure | None = None,
    solver: TissueSolution | None = None,
) -> Dataset:
    """A dataset v1 of the patch: a U x V marker grid over the marked rectangle.

    ``forces`` (K, 3) [N] are in the flat frame and turned to the skin normal at each
    contact (``on_skin``); ``contacts_xy`` (K, 2) [mm] are placed on the curved skin.
    The probe has ``radius`` [mm]; ``declare_radius`` False leaves ``probe_radius``
    out of the dataset (the loop then reads point forces). ``departure`` is what the
    truth does and the dataset does not declare (``fe.Departure``).
    """
    measurement = measurement or SimulationSettings()
    departure = departure or Departure()
    solver = solver or TissueSolution(patch)
    (mx, my), (u_count, v_count) = patch.marked, markers
    x, y = np.meshgrid(
        np.linspace(-mx / 2, mx / 2, u_count), np.linspace(-my / 2, my / 2, v_count), indexing="ij"
    )
    xy = np.column_stack([x.ravel(), y.ravel()])
    rest = solver.skin(xy)
    inner = np.column_stack([xy, -patch.sag(xy[:, 0], xy[:, 1])])
    contacts_xy = np.asarray(contacts_xy, dtype=float)
    declared = np.array([on_skin(patch, f, c) for f, c in zip(forces, contacts_xy)])
    contacts = solver.skin(contacts_xy)
    true_contacts = solver.skin(contacts_xy + np.asarray(departure.contact_offset_mm))
    tangential = np.array([*departure.tangential, 0.0])
    positions = []
    for k, (f, c) in enumerate(zip(np.asarray(forces, float), true_contacts)):
        tilted = on_skin(patch, f + np.linalg.norm(f) * tangential, contacts_xy[k])
        field = solver.displacement(tilted, c, radius * departure.radius_factor, probe)
        positions.append(rest + solver.at(field, rest))
    if departure.rigid_mm:
        positions = rigid_departure(positions, rest, departure.rigid_mm)
    radii = np.full(len(declared), float(radius))
    dataset = measured_dataset(
        rest, inner, positions, declared, contacts, measurement, markers, radii
    )
    return dataset if declare_radius else replace(dataset, probe_radius=None)
