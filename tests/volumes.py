"""Test volumes shared by the continuum verifications (imported by the tests)."""

from __future__ import annotations

import numpy as np

from symbolic.continuum import box_volume
from symbolic.volume import VolumeSpline


def curved_volume() -> VolumeSpline:
    """A 20 x 16 x 4 mm slab with a bulged top and wavy sides (a non-affine map)."""
    box = box_volume((20.0, 16.0, 4.0), (6, 5, 3), (3, 3, 2))
    p = box.control_points
    bulge = 1.5 * np.sin(np.pi * p[:, 0] / 20) * np.sin(np.pi * p[:, 1] / 16) * p[:, 2] / 4
    shifted = p + np.column_stack([0.8 * np.sin(p[:, 1] / 5), 0.3 * p[:, 0] / 20, bulge])
    return VolumeSpline(box.basis, shifted)
