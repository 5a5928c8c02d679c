"""Measurement effects: maps of the predicted markers before comparison (docs/inverse.md, eq. 24).

Both are properties of each loaded capture (one block of theta per load case),
applied about the centroid c of the case's observed rest markers:

- ``rigid_motion``: y = c + R(omega) (p - c) + t, a small rotation vector omega
  [rad] (Cayley form R = (I - W/2)^-1 (I + W/2), W = [omega]_x, exactly
  orthogonal and smooth at 0) and a translation t [mm]: the head moved, or the
  loaded reconstruction was registered imperfectly to the rest one.
- ``measurement_scale``: y = c + (1 + s)(p - c), a scale error s of the loaded
  reconstruction relative to the rest one. (A common scale of *all* captures
  cannot be seen: the energy of eq. (18) lives in parameter space, so it is
  absorbed by alpha.)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from symbolic.effects.base import CaseData, Effect
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.model import TissueModel


def skew(vector) -> ca.MX:
    """[v]_x, the cross-product matrix of a 3-vector expression."""
    return ca.vertcat(
        ca.horzcat(0, -vector[2], vector[1]),
        ca.horzcat(vector[2], 0, -vector[0]),
        ca.horzcat(-vector[1], vector[0], 0),
    )


def cayley_rotation(omega) -> ca.MX:
    """R = (I - W/2)^-1 (I + W/2) with W = [omega]_x; R = I + W + O(|omega|^2)."""
    half = 0.5 * skew(omega)
    identity = ca.DM.eye(3)
    return ca.solve(identity - half, identity + half)


class RigidMotion(Effect):
    """Per capture: rotation vector omega [rad] and translation t [mm] of the loaded markers.

    Realistic magnitude 0.1 mm: translations of 0.1 mm and rotations of
    0.1 / 20 rad (0.1 mm at the patch edge), different in each capture (a
    subject who moves between captures, or an imperfect registration).
    """

    name = "rigid_motion"
    parameters = (
        Parameter("omega_x", "rad", 0.001, -0.5, 0.5),
        Parameter("omega_y", "rad", 0.001, -0.5, 0.5),
        Parameter("omega_z", "rad", 0.001, -0.5, 0.5),
        Parameter("t_x", "mm", 0.01, -10.0, 10.0),
        Parameter("t_y", "mm", 0.01, -10.0, 10.0),
        Parameter("t_z", "mm", 0.01, -10.0, 10.0),
    )
    per_case = True
    magnitude = Magnitude(0.1, "mm")
    equation = "y = c + R(omega)(p - c) + t per capture"

    def direction(self):
        axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
        shift = np.array([0.6, 0.5, -0.62]) / np.linalg.norm([0.6, 0.5, -0.62])
        return tuple(axis / 20.0) + tuple(shift)

    def true_parameters(self, magnitude: float, n_cases: int) -> np.ndarray:
        base = np.asarray(self.direction())
        blocks = []
        for k in range(n_cases):
            turn = np.roll(base[:3], k) * (-1.0) ** k
            move = np.roll(base[3:], 2 * k) * (1.0 - 0.3 * k)
            blocks.append(magnitude * np.concatenate([turn, move]))
        return np.concatenate(blocks)

    def observe(self, model: TissueModel, case: CaseData, predicted: ca.MX, theta):
        center = ca.DM(case.centroid[None, :])
        n = predicted.shape[0]
        rotation = cayley_rotation(theta[:3])
        relative = predicted - ca.repmat(center, n, 1)
        moved = ca.mtimes(relative, rotation.T) + ca.repmat(center + theta[3:6].T, n, 1)
        return moved


class MeasurementScale(Effect):
    """Per capture: scale error s [1] of the loaded reconstruction about the centroid.

    Realistic magnitude 8e-3 (0.8 %: refocusing a macro lens changes its
    magnification by about that much; the second capture gets -0.6 times it).
    """

    name = "measurement_scale"
    parameters = (Parameter("scale", "1", 0.001, -0.2, 0.2, plausible=(-0.05, 0.05)),)
    per_case = True
    magnitude = Magnitude(0.008, "1")
    equation = "y = c + (1 + s)(p - c) per capture"

    def case_factor(self, k: int) -> float:
        return (1.0, -0.6, 0.8, -0.4)[k % 4]

    def observe(self, model: TissueModel, case: CaseData, predicted: ca.MX, theta):
        center = ca.repmat(ca.DM(case.centroid[None, :]), predicted.shape[0], 1)
        return center + (1 + theta[0]) * (predicted - center)
