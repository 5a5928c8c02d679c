"""A silicone phantom's compression test as a model: a cylinder between two plates.

The specimen (docs/experiments.md, "Silicone phantoms") is a cylinder, 50 mm across and
30 mm high, pressed by a flat plate onto a flat base. Two models of the same energy
(the compressible neo-Hookean of docs/continuum.md, eq. C6):

- **Bonded plates, 3D** (``cylinder_model``): a volume spline of the cylinder, the base
  w = 0 fixed, the top w = 1 moved by the plate as a whole (``PrescribedDisplacement``
  on a grid of its points, all three components). The ends cannot slide, so the
  cylinder barrels; the plate's force is the sum of the multipliers' z
  (``TissueModel.point_force_rows``).
- **Sliding plates, uniform stress** (``uniform_force``): frictionless plates leave the
  deformation homogeneous, F = diag(a, a, lambda) with the lateral stretch a such that
  P_11 = 0; the force is P_33 times the undeformed area. This is the assumption of the
  published fits.

The true contact lies between the two; both bound the effect of friction on E.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import brentq

from solvers.diagnosis.extended import ExtendedProblem
from solvers.inverse.problem import InverseProblem, LoadCase
from solvers.inverse.space import ParameterSpace
from symbolic.constraints import BoundaryConditions
from symbolic.continuum import box_volume, lame
from symbolic.continuum_model import NeoHookeanModel
from symbolic.loads import FrameLoad, PrescribedDisplacement
from symbolic.parameters import PARAMETERS
from symbolic.volume import VolumeSpline

POISSON = 0.49
"""nu [1] of the silicone, fixed: the force alone cannot separate it from E (**choice**;
Ecoflex is nearly incompressible, and the 3D model locks further towards 0.5)."""


def disc_map(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The square [-1, 1]^2 onto the unit disc: (a sqrt(1 - b^2/2), b sqrt(1 - a^2/2))."""
    return a * np.sqrt(1.0 - b**2 / 2.0), b * np.sqrt(1.0 - a**2 / 2.0)


def cylinder_volume(
    radius: float, height: float, shape=(7, 7, 5), degrees=(2, 2, 2)
) -> VolumeSpline:
    """The cylinder r <= ``radius``, 0 <= z <= ``height`` [mm] as a volume spline: a box's
    control net over [-1, 1]^2 x [0, height] with x, y mapped onto the disc
    (``disc_map``). w = 0 is the base, w = 1 the face under the plate."""
    box = box_volume((2.0, 2.0, height), shape, degrees, (-1.0, -1.0, 0.0))
    points = box.control_points.copy()
    x, y = disc_map(points[:, 0], points[:, 1])
    points[:, 0], points[:, 1] = radius * x, radius * y
    return VolumeSpline(box.basis, points)


def plate_uv(points: int) -> np.ndarray:
    """A points x points grid of (u, v) on the top face, corners included, (m, 2)."""
    side = np.linspace(0.0, 1.0, points)
    uu, vv = np.meshgrid(side, side, indexing="ij")
    return np.column_stack([uu.ravel(), vv.ravel()])


def cylinder_model(
    radius: float,
    height: float,
    young_kpa: float,
    shape=(7, 7, 5),
    degree: int = 2,
    energy=NeoHookeanModel,
    nu: float = POISSON,
):
    """The bonded 3D model (module docstring), E = ``young_kpa``; ``energy`` is the model
    class (``NeoHookeanModel``, or ``ContinuumModel`` for linear elasticity)."""
    volume = cylinder_volume(radius, height, shape, (degree,) * 3)
    return energy(
        volume,
        {"E": young_kpa, "nu": nu},
        BoundaryConditions(fix_inner=True),
        prescribed=PrescribedDisplacement(plate_uv(max(shape[:2]) + 2)),
    )


def load_cases(model: NeoHookeanModel, travel_mm: np.ndarray, force_n: np.ndarray, labels):
    """One ``LoadCase`` per curve point: the top face moved down by the travel, the
    plate's z force on the tissue observed (weight 1 mm/N: the residual is in N).

    Parameters
    ----------
    travel_mm : numpy.ndarray
        (K,) the plate's downward travel [mm] (> 0).
    force_n : numpy.ndarray
        (K,) the measured force on the tissue along z [N] (< 0: it pushes down).
    """
    count = model.prescribed.uv.shape[0]
    rows = sp.csr_matrix(model.point_force_rows()[2:3])
    empty = sp.csr_matrix((0, model.n_free))
    cases = []
    for travel, force, label in zip(travel_mm, force_n, labels):
        cases.append(
            LoadCase(
                force=np.zeros((model.n_free, 3)),
                rows=empty,
                offset=np.zeros((0, 3)),
                weights=np.zeros(0),
                prescribed=np.tile([0.0, 0.0, -float(travel)], (count, 1)),
                rest_points=np.zeros((0, 3)),
                label=label,
                marker_index=np.zeros(0, dtype=int),
                force_rows=rows,
                force_target=np.array([float(force)]),
                force_weight=1.0,
            )
        )
    return cases


