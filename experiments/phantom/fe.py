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
import scipy.sparse.linalg as spla

from experiments.dataset import Dataset
from experiments.phantom.simulate import SimulationSettings, measured_dataset
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
        Fix the far lateral faces too (the base is always fixed).
    """

    lengths: tuple[float, float, float] = (60.0, 60.0, 5.0)
    marked: tuple[float, float] = (40.0, 40.0)
    elements: tuple[int, int, int] = (18, 18, 3)
    young_kpa: float = 20.0
    poisson: float = 0.45
    fix_lateral: bool = True

    def __post_init__(self) -> None:
        if not (0.0 <= self.poisson < 0.5) or self.young_kpa <= 0:
            raise ValueError("need E > 0 kPa and 0 <= nu < 0.5")
        if any(m > extent for m, extent in zip(self.marked, self.lengths)):
            raise ValueError("the marked area must lie inside the slab")


class SlabSolution:
    """The slab's P2 displacement under Gaussian probe tractions, evaluated anywhere."""

    def __init__(self, slab: ReferenceSlab):
        skfem = self.skfem = require_skfem()
        from skfem.models.elasticity import linear_elasticity

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
        matrix = linear_elasticity(lam, mu_l).assemble(self.basis)

        def fixed(x):
            base = np.isclose(x[2], 0.0)
            if not slab.fix_lateral:
                return base
            side = np.isclose(np.abs(x[0]), lx / 2) | np.isclose(np.abs(x[1]), ly / 2)
            return base | side

        self.free = self.basis.complement_dofs(self.basis.get_dofs(fixed))
        self.factor = spla.splu(matrix[self.free][:, self.free].tocsc(), permc_spec="MMD_AT_PLUS_A")
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


def reference_dataset(
    slab: ReferenceSlab,
    forces: np.ndarray,
    contacts_xy: np.ndarray,
    radius: float = 2.0,
    markers: tuple[int, int] = (9, 9),
    measurement: SimulationSettings | None = None,
) -> Dataset:
    """A dataset v1 of the slab: markers over the marked area, probes of ``radius`` [mm].

    ``forces`` (K, 3) [N] and ``contacts_xy`` (K, 2) [mm] give the load cases.
    """
    measurement = measurement or SimulationSettings()
    solver = SlabSolution(slab)
    (mx, my), (u_count, v_count), thickness = slab.marked, markers, slab.lengths[2]
    x, y = np.meshgrid(
        np.linspace(-mx / 2, mx / 2, u_count), np.linspace(-my / 2, my / 2, v_count), indexing="ij"
    )
    rest = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, thickness)])
    inner = rest * np.array([1.0, 1.0, 0.0])
    contacts = np.column_stack([np.asarray(contacts_xy, float), np.full(len(forces), thickness)])
    positions = [
        rest + solver.at(solver.displacement(f, c, radius), rest) for f, c in zip(forces, contacts)
    ]
    return measured_dataset(
        rest,
        inner,
        positions,
        np.asarray(forces, dtype=float),
        contacts,
        measurement,
        markers,
        np.full(len(forces), float(radius)),
    )
