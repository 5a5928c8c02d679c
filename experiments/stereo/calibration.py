"""Camera calibration: from views of a planar target, and from a 3D object with known dots.

Planar target (chessboard, see :mod:`.chessboard` for the corners): each
camera is calibrated with ``cv2.calibrateCamera`` and a pair with
``cv2.stereoCalibrate``, by default holding the single-camera intrinsics
fixed.

3D object (MultiDIC cylinder): the normalised DLT of :mod:`.dlt` gives a
distortion-free camera, which ``cv2.calibrateCamera`` then refines together
with the lens distortion (``CALIB_USE_INTRINSIC_GUESS``; non-planar objects
need an initial ``K``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .cameras import Camera
from .dlt import decompose_projection, dlt_projection


@dataclass(frozen=True)
class CameraCalibration:
    """A single-camera calibration.

    Attributes
    ----------
    camera : Camera
        Intrinsics and distortion; pose of the first view (or of the object).
    rms : float
        RMS reprojection error over all points [px].
    per_view_rms : numpy.ndarray
        RMS reprojection error of each view [px].
    rvecs, tvecs : list of numpy.ndarray
        Pose of the target in each view (Rodrigues [rad], translation [units]).
    """

    camera: Camera
    rms: float
    per_view_rms: np.ndarray
    rvecs: list
    tvecs: list

    def view_camera(self, k: int) -> Camera:
        """The camera placed so that view ``k``'s target frame is the world frame."""
        c = self.camera
        return Camera.from_rvec(c.K, c.dist, self.rvecs[k], self.tvecs[k], c.image_size)


