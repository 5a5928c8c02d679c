"""Which control points are held: the boundary conditions of the volume (docs/model.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoundaryConditions:
    """Which control points are fixed (zero displacement).

    Attributes
    ----------
    fix_inner : bool
        Fix the inner layer c = 0 (w = 0), attached to the fascia. Default.
    fix_lateral : bool
        Also fix the lateral ring a in {0, M-1} or b in {0, N-1}, as for a patch
        cut out of a larger face.
    """

    fix_inner: bool = True
    fix_lateral: bool = False

    def fixed_mask(self, shape: tuple[int, int, int]) -> np.ndarray:
        """Boolean (M, N, L) array, True where a control point is fixed."""
        mask = np.zeros(shape, dtype=bool)
        if self.fix_inner:
            mask[:, :, 0] = True
        if self.fix_lateral:
            mask[[0, -1], :, :] = True
            mask[:, [0, -1], :] = True
        return mask
