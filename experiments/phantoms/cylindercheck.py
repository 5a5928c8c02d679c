"""The bonded cylinder's small-strain stiffness: the volume spline against scikit-fem.

A cylinder bonded to two rigid plates and compressed by delta is stiffer than under
uniform stress: its apparent modulus F H / (A delta) exceeds E by a factor that grows
as nu approaches 1/2 (the ends cannot expand, the incompressible core pushes the sides
out: barrelling). That factor is what separates the bonded and sliding E of
docs/experiments.md; near nu = 1/2 it is also where low-order elements lock (they
report too stiff a cylinder).

Both sides solve the same linear problem (docs/continuum.md, eq. C3): the spline
``ContinuumModel`` of ``cylinder.cylinder_volume`` and scikit-fem's quadratic
tetrahedra (P2) on the same mapped disc, with the base fixed and the top moved down by
delta, all components prescribed.
"""

from __future__ import annotations

import numpy as np

from experiments.phantom.fe import require_skfem
from experiments.phantoms.cylinder import cylinder_model, disc_map, plate_forces
from symbolic.continuum import lame
from symbolic.continuum_model import ContinuumModel

RADIUS, HEIGHT, TRAVEL = 25.0, 30.0, 0.3
"""The phantom's cylinder [mm] and the check's travel (1 % of the height) [mm]."""


def spline_ratio(nu: float, shape=(9, 9, 6), degree: int = 2) -> float:
    """F H / (E A delta) of the bonded spline cylinder (linear elasticity, E = 1 kPa)."""
    model = cylinder_model(RADIUS, HEIGHT, 1.0, shape, degree, ContinuumModel, nu)
    return float(plate_forces(model, np.array([TRAVEL]))[0] / _uniform(1.0))


def reference_ratio(nu: float, cells: int = 8) -> float:
    """The same ratio by scikit-fem: P2 tetrahedra on a cells x cells x cells box mapped
    onto the cylinder (``disc_map``), the base fixed, the top moved down by TRAVEL."""
    skfem = require_skfem()
    from skfem.models.elasticity import linear_elasticity

    mesh = skfem.MeshTet.init_tensor(
        np.linspace(-1, 1, cells + 1),
        np.linspace(-1, 1, cells + 1),
        np.linspace(0, HEIGHT, cells + 1),
    )
    x, y = disc_map(mesh.p[0], mesh.p[1])
    mesh = skfem.MeshTet(np.vstack([RADIUS * x, RADIUS * y, mesh.p[2]]), mesh.t)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
    mu, lam = lame(1.0, nu)
    stiffness = linear_elasticity(lam, mu).assemble(basis)
    bottom = basis.get_dofs(lambda p: np.isclose(p[2], 0.0))
    top = basis.get_dofs(lambda p: np.isclose(p[2], HEIGHT))
    displacement = np.zeros(basis.N)
    displacement[top.all("u^3")] = -TRAVEL  # every z dof of the top: vertices and edges
    fixed = np.concatenate([bottom.all(), top.all()])
    solution = skfem.solve(*skfem.condense(stiffness, x=displacement, D=fixed))
    reaction = stiffness @ solution
    force = -float(reaction[top.all("u^3")].sum())
    return force / _uniform(1.0)


def _uniform(young_kpa: float) -> float:
    """E A delta / H [N]: the force of a cylinder under uniform uniaxial stress, small
    strain (kPa = 1e-3 N/mm^2)."""
    return 1e-3 * young_kpa * np.pi * RADIUS**2 * TRAVEL / HEIGHT
