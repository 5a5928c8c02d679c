"""Chessboard corners and the calibration of a stereo pair from chessboard images.

Corners are found with ``cv2.findChessboardCornersSB`` (exhaustive search,
accuracy mode) and, if that fails, with ``cv2.findChessboardCorners`` refined
by ``cv2.cornerSubPix``. Board coordinates are ``(col, row, 0)`` in squares
(the square size of OpenCV's sample is not documented).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .calibration import CameraCalibration, StereoCalibration, calibrate_camera, stereo_calibrate
from .dots import to_gray

_SUBPIX = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)


def board_points(pattern: tuple[int, int]) -> np.ndarray:
    """Inner-corner coordinates ``(col, row, 0)`` [squares], shape (cols * rows, 3)."""
    cols, rows = pattern
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    return np.hstack([grid, np.zeros((grid.shape[0], 1))]).astype(np.float64)


def find_corners(image: np.ndarray, pattern: tuple[int, int], subpix_window: int = 5) -> np.ndarray:
    """Sub-pixel chessboard inner corners, row by row, shape (cols * rows, 2) [px].

    ``cv2.findChessboardCornersSB`` (exhaustive, accuracy mode) first, the
    classic ``cv2.findChessboardCorners`` if it fails; either way the corners
    are then refined by ``cv2.cornerSubPix`` with a ``(2 w + 1)^2`` window,
    ``w = subpix_window`` [px], which must stay below half the smallest square.
    On OpenCV's sample this refinement lowers the calibration RMS from about
    0.23 to 0.20 px and removes outliers at the board's outer corners.

    Raises
    ------
    ValueError
        If neither detector finds the complete board.
    """
    gray = to_gray(image)
    ok, corners = cv2.findChessboardCornersSB(
        gray, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    )
    if not ok:
        ok, corners = cv2.findChessboardCorners(
            gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
    if not ok:
        raise ValueError(f"no {pattern[0]}x{pattern[1]} chessboard found in the image")
    win = (int(subpix_window), int(subpix_window))
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), win, (-1, -1), _SUBPIX)
    return corners.reshape(-1, 2).astype(np.float64)


def match_board_order(
    reference: np.ndarray, corners: np.ndarray, pattern: tuple[int, int]
) -> np.ndarray:
    """Reverse ``corners`` if needed so their ordering agrees with ``reference``.

    A non-square board is found either way round (a 180-degree turn). For a
    stereo pair, whose cameras are only slightly rotated relative to each
    other, the ordering is the one whose row and column directions point
    the same way in both images.
    """
    cols = pattern[0]

    def directions(c):
        return np.concatenate([c[cols - 1] - c[0], c[-cols] - c[0]])

    if directions(reference) @ directions(corners) < 0:
        return corners[::-1].copy()
    return corners


@dataclass(frozen=True)
class StereoBoardCalibration:
    """Everything measured while calibrating a pair from chessboard images.

    Attributes
    ----------
    left, right : CameraCalibration
        Single-camera calibrations.
    stereo : StereoCalibration
        The pair, intrinsics fixed to ``left`` and ``right``.
    left_corners, right_corners : list of numpy.ndarray
        Detected corners per pair, (cols * rows, 2) [px], in the same order.
    object_points : numpy.ndarray
        Board corners ``(col, row, 0)`` [squares].
    """

    left: CameraCalibration
    right: CameraCalibration
    stereo: StereoCalibration
    left_corners: list
    right_corners: list
    object_points: np.ndarray


def calibrate_stereo_images(
    left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray], pattern: tuple[int, int]
) -> StereoBoardCalibration:
    """Detect the board in every pair and calibrate both cameras and the pair.

    Raises
    ------
    ValueError
        If the image lists differ in length or size, or a board is not found
        (the message names the pair).
    """
    if len(left_images) != len(right_images) or not left_images:
        raise ValueError("need the same, non-zero number of left and right images")
    sizes = {np.asarray(im).shape[:2] for im in (*left_images, *right_images)}
    if len(sizes) != 1:
        raise ValueError(f"all images must have one size, got {sorted(sizes)}")
    h, w = sizes.pop()
    left_c, right_c = [], []
    for k, (li, ri) in enumerate(zip(left_images, right_images)):
        try:
            lc, rc = find_corners(li, pattern), find_corners(ri, pattern)
        except ValueError as err:
            raise ValueError(f"pair {k}: {err}") from err
        left_c.append(lc)
        right_c.append(match_board_order(lc, rc, pattern))
    obj = board_points(pattern)
    objs = [obj] * len(left_c)
    cal_l = calibrate_camera(objs, left_c, (w, h))
    cal_r = calibrate_camera(objs, right_c, (w, h))
    stereo = stereo_calibrate(objs, left_c, right_c, cal_l, cal_r)
    return StereoBoardCalibration(cal_l, cal_r, stereo, left_c, right_c, obj)
