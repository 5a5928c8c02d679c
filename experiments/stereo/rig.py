"""A camera rig: the virtual rig of the synthetic forehead experiment, and rig calibration.

**Virtual rig** (:func:`default_rig`): three upright cameras 200 mm from the forehead
phantom's centre (the origin; z out of the skin), aimed at it. Camera 0 is frontal; cameras 1
and 2 are turned by +25 and -25 degrees about the phantom's y axis. Camera 0 therefore sees
the marker index i (along x) increase to the right and j (along y) upwards. Sensors are
2048 x 1536 px with a 5000 px focal length, that is 25 px/mm at 200 mm (macro-lens-like),
with off-centre principal points and slight distortion (a few px at the corners).
``scale`` bins the sensors (0.5: 1024 x 768 px, 12.5 px/mm) for fast tests.

**Scene** (:func:`phantom_scene`): the phantom's markers, at rest and under each load, with
the orientation and deformation of each dot, from the phantom's equilibrium.

**Target** (:class:`BoardTarget`, :func:`board_poses`): a chessboard of 13 x 9 inner corners
with 3 mm squares, tilted and moved over the volume the markers occupy.

**Calibration** (:func:`calibrate_rig`): each camera's intrinsics from its board views
(k1, k2, p1, p2; k3 = 0), then its pose relative to camera 0 (``cv2.stereoCalibrate``,
intrinsics fixed). The world frame is camera 0's, in mm; OpenCV's conventions (:mod:`.cameras`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from solvers.forward.equilibrium import EquilibriumSolver

from .calibration import CameraCalibration, calibrate_camera, stereo_calibrate
from .cameras import Camera
from .chessboard import board_points, find_corners, match_board_order


@dataclass(frozen=True)
class RigSettings:
    """Layout and optics of the virtual rig (lengths in mm, angles in degrees).

    Attributes
    ----------
    distance_mm : float
        Distance of every camera centre from the phantom's centre [mm].
    azimuths_deg : tuple of float
        Rotation of each camera about the phantom's y axis [deg]; 0 is frontal.
    rolls_deg : tuple of float
        Roll of each camera about its optical axis [deg].
    image_size : tuple of int
        Full sensor ``(width, height)`` [px].
    focal_px : float
        Focal length of the full sensor [px]; ``focal_px / distance_mm`` px/mm.
    distortion : tuple of tuple of float
        ``(k1, k2, p1, p2, k3)`` per camera (dimensionless).
    principal_offset_px : tuple of tuple of float
        Principal point minus the image centre per camera, full sensor [px].
    scale : float
        Binning factor applied to the sensor (1 = full size, 0.5 = 2 x 2 binning).
    """

    distance_mm: float = 200.0
    azimuths_deg: tuple[float, ...] = (0.0, 25.0, -25.0)
    rolls_deg: tuple[float, ...] = (0.0, 1.5, -1.0)
    image_size: tuple[int, int] = (2048, 1536)
    focal_px: float = 5000.0
    distortion: tuple[tuple[float, ...], ...] = (
        (-0.08, 0.15, 2e-4, -1e-4, 0.0),
        (-0.06, 0.10, -1e-4, 2e-4, 0.0),
        (-0.09, 0.20, 1e-4, 1e-4, 0.0),
    )
    principal_offset_px: tuple[tuple[float, float], ...] = ((6.0, -4.0), (-8.0, 5.0), (3.0, 7.0))
    scale: float = 1.0

    def __post_init__(self) -> None:
        n = len(self.azimuths_deg)
        if n < 2:
            raise ValueError(f"a rig needs at least 2 cameras, got {n}")
        if not (len(self.rolls_deg) == len(self.distortion) == len(self.principal_offset_px) == n):
            raise ValueError(
                "rolls_deg, distortion and principal_offset_px need one entry per camera"
            )
        if self.distance_mm <= 0 or self.focal_px <= 0 or not 0 < self.scale <= 1:
            raise ValueError("distance_mm and focal_px must be > 0 and scale in (0, 1]")


def look_at(center, target, up=(0.0, 1.0, 0.0), roll_deg: float = 0.0) -> tuple:
    """``R`` (3, 3) and ``t`` (3,) [mm] of a camera at ``center`` aimed at ``target`` [mm].

    ``up`` appears upwards in the image; ``roll_deg`` turns the camera about its axis [deg].
    """
    z = np.asarray(target, float) - np.asarray(center, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("the up direction is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    R = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.stack([x, np.cross(z, x), z])
    return R, -R @ np.asarray(center, float)


def default_rig(settings: RigSettings | None = None) -> tuple[Camera, ...]:
    """The virtual rig's cameras in the phantom's frame [mm] (see the module docstring)."""
    s = settings or RigSettings()
    w, h = (round(v * s.scale) for v in s.image_size)
    cameras = []
    for az, roll, dist, off in zip(
        s.azimuths_deg, s.rolls_deg, s.distortion, s.principal_offset_px
    ):
        a = np.radians(az)
        center = s.distance_mm * np.array([np.sin(a), 0.0, np.cos(a)])
        R, t = look_at(center, np.zeros(3), roll_deg=roll)
        f, cx, cy = s.focal_px * s.scale, (w - 1) / 2 + off[0] * s.scale, (h - 1) / 2
        K = np.array([[f, 0.0, cx], [0.0, f, cy + off[1] * s.scale], [0.0, 0.0, 1.0]])
        cameras.append(Camera(K, np.asarray(dist, float), R, t, (w, h)))
    return tuple(cameras)


@dataclass(frozen=True)
class BoardTarget:
    """A chessboard calibration target.

    Attributes
    ----------
    pattern : tuple of int
        Inner corners ``(columns, rows)``.
    square_mm : float
        Side of a square [mm].
    margin_squares : float
        White border around the squares [squares].
    """

    pattern: tuple[int, int] = (13, 9)
    square_mm: float = 3.0
    margin_squares: float = 1.0

    def object_points(self) -> np.ndarray:
        """Inner corners ``(col, row, 0) * square_mm`` [mm], (cols * rows, 3), row by row."""
        return board_points(self.pattern) * self.square_mm

    def center(self) -> np.ndarray:
        """Centre of the inner-corner grid in board coordinates, (3,) [mm]."""
        cols, rows = self.pattern
        return np.array([cols - 1, rows - 1, 0.0]) * (0.5 * self.square_mm)


def board_poses(target: BoardTarget | None = None, count: int = 12) -> list[tuple]:
    """Board poses ``X_world = R x_board + t`` spread over the phantom's working volume.

    The board faces the cameras (its x along world +x and its y along world -y
    when untilted). The poses tilt it by up to 20 degrees about x and y, turn it
    by up to 10 degrees in its plane, move its centre by up to 9 mm sideways and
    8 mm in depth: the corners then cover the whole marker grid (40 x 40 mm,
    5 mm deep), so the lens distortion is not extrapolated at the grid's edges.

    Returns
    -------
    list of (numpy.ndarray, numpy.ndarray)
        ``count`` pairs (R (3, 3), t (3,) [mm]).
    """
    target = target or BoardTarget()
    # tilt about x, tilt about y, in-plane turn [deg]; centre x, y, z [mm]
    # fmt: off
    table = [(0, 0, 0, 0, 0, 0), (20, 0, 8, 0, 9, -6), (-20, 0, -6, 0, -9, 6),
             (0, 20, -8, 9, 0, 0), (0, -20, 6, -9, 0, -6), (14, 14, 0, -8, -8, 5),
             (-14, -14, 5, 8, 8, 0), (14, -14, -10, 8, -8, 4), (-14, 14, 10, -8, 8, -4),
             (8, -8, 4, 0, -9, 8), (-8, 8, -4, 0, 9, -8), (0, 0, 10, 9, 0, 6),
             (0, 0, -10, -9, 0, -6), (10, 10, 0, 0, 0, -8)]
    # fmt: on
    if not 3 <= count <= len(table):
        raise ValueError(f"count must lie in [3, {len(table)}], got {count}")
    base = np.diag([1.0, -1.0, -1.0])
    poses = []
    for ax, ay, turn, x, y, z in table[:count]:
        rx, ry, rz = (
            cv2.Rodrigues(np.radians(v) * e)[0] for v, e in zip((ax, ay, turn), np.eye(3))
        )
        R = ry @ rx @ base @ rz
        poses.append((R, np.array([x, y, z]) - R @ target.center()))
    return poses


@dataclass(frozen=True)
class PhantomScene:
    """The phantom's markers, as the cameras see them (phantom frame, mm).

    Attributes
    ----------
    shape : tuple of int
        Marker grid (U, V); markers are numbered ``i * V + j``.
    rest, loaded : numpy.ndarray
        Marker positions at rest (n, 3) and under each load (K, n, 3) [mm].
    rest_axes, loaded_axes : numpy.ndarray
        Dot axes (n, 3, 2) and (K, n, 3, 2) [mm/mm]: an orthonormal tangent
        basis at rest, and its image under the skin's deformation.
    inner : numpy.ndarray
        Inner surface below each marker, at the marker's (u, v) (n, 3) [mm].
    forces, contacts, tips : numpy.ndarray
        Force (K, 3) [N], contact at rest (K, 3) and under load (K, 3) [mm].
    probe_radius : numpy.ndarray
        Load model's probe radius (K,) [mm]; 0 = point force.
    """

    shape: tuple[int, int]
    rest: np.ndarray
    rest_axes: np.ndarray
    loaded: np.ndarray
    loaded_axes: np.ndarray
    inner: np.ndarray
    forces: np.ndarray
    contacts: np.ndarray
    tips: np.ndarray
    probe_radius: np.ndarray


def phantom_scene(
    phantom: PhantomSettings | None = None, parameters: dict[str, float] | None = None
) -> PhantomScene:
    """Solve the phantom (default settings, true parameters) under its loads: what cameras see."""
    phantom = phantom or PhantomSettings()
    truth = forehead_model(phantom, parameters or TRUE_PARAMETERS)
    vol = truth.volume
    params = vol.outer_params(marker_uv(phantom))
    J, Ju, Jv, Jw = (
        vol.collocation(params, d) for d in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1))
    )

    def tangents(P):
        return np.stack([Ju @ P, Jv @ P], axis=-1)

    T0 = tangents(truth.rest)
    t1 = T0[..., 0] / np.linalg.norm(T0[..., 0], axis=1, keepdims=True)
    n = np.cross(T0[..., 0], T0[..., 1])
    n *= np.sign(np.sum(n * (Jw @ truth.rest), axis=1, keepdims=True))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rest_axes = np.stack([t1, np.cross(n, t1)], axis=-1)
    pinv = np.linalg.pinv(T0)
    solver = EquilibriumSolver(truth)
    loads = probe_loads(truth, phantom)
    loaded, axes, tips, contacts = [], [], [], []
    for load in loads:
        P = solver.solve(truth.generalized_force(load)).positions
        loaded.append(J @ P)
        axes.append(np.einsum("nij,njk,nkl->nil", tangents(P), pinv, rest_axes))
        centre = vol.collocation(vol.outer_params(load.uv[None]))
        tips.append((centre @ P)[0])
        contacts.append((centre @ truth.rest)[0])
    inner = vol.collocation(np.column_stack([params[:, :2], np.zeros(len(params))]))
    return PhantomScene(
        tuple(phantom.markers),
        J @ truth.rest,
        rest_axes,
        np.stack(loaded),
        np.stack(axes),
        inner @ truth.rest,
        np.array([ld.force for ld in loads]),
        np.array(contacts),
        np.array(tips),
        np.full(len(loads), float(phantom.probe_radius)),
    )


@dataclass(frozen=True)
class RigCalibration:
    """A calibrated rig; camera 0's frame is the world frame [mm].

    Attributes
    ----------
    cameras : tuple of Camera
        All cameras; ``cameras[0]`` has ``R = I, t = 0``.
    rms_px : tuple of float
        RMS reprojection error of each camera's own calibration [px].
    stereo_rms_px : tuple of float
        RMS of the stereo calibration of each camera with camera 0 [px] (0 for camera 0).
    working_distance_mm : float
        Median distance from camera 0 to the board's centre [mm]; the scene is
        assumed to sit at about this distance.
    """

    cameras: tuple[Camera, ...]
    rms_px: tuple[float, ...]
    stereo_rms_px: tuple[float, ...]
    working_distance_mm: float

    def check_geometry(self, min_ray_angle: float = 1.0) -> None:
        """Raise ``ValueError`` if some camera has no baseline to camera 0.

        The angle subtended by the baseline at the working distance must be at
        least ``min_ray_angle`` [deg]; below it depth is undetermined.
        """
        c0 = self.cameras[0].center()
        for c, cam in enumerate(self.cameras[1:], start=1):
            baseline = float(np.linalg.norm(cam.center() - c0))
            angle = np.degrees(2 * np.arctan2(baseline, 2 * self.working_distance_mm))
            if angle < min_ray_angle:
                raise ValueError(
                    f"degenerate camera geometry: cameras 0 and {c} are {baseline:.3g} mm apart "
                    f"at a working distance of {self.working_distance_mm:.0f} mm (their rays "
                    f"meet at {angle:.2g} deg < {min_ray_angle} deg), so depth is undetermined; "
                    "move the cameras apart"
                )


def posed_camera(camera: Camera, objects, corners, size, index: int = 0) -> CameraCalibration:
    """Given intrinsics, the board pose of every view (``cv2.solvePnP``) and the RMS [px].

    Raises
    ------
    ValueError
        If the intrinsics are for another image size than the images.
    """
    if tuple(camera.image_size) != tuple(size):
        raise ValueError(
            f"the intrinsics of camera {index} are for {camera.image_size[0]}x"
            f"{camera.image_size[1]} images, its board images are {size[0]}x{size[1]}"
        )
    rvecs, tvecs, per_view, squares = [], [], [], []
    for X, x in zip(objects, corners):
        ok, rvec, tvec = cv2.solvePnP(
            np.asarray(X, np.float64), np.asarray(x, np.float64), camera.K, camera.dist
        )
        view = Camera.from_rvec(camera.K, camera.dist, rvec, tvec, camera.image_size)
        error = np.sum((np.asarray(x) - view.project(np.asarray(X))) ** 2, axis=1)
        rvecs.append(rvec), tvecs.append(tvec), squares.append(error)
        per_view.append(float(np.sqrt(np.mean(error))))
    rms = float(np.sqrt(np.mean(np.concatenate(squares))))
    first = Camera.from_rvec(camera.K, camera.dist, rvecs[0], tvecs[0], camera.image_size)
    return CameraCalibration(first, rms, np.array(per_view), rvecs, tvecs)


def calibrate_rig(
    board_images: Sequence[Sequence[np.ndarray]],
    target: BoardTarget,
    flags: int = cv2.CALIB_FIX_K3,
    intrinsics: Sequence[Camera] | None = None,
) -> RigCalibration:
    """Calibrate every camera and its pose relative to camera 0 from chessboard images.

    Parameters
    ----------
    board_images : sequence of sequence of numpy.ndarray
        ``board_images[c][j]``: camera ``c``'s image of board pose ``j``; every
        camera must see every pose (the same poses in the same order).
    target : BoardTarget
        The board (pattern and square size).
    flags : int
        ``cv2.calibrateCamera`` flags of the single-camera calibrations.
    intrinsics : sequence of Camera, optional
        One camera per entry of ``board_images`` whose K and distortion are kept
        (a separate calibration, ``experiments.stereo.intrinsics``); then only the
        board poses (``cv2.solvePnP``) and the cameras' poses are estimated.

    Raises
    ------
    ValueError
        For fewer than 2 cameras or 3 poses, differing counts or sizes, or a
        board not found (the message names camera and pose).
    """
    n_cams = len(board_images)
    n_views = len(board_images[0]) if n_cams else 0
    if n_cams < 2 or n_views < 3 or any(len(v) != n_views for v in board_images):
        raise ValueError("need >= 2 cameras, each with the same >= 3 board views")
    if intrinsics is not None and len(intrinsics) != n_cams:
        raise ValueError(f"the intrinsics are for {len(intrinsics)} cameras, the rig has {n_cams}")
    corners = []
    for c, views in enumerate(board_images):
        sizes = {np.shape(im)[:2] for im in views}
        if len(sizes) != 1:
            raise ValueError(f"camera {c}: board images differ in size {sorted(sizes)}")
        found = []
        for j, image in enumerate(views):
            try:
                found.append(find_corners(image, target.pattern))
            except ValueError as err:
                raise ValueError(f"camera {c}, board view {j}: {err}") from None
        corners.append(found)
    obj = [target.object_points()] * n_views
    singles = []
    for c, views in enumerate(board_images):
        if c:
            corners[c] = [
                match_board_order(r, k, target.pattern) for r, k in zip(corners[0], corners[c])
            ]
        h, w = np.shape(views[0])[:2]
        if intrinsics is None:
            singles.append(calibrate_camera(obj, corners[c], (w, h), flags=flags))
        else:
            singles.append(posed_camera(intrinsics[c], obj, corners[c], (w, h), c))
    first = singles[0].camera
    cameras, stereo_rms = [Camera(first.K, first.dist, image_size=first.image_size)], [0.0]
    for c in range(1, n_cams):
        pair = stereo_calibrate(obj, corners[0], corners[c], singles[0], singles[c])
        cameras.append(pair.right)
        stereo_rms.append(pair.rms)
    centre = target.center()
    depth = [
        np.linalg.norm(cv2.Rodrigues(r)[0] @ centre + np.ravel(t))
        for r, t in zip(singles[0].rvecs, singles[0].tvecs)
    ]
    return RigCalibration(
        tuple(cameras), tuple(s.rms for s in singles), tuple(stereo_rms), float(np.median(depth))
    )
