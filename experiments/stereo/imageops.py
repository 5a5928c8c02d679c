"""Image operations of the synthetic renderer: the undistortion map, a box filter and the
anti-aliased square wave of the dot pattern."""

from __future__ import annotations

import numpy as np

from .cameras import Camera


def _undistortion_map(camera: Camera, step: int = 8) -> np.ndarray:
    """Undistorted normalised coordinates of every pixel, (h, w, 2).

    Exact (``cv2.undistortPoints``) on a grid of every ``step`` px, bilinear in between:
    the map is so smooth that this adds below 1e-3 px at 25 px/mm.
    """
    w, h = camera.image_size
    gu, gv = np.arange(0, w + step, step), np.arange(0, h + step, step)
    grid = np.stack(np.meshgrid(gu, gv), axis=-1).reshape(-1, 2).astype(np.float64)
    coarse = camera.undistort_normalized(grid).reshape(len(gv), len(gu), 2).astype(np.float32)
    u, v = np.arange(w), np.arange(h)
    iu, iv = u // step, v // step
    fu = (u % step / step).astype(np.float32)[None, :, None]
    fv = (v % step / step).astype(np.float32)[:, None, None]
    rows = coarse[iv]  # (h, len(gu), 2)
    top = rows[:, iu] * (1 - fu) + rows[:, iu + 1] * fu
    rows = coarse[iv + 1]
    bottom = rows[:, iu] * (1 - fu) + rows[:, iu + 1] * fu
    return top * (1 - fv) + bottom * fv


def _box_filter(x: np.ndarray, lo: float, hi: float, width: np.ndarray) -> np.ndarray:
    """Indicator of [lo, hi] averaged over a box of ``width`` centred at x (linear ramps)."""
    return np.clip((x - lo) / width + 0.5, 0, 1) * np.clip((hi - x) / width + 0.5, 0, 1)


def _square_wave(x: np.ndarray, width: np.ndarray) -> np.ndarray:
    """``(-1)^floor(x)`` averaged exactly over a box of ``width`` centred at x."""

    def tri(v):  # antiderivative of the square wave: a triangle wave of period 2
        return 1.0 - np.abs(np.mod(v, 2.0) - 1.0)

    return (tri(x + width / 2) - tri(x - width / 2)) / width
