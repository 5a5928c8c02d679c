"""The default forehead phantom: geometry, markers, probe loads and true parameters.

- Outer surface: a 40 x 40 mm patch of a sphere of radius 80 mm (the skin).
- Inner surface: the same patch offset 5 mm inwards (soft-tissue thickness).
- Segmentation: 15 x 15 x 2 points, fitted by a 9 x 9 x 2 volume of degrees (3, 3, 1).
- Markers: a 9 x 9 grid of material points spanning the outer surface. **choice**:
  the grid spans the whole modelled patch, because the inverse rebuilds the
  geometry from the markers; a grid 5 % short of the patch biases alpha_u by 20 %.
- Loads: a probe at the centre pressing along the inward normal with 0.17 N and 0.25 N.
- True parameters close to the paper's data set 2: alpha = (2.6, 0.18, 1.7) N/mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.constraints import BoundaryConditions
from symbolic.loads import PointForce, ProbeForce
from symbolic.model import TissueModel
from symbolic.volume import FitReport, VolumeSpline

TRUE_PARAMETERS = {"alpha_u": 2.6, "alpha_v": 0.18, "alpha_w": 1.7, "mu": 5e-4, "gamma": 15.0}
"""Synthetic truth [N/mm, t, N s/mm]: the paper's data set 2 and literature mu."""


@dataclass(frozen=True)
class PhantomSettings:
    """Geometry and experiment of the forehead phantom (lengths in mm, forces in N)."""

    width: float = 40.0
    curvature_radius: float = 80.0
    thickness: float = 5.0
    segmentation: tuple[int, int] = (15, 15)
    grid: tuple[int, int, int] = (9, 9, 2)
    degrees: tuple[int, int, int] = (3, 3, 1)
    markers: tuple[int, int] = (9, 9)
    marker_margin: float = 0.0
    forces: tuple[float, ...] = (0.17, 0.25)
    probe_radius: float = 0.0
    fix_lateral: bool = False

    def __post_init__(self) -> None:
        if not (0 < self.thickness < self.curvature_radius):
            raise ValueError("thickness must be positive and below the curvature radius")
        if self.width <= 0 or self.width >= 2 * self.curvature_radius:
            raise ValueError("width must be positive and below the sphere's diameter")
        if min(self.segmentation) < 2 or min(self.markers) < 1:
            raise ValueError("segmentation needs >= 2 points and markers >= 1 per direction")
        if not 0 <= self.marker_margin < 0.5:
            raise ValueError("marker_margin must lie in [0, 0.5)")


def segmented_surfaces(settings: PhantomSettings | None = None) -> np.ndarray:
    """The segmented inner and outer surfaces, shape (U, V, 2, 3) [mm].

    Layer 0 is the inner surface, layer 1 the skin. The sphere's top is the
    origin and z points out of the skin.
    """
    s = settings or PhantomSettings()
    half = 0.5 * s.width
    x, y = np.meshgrid(
        np.linspace(-half, half, s.segmentation[0]),
        np.linspace(-half, half, s.segmentation[1]),
        indexing="ij",
    )
    radius = s.curvature_radius
    center = np.array([0.0, 0.0, -radius])
    outer = np.stack([x, y, np.sqrt(radius**2 - x**2 - y**2) - radius], axis=-1)
    inner = center + (outer - center) * (radius - s.thickness) / radius
    return np.stack([inner, outer], axis=2)


def marker_uv(settings: PhantomSettings | None = None) -> np.ndarray:
    """(u, v) of the marker grid on the outer surface, shape (U*V, 2), C order."""
    s = settings or PhantomSettings()
    m = s.marker_margin
    u, v = (np.linspace(m, 1.0 - m, count) for count in s.markers)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    return np.column_stack([uu.ravel(), vv.ravel()])


def rest_volume(settings: PhantomSettings | None = None) -> tuple[VolumeSpline, FitReport]:
    """The volume spline fitted to the segmented surfaces, and the fit's error."""
    s = settings or PhantomSettings()
    return VolumeSpline.fit(segmented_surfaces(s), s.grid, s.degrees)


def forehead_model(
    settings: PhantomSettings | None = None, parameters: dict[str, float] | None = None
) -> TissueModel:
    """The phantom as a TissueModel with the true parameters (or the given ones)."""
    s = settings or PhantomSettings()
    volume, _ = rest_volume(s)
    values = dict(TRUE_PARAMETERS if parameters is None else parameters)
    return TissueModel(volume, values, BoundaryConditions(fix_lateral=s.fix_lateral))


def probe_loads(model: TissueModel, settings: PhantomSettings | None = None) -> list:
    """One load per force magnitude: at the centre, along the inward normal."""
    s = settings or PhantomSettings()
    center = np.array([0.5, 0.5])
    inward = -model.volume.outer_normal(center[None])[0]
    if s.probe_radius > 0:
        return [ProbeForce(f * inward, s.probe_radius, uv=center) for f in s.forces]
    return [PointForce(f * inward, uv=center) for f in s.forces]
