"""Checks every planar energy of the extensometer must pass, on the healthy case's mesh.

``healthy_mesh`` is the coarse mesh of the healthy case's geometry.geo, written out here
so that the energy tests need no data; ``check_tangent_and_residual`` compares an energy's
derivatives with central differences (imported by the tests).
"""

from __future__ import annotations

import numpy as np

from experiments.realskin import mesh2d
from experiments.realskin.geometry import Rect, SkinGeometry

HEALTHY = SkinGeometry(
    region=Rect(0.0, -5.0, 100.0, 45.0),
    pad_moving=Rect(26.0, 16.0, 34.0, 24.0),
    pad_fixed=Rect(66.0, 16.0, 74.0, 24.0),
    keloid=None,
    variables={},
)
"""The healthy case's geometry.geo, written out."""


def healthy_mesh() -> mesh2d.Mesh2D:
    """The healthy geometry meshed coarsely: 2 mm around the pads and in the gap, 6 mm
    elsewhere."""
    return mesh2d.build_mesh(HEALTHY, 2.0, 6.0)


def check_tangent_and_residual(model, u, v, tangent_rtol: float, symmetry_rtol: float) -> None:
    """K v against (R(u + h v) - R(u - h v)) / 2h, K symmetric, and R . v against the
    energy's central difference (h = 1e-6), to 1e-7 relative.

    Parameters
    ----------
    model : PlanarNeoHookean or PlanarStiffening
        A planar energy with ``energy``, ``residual`` and ``stiffness`` of the nodal
        displacements.
    u, v : numpy.ndarray
        (2 N,) the displacement [mm] and the direction of the differences.
    tangent_rtol : float
        Bound on the error of K v relative to its norm.
    symmetry_rtol : float
        Bound on the largest entry of K - K^T relative to K's largest.
    """
    h = 1e-6
    tangent = model.stiffness(u)
    numeric = (model.residual(u + h * v) - model.residual(u - h * v)) / (2 * h)
    error, size = np.linalg.norm(numeric - tangent @ v), np.linalg.norm(tangent @ v)
    assert error < tangent_rtol * size, f"K v off by {error:.3g} of {size:.3g}"
    asymmetry, largest = abs(tangent - tangent.T).max(), abs(tangent).max()
    assert asymmetry < symmetry_rtol * largest, f"K - K^T up to {asymmetry:.3g} of {largest:.3g}"
    slope = (model.energy(u + h * v) - model.energy(u - h * v)) / (2 * h)
    work = model.residual(u) @ v
    assert abs(slope - work) < 1e-7 * abs(slope), f"R . v = {work!r}, energy's slope {slope!r}"