def plate_forces(model, travel_mm: np.ndarray) -> np.ndarray:
    """The bonded model's compressive force [N] (> 0) at each travel, at the model's own
    E: every case solved by the shared solver (``solvers.diagnosis.extended``), in order
    of travel, each Newton solve started from the last state scaled to the new travel
    (from rest, Newton fails at the larger travels and the solver falls back to load
    steps: the same forces to 1e-9, 5.7x slower on the 9 x 9 x 7 cubic cylinder to 30 %)."""
    travel_mm = np.asarray(travel_mm, dtype=float)
    labels = [f"{t:.3f} mm" for t in travel_mm]
    cases = load_cases(model, travel_mm, -np.ones(len(labels)), labels)
    young = float(model.parameters["E"])
    space = ParameterSpace.create(("E",), {"E": young}, {"E": (1e-3, 1e4)})
    problem = InverseProblem(model, cases, space, noise_mm=1.0)
    extended = ExtendedProblem(problem, [FrameLoad(label) for label in labels], [])
    p = np.array([young])
    residual, state, last = np.zeros(len(labels)), None, None
    for position in np.argsort(travel_mm):
        start = None if state is None else state * (travel_mm[position] / travel_mm[last])
        state, _ = extended.solve_state(int(position), p, start)
        value = extended.numeric(int(position), "residual")(state, p)
        value = value.toarray() if sp.issparse(value) else np.asarray(value)
        residual[position] = float(np.ravel(value)[0])  # F_model - F_target, F_target = -1
        last = position
    return -(residual - 1.0)


def uniform_force(
    travel_mm: np.ndarray,
    height: float,
    radius: float,
    young_kpa: float,
    nu: float = POISSON,
    stiffening: float = 0.0,
    yeoh: float = 0.0,
) -> np.ndarray:
    """The compressive force [N] (> 0) of a homogeneous uniaxial compression (sliding
    plates) of the eq. (C6) neo-Hookean cylinder, per travel; with ``stiffening`` > 0
    the eq. (C10) term is added, k1 = stiffening x E, at the default k2; with ``yeoh``
    (either sign) Yeoh's second-order term c2 (Ibar1 - 3)^2, c2 = yeoh x E.

    With F = diag(a, a, lambda), lambda = 1 - travel / height and J = a^2 lambda, the
    first Piola stress of eq. (C7) is P_ii = mu F_ii + (Lambda ln J - mu) / F_ii, and
    eq. (C10)'s term and Yeoh's add (k1 s exp(k2 s^2) + 2 c2 s) (2 J^(-2/3) F_ii -
    2 Ibar1 / (3 F_ii)) with s = Ibar1 - 3; a solves P_11 = 0 and the force is
    -P_33 pi radius^2. With k1 and c2 proportional to E the force stays E times the
    force at E = 1.
    """
    mu, lam = lame(young_kpa, nu)
    k1 = stiffening * 2.0 * (1.0 + nu) * mu  # stiffening x E [N/mm^2]
    c2 = yeoh * 2.0 * (1.0 + nu) * mu
    k2 = PARAMETERS["k2"].default

    def piola(f_ii, a, stretch):
        jacobian = a * a * stretch
        invariant = jacobian ** (-2.0 / 3.0) * (2.0 * a * a + stretch * stretch)
        s = invariant - 3.0
        extra = k1 * s * np.exp(k2 * s * s) + 2.0 * c2 * s
        extra *= 2.0 * jacobian ** (-2.0 / 3.0) * f_ii - 2.0 * invariant / (3.0 * f_ii)
        return mu * f_ii + (lam * np.log(jacobian) - mu) / f_ii + extra

    forces = []
    for travel in np.atleast_1d(travel_mm):
        stretch = 1.0 - float(travel) / height
        a = brentq(lambda x, s=stretch: piola(x, x, s), 0.5, 4.0)
        forces.append(-piola(stretch, a, stretch) * np.pi * radius**2)
    return np.array(forces)
