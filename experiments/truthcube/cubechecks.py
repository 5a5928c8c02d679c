"""Checks of the cube's discretisation: the spline against scikit-fem, and nu by grid.

**Locking.** A displacement-based discretisation of a nearly incompressible solid
(nu -> 0.5) can lock: the volumetric term lambda (div u)^2 over-stiffens the element
space and the displacements come out wrong. ``fem_comparison`` solves the same cube
(bonded base and plate, the plate moved by the 18.25 % state's nominal travel along
-z) with the linear spline model at a few grids and degrees and with scikit-fem's
quadratic tetrahedra (P2, https://scikit-fem.readthedocs.io, ``experiments.phantom.fe``)
at two meshes, for nu 0.45, 0.49 and 0.499, and reports the beads' displacement
difference. ``grid_study`` fits nu (linear energy) on each grid: a locked grid needs a
smaller nu to match the same beads.
"""

from __future__ import annotations

import time

import numpy as np

from experiments.phantom.fe import require_skfem
from experiments.truthcube.cubefit import CubeSolver, fit_cube, rms
from experiments.truthcube.cubemodel import CubeData, CubeSettings, cube_model
from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.continuum import lame

CHECK_NUS = (0.45, 0.49, 0.499)
"""Poisson's ratios of the comparison [1]."""
CHECK_GRIDS = (((6, 6, 6), 2), ((6, 6, 6), 3), ((7, 7, 7), 3), ((9, 9, 9), 3))
"""(control points, degree) of the spline models compared."""
FEM_CELLS = (6, 10)
"""Hexahedral cells per edge of the scikit-fem meshes (each cut into tetrahedra)."""


FEM_CONTACTS = ("bonded", "frictionless")
"""The plate contacts of ``FemCube``: every displacement component of the top face
prescribed (bonded), or its vertical one alone (frictionless: the face slides freely)."""


class FemCube:
    """The cube by scikit-fem P2 tetrahedra: linear elasticity, bonded base, and a plate
    bonded to the top face or sliding on it without friction.

    Parameters
    ----------
    cells : int
        Hexahedral cells per edge.
    nu : float
        Poisson's ratio [1] (E is irrelevant for the displacements; 1 kPa).
    edge : float
        The cube's edge [mm]; model frame: base z = 0, plate z = edge.
    contact : {"bonded", "frictionless"}
        The plate's contact (``FEM_CONTACTS``): with "frictionless" only the vertical
        displacement of the top face is prescribed, its lateral traction is zero.
    """

    def __init__(self, cells: int, nu: float, edge: float = 80.0, contact: str = "bonded"):
        if contact not in FEM_CONTACTS:
            raise ValueError(f"contact must be one of {FEM_CONTACTS}, got {contact!r}")
        skfem = require_skfem()
        from skfem.helpers import ddot, div, sym_grad

        half = 0.5 * edge
        mesh = skfem.MeshTet.init_tensor(
            np.linspace(-half, half, cells + 1),
            np.linspace(-half, half, cells + 1),
            np.linspace(0.0, edge, cells + 1),
        )
        self.basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
        mu_l, lam = lame(1.0, nu)

        @skfem.BilinearForm
        def elasticity(u, v, w):
            return 2.0 * mu_l * ddot(sym_grad(u), sym_grad(v)) + lam * div(u) * div(v)

        self.matrix = elasticity.assemble(self.basis).tocsr()
        base = self.basis.get_dofs(lambda x: np.isclose(x[2], 0.0)).all()
        top = self.basis.get_dofs(lambda x: np.isclose(x[2], edge))
        self.components = (0, 1, 2) if contact == "bonded" else (2,)
        """The plate's prescribed displacement components."""
        self.plate = {c: top.all(f"u^{c + 1}") for c in self.components}
        self.boundary = np.unique(np.concatenate([base, *self.plate.values()]))
        self.free = np.setdiff1d(np.arange(self.basis.N), self.boundary)
        block = self.matrix[self.free][:, self.free].tocsc()
        self.factor = factorised(block, symmetric_lu)

    def displacement(self, translation) -> np.ndarray:
        """Nodal displacements [mm] with the plate moved by ``translation`` (3,) [mm]
        (a frictionless plate: its vertical component alone)."""
        solution = np.zeros(self.basis.N)
        for c, dofs in self.plate.items():
            solution[dofs] = translation[c]  # vertex and edge dofs
        rhs = -(self.matrix @ solution)[self.free]
        solution[self.free] = self.factor.solve(rhs)
        return solution

    def at(self, solution: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The displacement at model-frame points (n, 3) [mm]."""
        return (self.basis.probes(np.asarray(points, dtype=float).T) @ solution).reshape(3, -1).T


def spline_displacement(settings: CubeSettings, nu: float, data: CubeData, translation):
    """The linear spline model's bead displacements (N, 3) [mm]."""
    solver = CubeSolver(cube_model(settings, "linear", nu), data)
    solution = solver.equilibrium(nu, np.asarray(translation, dtype=float))
    return solver.positions(solution) - solver.rest_points


def fem_comparison(data: CubeData, log=print) -> list[dict]:
    """Bead displacements of the spline grids against scikit-fem's finest mesh, for each
    nu of ``CHECK_NUS``: RMS and largest distance [mm], and the displacement's RMS."""
    translation = np.array([0.0, 0.0, -float(data.nominal_travel[-1])])
    rows = []
    for nu in CHECK_NUS:
        fem = {}
        for cells in FEM_CELLS:
            begin = time.perf_counter()
            cube = FemCube(cells, nu)
            fem[cells] = cube.at(cube.displacement(translation), data.rest)
            log(f"  scikit-fem {cells}^3 P2 at nu {nu}: {time.perf_counter() - begin:.1f} s")
        reference = fem[FEM_CELLS[-1]]
        size = rms(reference)
        entries = [(f"scikit-fem P2 {c}^3 cells", fem[c]) for c in FEM_CELLS[:-1]]
        for shape, degree in CHECK_GRIDS:
            settings = CubeSettings(shape, degree, max(12, shape[0] + 2))
            label = f"spline {'x'.join(map(str, shape))}, degree {degree}"
            entries.append((label, spline_displacement(settings, nu, data, translation)))
        for label, values in entries:
            difference = values - reference
            rows.append(
                {
                    "nu": nu,
                    "model": label,
                    "rms_difference_mm": rms(difference),
                    "max_difference_mm": float(np.max(np.linalg.norm(difference, axis=1))),
                    "displacement_rms_mm": size,
                }
            )
            log(f"  nu {nu}: {label}: RMS difference {rms(difference):.4f} mm")
    return rows


def grid_study(data: CubeData, grids=CHECK_GRIDS, log=print) -> list[dict]:
    """nu (linear energy) fitted on every grid: nu, its standard error, RMS per state,
    seconds."""
    rows = []
    for shape, degree in grids:
        begin = time.perf_counter()
        settings = CubeSettings(shape, degree, max(12, shape[0] + 2))
        fitted = fit_cube(CubeSolver(cube_model(settings, "linear"), data), nu0=0.49)
        rows.append(
            {
                "grid": f"{'x'.join(map(str, shape))}, degree {degree}",
                "nu": fitted.nu,
                "nu_se": fitted.nu_se,
                "rms_mm": fitted.rms_mm,
                "seconds": time.perf_counter() - begin,
            }
        )
        log(f"  {rows[-1]['grid']}: nu {fitted.nu:.4f} +- {fitted.nu_se:.4f}")
    return rows
