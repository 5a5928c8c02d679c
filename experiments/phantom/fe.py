"""Reference continuum data by scikit-fem: a linear-elastic slab under probe loads.

The generator shares nothing with the spline model but the physics it claims to
represent: quadratic tetrahedra (P2) on a structured mesh, assembled and solved by
scikit-fem (https://scikit-fem.readthedocs.io, an optional dependency: the ``fe``
extra). The slab is larger than the marked area (the tissue goes on beyond the
markers), fixed at its base and on its far lateral faces; each probe is a Gaussian
traction of standard deviation r / 2 on the top face, the probe patch
``symbolic.loads.ProbeForce`` declares. Markers are the top surface's points on a
U x V grid over the marked area, measured as ``experiments.phantom.simulate`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.data.dataset import Dataset
from experiments.phantom.simulate import SimulationSettings, measured_dataset
from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.continuum import lame


def require_skfem():
    """scikit-fem, or a one-line ImportError that says how to install it."""
    try:
        import skfem
    except ImportError as error:  # pragma: no cover - the test extra installs it
        raise ImportError(
            "the reference finite elements need scikit-fem: pip install 'dvs[fe]'"
        ) from error
    return skfem


@dataclass(frozen=True)
class ReferenceSlab:
    """The FE slab (lengths in mm, forces in N, E in kPa).

    Attributes
    ----------
    lengths : tuple of float
        Tissue extent along x and y and its thickness; centred on x = y = 0, base at
        z = 0, skin at z = thickness.
    marked : tuple of float
        Extent of the marked area along x and y (centred).
    elements : tuple of int
        Hexahedral cells along x, y, z, each cut into tetrahedra by scikit-fem.
    young_kpa, poisson : float
        Isotropic material.
    fix_lateral : bool
        Fix the far lateral faces too.
    gradient : float
        A stiffness gradient along x: E(x) = E (1 + gradient 2 x / marked_x), so E
        runs from (1 - gradient) E to (1 + gradient) E across the marked area
        (continued linearly beyond it, and at least 0.05 E).
    base_spring : float or None
        None fixes the base; a number rests it on a Winkler foundation of this
        stiffness [N/mm^3] instead (a compliant base: muscle under the fat).
    inclusion : tuple of float or None
        (x, y, diameter, ratio): a disc through the thickness, centred at (x, y) [mm],
        whose E is ``ratio`` times the rest (a lesion; stiffness imaging). The mesh
        does not follow its edge: E jumps between quadrature points.
    """

    lengths: tuple[float, float, float] = (60.0, 60.0, 5.0)
    marked: tuple[float, float] = (40.0, 40.0)
    elements: tuple[int, int, int] = (18, 18, 3)
    young_kpa: float = 20.0
    poisson: float = 0.45
    fix_lateral: bool = True
    gradient: float = 0.0
    base_spring: float | None = None
    inclusion: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (0.0 <= self.poisson < 0.5) or self.young_kpa <= 0:
            raise ValueError("need E > 0 kPa and 0 <= nu < 0.5")
        if not abs(self.gradient) < 1.0 or (self.base_spring is not None and self.base_spring <= 0):
            raise ValueError("need |gradient| < 1 and a positive base_spring (or None)")
        if self.inclusion is not None and (
            len(self.inclusion) != 4 or self.inclusion[2] <= 0 or self.inclusion[3] <= 0
        ):
            raise ValueError("an inclusion is (x, y, diameter > 0, ratio > 0)")
        if any(m > extent for m, extent in zip(self.marked, self.lengths)):
            raise ValueError("the marked area must lie inside the slab")


class SlabSolution:
    """The slab's P2 displacement under Gaussian probe tractions, evaluated anywhere."""

    def __init__(self, slab: ReferenceSlab):
        skfem = self.skfem = require_skfem()
        from skfem.helpers import ddot, div, dot, sym_grad

        self.slab = slab
        (lx, ly, lz), (nx, ny, nz) = slab.lengths, slab.elements
        mesh = skfem.MeshTet.init_tensor(
            np.linspace(-lx / 2, lx / 2, nx + 1),
            np.linspace(-ly / 2, ly / 2, ny + 1),
            np.linspace(0.0, lz, nz + 1),
        )
        element = skfem.ElementVector(skfem.ElementTetP2())
        self.basis = skfem.Basis(mesh, element)
        mu_l, lam = lame(slab.young_kpa, slab.poisson)

        @skfem.BilinearForm
        def elasticity(u, v, w):
            factor = np.maximum(1.0 + slab.gradient * 2.0 * w.x[0] / slab.marked[0], 0.05)
            if slab.inclusion is not None:
                x0, y0, diameter, ratio = slab.inclusion
                inside = (w.x[0] - x0) ** 2 + (w.x[1] - y0) ** 2 <= (diameter / 2.0) ** 2
                factor = factor * np.where(inside, ratio, 1.0)
            return factor * (2.0 * mu_l * ddot(sym_grad(u), sym_grad(v)) + lam * div(u) * div(v))

        matrix = elasticity.assemble(self.basis)
        if slab.base_spring is not None:

            @skfem.BilinearForm
            def foundation(u, v, w):
                return slab.base_spring * dot(u, v)

            bottom = mesh.facets_satisfying(lambda x: np.isclose(x[2], 0.0))
            matrix = matrix + foundation.assemble(skfem.FacetBasis(mesh, element, facets=bottom))

        def fixed(x):
            base = np.isclose(x[2], 0.0) & (slab.base_spring is None)
            if not slab.fix_lateral:
                return base
            side = np.isclose(np.abs(x[0]), lx / 2) | np.isclose(np.abs(x[1]), ly / 2)
            return base | side

        self.free = self.basis.complement_dofs(self.basis.get_dofs(fixed))
        # symmetric positive definite: CHOLMOD (solvers/linalg/cholmod.py), else SuperLU with
        # diagonal pivots and a symmetric ordering (partial pivoting at nu = 0.49 on
        # 24 x 24 x 4 cells: 31.7 s against 8.6 s, same solution to 3e-14)
        self.factor = factorised(matrix[self.free][:, self.free].tocsc(), symmetric_lu)
        top = mesh.facets_satisfying(lambda x: np.isclose(x[2], lz))
        self.top = skfem.FacetBasis(mesh, element, facets=top, intorder=6)

    def displacement(self, force: np.ndarray, contact: np.ndarray, radius: float) -> np.ndarray:
        """Nodal displacements [mm] under a Gaussian traction of total ``force`` [N]."""
        skfem = self.skfem
        sigma = 0.5 * radius
        force = np.asarray(force, dtype=float)

        @skfem.LinearForm
        def gauss(v, w):
            r2 = (w.x[0] - contact[0]) ** 2 + (w.x[1] - contact[1]) ** 2
            traction = v[0] * force[0] + v[1] * force[1] + v[2] * force[2]
            return np.exp(-r2 / (2 * sigma**2)) * traction

        @skfem.Functional
        def area(w):
            r2 = (w.x[0] - contact[0]) ** 2 + (w.x[1] - contact[1]) ** 2
            return np.exp(-r2 / (2 * sigma**2))

        load = gauss.assemble(self.top) / area.assemble(self.top)
        solution = np.zeros(self.basis.N)
        solution[self.free] = self.factor.solve(load[self.free])
        return solution

    def at(self, solution: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The displacement at physical points (n, 3) [mm], shape (n, 3)."""
        values = self.basis.probes(np.asarray(points, dtype=float).T) @ solution
        return values.reshape(3, -1).T


@dataclass(frozen=True)
class Departure:
    """What the truth does and the dataset does not declare (the loop's injected effects).

    Attributes
    ----------
    contact_offset_mm : tuple of float
        The probe presses this far (x, y) [mm] from the declared contact.
    radius_factor : float
        The true probe patch is this many times the declared radius.
    tangential : tuple of float
        Tangential force per unit force (x, y) [1] added to every declared force: a
        tilted probe.
    rigid_mm : float
        Rigid motion of every loaded capture, ``RigidMotion.true_parameters`` of this
        magnitude [mm]: the subject moved between captures.
    """

    contact_offset_mm: tuple[float, float] = (0.0, 0.0)
    radius_factor: float = 1.0
    tangential: tuple[float, float] = (0.0, 0.0)
    rigid_mm: float = 0.0


def design_cases(design: str, slab: ReferenceSlab, forces=(0.17, 0.25)):
    """Forces (K, 3) [N] and contacts (K, 2) [mm] of a named design on the flat slab.

    ``paper``: every force at the centre along -z. ``diagnosis``: the phantom's five
    contacts (``DIAGNOSIS_CONTACTS`` as fractions of the marked area), the first force
    along -z and the others tilted by ``DIAGNOSIS_TILT_DEG`` away from the centre (along
    x at the centre), as ``experiments.phantom.designs.design_loads``.
    """
    from experiments.phantom.designs import DESIGNS, DIAGNOSIS_CONTACTS, DIAGNOSIS_TILT_DEG

    if design not in DESIGNS:
        raise ValueError(f"unknown design {design!r}; choose from {', '.join(DESIGNS)}")
    contacts = ((0.5, 0.5),) if design == "paper" else DIAGNOSIS_CONTACTS
    angle = 0.0 if design == "paper" else np.radians(DIAGNOSIS_TILT_DEG)
    all_forces, all_xy = [], []
    for u, v in contacts:
        xy = np.array([(u - 0.5) * slab.marked[0], (v - 0.5) * slab.marked[1]])
        away = xy / np.linalg.norm(xy) if np.linalg.norm(xy) > 1e-9 else np.array([1.0, 0.0])
        for k, size in enumerate(forces):
            tilt = 0.0 if k == 0 else angle
            all_forces.append(size * np.array([*(np.sin(tilt) * away), -np.cos(tilt)]))
            all_xy.append(xy)
    return np.array(all_forces), np.array(all_xy)


def rigid_departure(positions: list, rest: np.ndarray, magnitude: float) -> list:
    """Every capture moved rigidly about the rest centroid (``RigidMotion`` pattern)."""
    from scipy.spatial.transform import Rotation

    from symbolic.effects.measurement import RigidMotion

    blocks = RigidMotion().true_parameters(magnitude, len(positions)).reshape(-1, 6)
    centre = rest.mean(axis=0)
    moved = []
    for points, block in zip(positions, blocks):
        rotation = Rotation.from_rotvec(block[:3]).as_matrix()
        moved.append(centre + (points - centre) @ rotation.T + block[3:])
    return moved


def reference_dataset(
    slab: ReferenceSlab,
    forces: np.ndarray,
    contacts_xy: np.ndarray,
    radius: float = 2.0,
    markers: tuple[int, int] = (9, 9),
    measurement: SimulationSettings | None = None,
    departure: Departure | None = None,
    solver: SlabSolution | None = None,
) -> Dataset:
    """A dataset v1 of the slab: markers over the marked area, probes of ``radius`` [mm].

    ``forces`` (K, 3) [N] and ``contacts_xy`` (K, 2) [mm] give the declared load cases;
    ``departure`` what the truth does differently; ``solver`` a ``SlabSolution`` of
    ``slab`` to reuse.
    """
    measurement = measurement or SimulationSettings()
    departure = departure or Departure()
    solver = solver or SlabSolution(slab)
    (mx, my), (u_count, v_count), thickness = slab.marked, markers, slab.lengths[2]
    x, y = np.meshgrid(
        np.linspace(-mx / 2, mx / 2, u_count), np.linspace(-my / 2, my / 2, v_count), indexing="ij"
    )
    rest = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, thickness)])
    inner = rest * np.array([1.0, 1.0, 0.0])
    forces = np.asarray(forces, dtype=float)
    contacts = np.column_stack([np.asarray(contacts_xy, float), np.full(len(forces), thickness)])
    shift = np.array([*departure.contact_offset_mm, 0.0])
    tangential = np.array([*departure.tangential, 0.0])
    positions = []
    for f, c in zip(forces, contacts):
        true_force = f + np.linalg.norm(f) * tangential
        field = solver.displacement(true_force, c + shift, radius * departure.radius_factor)
        positions.append(rest + solver.at(field, rest))
    if departure.rigid_mm:
        positions = rigid_departure(positions, rest, departure.rigid_mm)
    return measured_dataset(
        rest,
        inner,
        positions,
        forces,
        contacts,
        measurement,
        markers,
        np.full(len(forces), float(radius)),
    )