def calibrate_camera(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    flags: int = 0,
) -> CameraCalibration:
    """``cv2.calibrateCamera`` over several views of a planar target.

    Parameters
    ----------
    object_points : sequence of numpy.ndarray
        Target points per view, (n_k, 3) [target units].
    image_points : sequence of numpy.ndarray
        Their detections, (n_k, 2) [px].
    image_size : tuple of int
        ``(width, height)`` [px].
    flags : int
        OpenCV calibration flags.
    """
    if len(object_points) != len(image_points) or not object_points:
        raise ValueError("need the same, non-zero number of object and image point sets")
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    img = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in image_points]
    rms, K, dist, rvecs, tvecs, _, _, per_view = cv2.calibrateCameraExtended(
        obj, img, tuple(image_size), None, None, flags=flags
    )
    cam = Camera.from_rvec(K, dist.ravel(), rvecs[0], tvecs[0], tuple(image_size))
    return CameraCalibration(cam, float(rms), per_view.ravel(), list(rvecs), list(tvecs))


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated pair; camera 1 is the world frame (``R = I, t = 0``).

    Attributes
    ----------
    left, right : Camera
        The two cameras; ``right.R, right.t`` map left-camera coordinates to
        right-camera coordinates.
    rms : float
        RMS reprojection error over both cameras and all views [px].
    per_view_rms : numpy.ndarray
        Shape (n_views, 2): RMS per view and camera [px].
    """

    left: Camera
    right: Camera
    rms: float
    per_view_rms: np.ndarray

    @property
    def baseline(self) -> float:
        """Distance between the camera centres [target units]."""
        return float(np.linalg.norm(self.right.center() - self.left.center()))


def stereo_calibrate(
    object_points,
    left_points,
    right_points,
    left: CameraCalibration,
    right: CameraCalibration,
    flags: int = cv2.CALIB_FIX_INTRINSIC,
) -> StereoCalibration:
    """``cv2.stereoCalibrate`` with (by default) fixed single-camera intrinsics."""
    n = len(object_points)
    if not (n == len(left_points) == len(right_points)) or n == 0:
        raise ValueError("need the same, non-zero number of views for both cameras")
    if left.camera.image_size != right.camera.image_size:
        raise ValueError("this stereo calibration expects both cameras to share an image size")
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    l_img = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in left_points]
    r_img = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in right_points]
    cl, cr = left.camera, right.camera
    out = cv2.stereoCalibrateExtended(
        obj,
        l_img,
        r_img,
        cl.K.copy(),
        cl.dist.copy(),
        cr.K.copy(),
        cr.dist.copy(),
        cl.image_size,
        None,
        None,
        flags=flags,
    )
    rms, K1, d1, K2, d2, R, T = out[:7]
    per_view = out[-1]
    cam_l = Camera(K1, d1.ravel(), np.eye(3), np.zeros(3), cl.image_size)
    cam_r = Camera(K2, d2.ravel(), R, T.ravel(), cr.image_size)
    return StereoCalibration(cam_l, cam_r, float(rms), np.asarray(per_view).reshape(n, 2))


@dataclass(frozen=True)
class ObjectCalibration:
    """A camera calibrated from one view of a known 3D object.

    Attributes
    ----------
    camera : Camera
        Refined camera with distortion; the object frame is the world frame.
    dlt_camera : Camera
        The distortion-free DLT camera it started from.
    dlt_rms : float
        RMS reprojection error of the DLT fit [px].
    rms : float
        RMS reprojection error after refinement [px] (in-sample).
    residuals : numpy.ndarray
        Observed minus reprojected pixels after refinement, (n, 2) [px].
    principal_point_std : numpy.ndarray
        Standard errors of (cx, cy) from the calibration's covariance [px]
        (``cv2.calibrateCameraExtended``; assumes independent residuals).
    """

    camera: Camera
    dlt_camera: Camera
    dlt_rms: float
    rms: float
    residuals: np.ndarray
    principal_point_std: np.ndarray


_G = cv2.CALIB_USE_INTRINSIC_GUESS
_PRISM = cv2.CALIB_THIN_PRISM_MODEL
DISTORTION_MODELS = {
    "k1 k2": _G | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "k1 k2 k3": _G | cv2.CALIB_ZERO_TANGENT_DIST,
    "k1 k2 p1 p2": _G | cv2.CALIB_FIX_K3,
    "k1 k2 k3 p1 p2": _G,
    "k1 k2 + thin prism": _G | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | _PRISM,
    "k1 k2 p1 p2 + thin prism": _G | cv2.CALIB_FIX_K3 | _PRISM,
}
"""Candidate lens models of the object calibration, simplest first (OpenCV flags)."""

#: Distortion model used by default for the object calibration: radial k1, k2. Chosen
#: by the spatial hold-out (``select_distortion_model``) on both MultiDIC views; the
#: richer models fit the dots they saw better (0.38-0.61 against 0.66 px) but trade
#: their decentring terms against the principal point, which then moves by 50-130 px
#: (docs/results/stereo-distortion-models.md).
OBJECT_FLAGS = DISTORTION_MODELS["k1 k2"]

PRINCIPAL_POINT_STD_BOUND_PX = 25.0
"""Largest spatial standard error of the principal point accepted without a warning [px]
(1 % of a 2464 px wide image)."""


def calibrate_from_object(
    points3d: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], flags: int = OBJECT_FLAGS
) -> ObjectCalibration:
    """Calibrate one camera from known 3D points: normalised DLT, then refinement.

    Parameters
    ----------
    points3d : numpy.ndarray
        Object points, (n, 3) [mm], non-coplanar, n >= 6 (many more in practice
        to fit the distortion).
    pixels : numpy.ndarray
        Their detected images, (n, 2) [px].
    image_size : tuple of int
        ``(width, height)`` [px].
    flags : int
        Flags for ``cv2.calibrateCamera`` (a ``DISTORTION_MODELS`` entry);
        ``CALIB_USE_INTRINSIC_GUESS`` is always added.

    Raises
    ------
    ValueError
        For too few or coplanar points, or a DLT fit that is a mirror image
        (object points wrongly labelled).
    """
    X = np.asarray(points3d, dtype=float)
    x = np.asarray(pixels, dtype=float)
    dlt = dlt_projection(X, x)
    if not dlt.proper:
        raise ValueError("the DLT fit is a reflection: the object labelling is mirrored")
    cam0 = decompose_projection(dlt.P, image_size)
    K0 = cam0.K.copy()
    K0[0, 1] = 0.0  # OpenCV's model has no skew
    out = cv2.calibrateCameraExtended(
        [X.astype(np.float32).reshape(-1, 1, 3)],
        [x.astype(np.float32).reshape(-1, 1, 2)],
        tuple(image_size),
        K0,
        np.zeros(12 if flags & cv2.CALIB_THIN_PRISM_MODEL else 5),
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
    )
    _, K, dist, rvecs, tvecs, std_intrinsics = out[:6]
    cam = Camera.from_rvec(K, dist.ravel(), rvecs[0], tvecs[0], tuple(image_size))
    residuals = x - cam.project(X)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    pp_std = np.asarray(std_intrinsics, float).ravel()[2:4]
    return ObjectCalibration(cam, cam0, dlt.rms, rms, residuals, pp_std)


def pose_from_object(
    points3d: np.ndarray, pixels: np.ndarray, intrinsics: Camera
) -> ObjectCalibration:
    """Only the pose of a camera whose intrinsics come from elsewhere (``cv2.solvePnP``).

    MultiDIC's workflow: K and distortion from checkerboards, the pose from the
    object. The returned ``principal_point_std`` is zero (not estimated here) and
    ``dlt_camera`` is the DLT fit, for comparison.
    """
    X = np.asarray(points3d, dtype=float)
    x = np.asarray(pixels, dtype=float)
    dlt = dlt_projection(X, x)
    cam0 = decompose_projection(dlt.P, intrinsics.image_size)
    ok, rvec, tvec = cv2.solvePnP(X, x, intrinsics.K, intrinsics.dist)
    if not ok:
        raise ValueError("the pose could not be found from these object points")
    cam = Camera.from_rvec(intrinsics.K, intrinsics.dist, rvec, tvec, intrinsics.image_size)
    residuals = x - cam.project(X)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    return ObjectCalibration(cam, cam0, dlt.rms, rms, residuals, np.zeros(2))


def spatial_halves(points3d: np.ndarray) -> list[np.ndarray]:
    """Test masks of a spatial hold-out: halves of the object along its two longest axes.

    Four folds: the points on either side of the median along the first principal
    axis of ``points3d`` (one end of a cylinder against the other), then along the
    second (one side against the other). A fold's training set is its complement, so
    a model is judged where it saw no dot nearby, which interleaved splits cannot do.
    """
    X = np.asarray(points3d, float)
    centred = X - X.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    folds = []
    for axis in axes[:2]:
        coordinate = centred @ axis
        low = coordinate < np.median(coordinate)
        folds += [low, ~low]
    return folds


def spatial_blocks(points3d: np.ndarray, shape: tuple[int, int] = (4, 3)) -> np.ndarray:
    """Block label (0 .. a b - 1) of every point: quantile bands along the two longest axes."""
    X = np.asarray(points3d, float)
    centred = X - X.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    label = np.zeros(X.shape[0], dtype=int)
    for axis, count in zip(axes[:2], shape):
        coordinate = centred @ axis
        edges = np.quantile(coordinate, np.linspace(0, 1, count + 1)[1:-1])
        label = label * count + np.digitize(coordinate, edges)
    return label


def select_distortion_model(
    points3d: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], models=None
) -> tuple[str, dict]:
    """The lens model with the smallest spatial hold-out reprojection error.

    Each model is fitted on the complement of each ``spatial_halves`` fold and judged
    by the RMS reprojection error of the fold's points [px], pooled over the four
    folds. A richer model must beat every simpler one by 2 % to be chosen.

    Returns
    -------
    name : str
        The chosen key of ``models`` (default ``DISTORTION_MODELS``).
    table : dict
        Model -> {"holdout_rms_px", "in_sample_rms_px"}.
    """
    models = DISTORTION_MODELS if models is None else models
    X, x = np.asarray(points3d, float), np.asarray(pixels, float)
    folds = spatial_halves(X)
    table = {}
    for name, flags in models.items():
        squares = []
        for test in folds:
            camera = calibrate_from_object(X[~test], x[~test], image_size, flags).camera
            squares.append(np.sum((x[test] - camera.project(X[test])) ** 2, axis=1))
        table[name] = {
            "holdout_rms_px": float(np.sqrt(np.mean(np.concatenate(squares)))),
            "in_sample_rms_px": calibrate_from_object(X, x, image_size, flags).rms,
        }
    best = None
    for name, row in table.items():
        if best is None or row["holdout_rms_px"] < 0.98 * table[best]["holdout_rms_px"]:
            best = name
    return best, table


def principal_point_spread(
    points3d: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], flags: int = OBJECT_FLAGS
) -> np.ndarray:
    """Spatial standard error of (cx, cy) [px]: delete-one-block jackknife.

    The calibration is repeated without each of the 12 ``spatial_blocks``;
    ``sqrt((g - 1) / g sum (c_b - mean c)^2)``. Unlike the covariance it holds when
    the residuals are correlated in space (on the MultiDIC cylinder it is 9x larger,
    and agrees with the spread between the ``spatial_halves``).
    """
    X, x = np.asarray(points3d, float), np.asarray(pixels, float)
    blocks = spatial_blocks(X)
    centres = []
    for b in np.unique(blocks):
        keep = blocks != b
        centres.append(calibrate_from_object(X[keep], x[keep], image_size, flags).camera.K[:2, 2])
    centres = np.array(centres)
    g = centres.shape[0]
    return np.sqrt((g - 1) / g * np.sum((centres - centres.mean(axis=0)) ** 2, axis=0))
