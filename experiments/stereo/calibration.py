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
        RMS reprojection error after refinement [px].
    residuals : numpy.ndarray
        Observed minus reprojected pixels after refinement, (n, 2) [px].
    """

    camera: Camera
    dlt_camera: Camera
    dlt_rms: float
    rms: float
    residuals: np.ndarray


#: Distortion model used by default for the object calibration: radial k1, k2,
#: tangential p1, p2 and thin-prism s1..s4; k3 held at zero. Chosen by the
#: reprojection error of held-out dots on the MultiDIC views (docs/stereo.md):
#: 0.61 px with k1, k2, p1, p2 alone, 0.40 px with the thin-prism terms, which
#: model a slightly tilted or decentred lens (small board cameras).
OBJECT_FLAGS = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3 | cv2.CALIB_THIN_PRISM_MODEL


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
        Flags for ``cv2.calibrateCamera``; must include
        ``CALIB_USE_INTRINSIC_GUESS``.

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
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [X.astype(np.float32).reshape(-1, 1, 3)],
        [x.astype(np.float32).reshape(-1, 1, 2)],
        tuple(image_size),
        K0,
        np.zeros(12 if flags & cv2.CALIB_THIN_PRISM_MODEL else 5),
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
    )
    cam = Camera.from_rvec(K, dist.ravel(), rvecs[0], tvecs[0], tuple(image_size))
    residuals = x - cam.project(X)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    return ObjectCalibration(cam, cam0, dlt.rms, rms, residuals)
