"""The stereo pipeline fails loudly on bad input, and is right on clean synthetic input.

No real data: images, cameras and the dotted cylinder are synthesised here.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from experiments.stereo.calibration import calibrate_from_object, stereo_calibrate
from experiments.stereo.cameras import Camera
from experiments.stereo.chessboard import find_corners
from experiments.stereo.dlt import decompose_projection, dlt_projection
from experiments.stereo.dots import detect_dots
from experiments.stereo.gridlabel import label_grid
from experiments.stereo.lattice import grid_lattice
from experiments.stereo.multidic import label_view
from experiments.stereo.surface import fit_surface, icp_to_surface, rigid_align
from experiments.stereo.triangulation import triangulate

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def rotation(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))[0]


def stereo_rig(baseline: float = 100.0) -> tuple[Camera, Camera]:
    """Left camera at the origin; right one ``baseline`` mm to its right, toed in 3 deg."""
    left = Camera(K, np.zeros(5), np.eye(3), np.zeros(3), SIZE)
    R = rotation([0.0, -np.radians(3.0), 0.0])
    right = Camera(K, np.zeros(5), R, -R @ np.array([baseline, 0.0, 0.0]), SIZE)
    return left, right


def scene(n: int = 30, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-150, 250, n), rng.uniform(-120, 120, n), rng.uniform(900, 1100, n)]
    )


def cylinder_grid(ni: int = 20, nj: int = 14) -> np.ndarray:
    """The MultiDIC layout: radius 57 mm, 12.06 deg per column, 12 mm per row."""
    th = np.radians(12.06) * np.arange(nj)
    z = 10.0 + 12.0 * np.arange(ni)
    return np.stack(
        np.broadcast_arrays(57 * np.cos(th)[None], 57 * np.sin(th)[None], z[:, None]), axis=-1
    )


def look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple:
    """R, t of an upright camera at ``center`` looking at ``target`` (OpenCV axes)."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


# --- errors ------------------------------------------------------------------------------


def test_camera_rejects_invalid_parameters():
    with pytest.raises(ValueError, match="3x3"):
        Camera(np.eye(2))
    with pytest.raises(ValueError, match="focal"):
        Camera(np.diag([-1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="rotation"):
        Camera(K, R=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="dist"):
        Camera(K, dist=np.zeros(3))
    with pytest.raises(ValueError, match="3-vector"):
        Camera(K, t=np.zeros(2))


@pytest.mark.parametrize(
    "image",
    [
        np.full((480, 640), 200, np.uint8),
        np.random.default_rng(1).integers(0, 256, (480, 640)).astype(np.uint8),
    ],
)
def test_image_without_a_grid_gives_clear_errors(image):
    with pytest.raises(ValueError, match="chessboard"):
        find_corners(image, (9, 6))
    with pytest.raises(ValueError, match="grid|dots"):
        grid_lattice(detect_dots(image).centers)
    with pytest.raises(ValueError, match="grid|dots"):
        label_view(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), cylinder_grid())


def test_triangulation_needs_two_views():
    left, _ = stereo_rig()
    X = scene()
    with pytest.raises(ValueError, match="at least 2 views"):
        triangulate([left], [left.project(X)])
    right = stereo_rig()[1]
    with pytest.raises(ValueError, match="pixel arrays"):
        triangulate([left, right], [left.project(X)])
    unseen = right.project(X)
    unseen[3] = np.nan
    with pytest.raises(ValueError, match="fewer than 2 views"):
        triangulate([left, right], [left.project(X), unseen])


def test_image_size_mismatch_is_rejected():
    left, right = stereo_rig()
    X = scene()
    small = Camera(right.K, right.dist, right.R, right.t, (320, 240))
    with pytest.raises(ValueError, match="outside its 320x240 image"):
        triangulate([left, small], [left.project(X), right.project(X)])


def test_swapped_calibration_is_rejected_not_triangulated():
    left, right = stereo_rig()
    X = scene()
    with pytest.raises(ValueError, match="behind camera"):
        triangulate([right, left], [left.project(X), right.project(X)])


@pytest.mark.parametrize("baseline", [0.0, 1e-3])
def test_degenerate_baseline_is_rejected(baseline):
    left, _ = stereo_rig()
    right = Camera(K, np.zeros(5), np.eye(3), np.array([-baseline, 0.0, 0.0]), SIZE)
    X = scene()
    with pytest.raises(ValueError, match="parallel"):
        triangulate([left, right], [left.project(X), right.project(X)])


def test_stereo_calibration_needs_matching_image_sizes():
    from experiments.stereo.calibration import CameraCalibration

    a = CameraCalibration(Camera(K, image_size=(640, 480)), 0.1, np.zeros(1), [], [])
    b = CameraCalibration(Camera(K, image_size=(800, 600)), 0.1, np.zeros(1), [], [])
    with pytest.raises(ValueError, match="image size"):
        stereo_calibrate([np.zeros((4, 3))], [np.zeros((4, 2))], [np.zeros((4, 2))], a, b)


def test_dlt_rejects_coplanar_points_and_mirrored_labels():
    left, _ = stereo_rig()
    X = scene(40)
    flat = X.copy()
    flat[:, 2] = 1000.0
    with pytest.raises(ValueError, match="coplanar"):
        dlt_projection(flat, left.project(flat))
    mirrored = X * np.array([1.0, -1.0, 1.0])  # the object's mirror image, same pixels
    assert not dlt_projection(mirrored, left.project(X)).proper
    with pytest.raises(ValueError, match="mirrored"):
        calibrate_from_object(mirrored, left.project(X), SIZE)


def test_surface_fit_rejects_underdetermined_problems():
    rng = np.random.default_rng(2)
    uv = rng.uniform(0, 1, (20, 2))
    with pytest.raises(ValueError, match="cannot determine"):
        fit_surface(rng.normal(size=(20, 3)), uv, (6, 6))
    uv_line = np.column_stack([np.full(60, 0.5), rng.uniform(0, 1, 60)])
    with pytest.raises(ValueError, match="rank-deficient"):
        fit_surface(rng.normal(size=(60, 3)), uv_line, (4, 4))


# --- the same code on clean synthetic input ---------------------------------------------


def test_dlt_recovers_a_known_camera():
    R = rotation([0.2, -0.4, 0.1])
    cam = Camera(
        np.array([[1500.0, 0, 700], [0, 1520.0, 500], [0, 0, 1]]),
        np.zeros(5),
        R,
        np.array([20.0, -10.0, 800.0]),
        (1400, 1000),
    )
    X = scene(50) - [0, 0, 1000]
    fit = dlt_projection(X, cam.project(X))
    assert fit.proper and fit.rms < 1e-6
    back = decompose_projection(fit.P)
    assert np.allclose(back.K, cam.K, atol=1e-4)
    assert np.allclose(back.R, cam.R, atol=1e-8)
    assert np.allclose(back.center(), cam.center(), atol=1e-5)


def test_triangulation_error_agrees_with_its_covariance():
    left, right = stereo_rig()
    third = Camera(K, np.zeros(5), rotation([0.05, 0.0, 0.0]), np.array([-50.0, -60.0, 0.0]), SIZE)
    cams = [left, right, third]
    X = scene(400, seed=3)
    rng = np.random.default_rng(4)
    sigma = 0.3
    obs = [c.project(X) + rng.normal(0.0, sigma, (X.shape[0], 2)) for c in cams]
    tri = triangulate(cams, obs)
    assert abs(tri.sigma / sigma - 1.0) < 0.15
    err = tri.points - X
    mahal = np.einsum("ni,nij,nj->n", err, np.linalg.inv(tri.covariances), err)
    assert abs(mahal.mean() / 3.0 - 1.0) < 0.2  # chi-square with 3 degrees of freedom


def test_lattice_never_fills_a_missing_dot_with_a_neighbour():
    img = np.full((520, 600), 235, np.uint8)
    H = np.array([[1.0, 0.08, 60.0], [0.02, 0.95, 50.0], [2e-4, 1e-4, 1.0]])
    truth = {}
    for r in range(9):
        for c in range(11):
            if (r, c) == (4, 5):
                continue  # the missing dot
            sq = np.array([[c, r], [c + 0.35, r], [c + 0.35, r + 0.35], [c, r + 0.35]]) * 44
            pts = cv2.perspectiveTransform(sq[None].astype(np.float64), H)[0]
            cv2.fillConvexPoly(img, np.round(pts * 16).astype(np.int32), 20, cv2.LINE_AA, 4)
            truth[(r, c)] = pts.mean(axis=0)
    cv2.circle(img, (int(truth[(4, 4)][0] + 30), int(truth[(4, 4)][1] + 5)), 5, 20, -1)  # clutter
    dots = detect_dots(img, max_dot_size=41)
    coords, valid = grid_lattice(dots.centers)
    tp = np.array(list(truth.values()))
    labels = list(truth)
    matched = {}
    for k in np.flatnonzero(valid):
        d = np.linalg.norm(tp - dots.centers[k], axis=1)
        assert d.min() < 1.0, "a labelled blob is not a grid dot"
        matched[labels[int(np.argmin(d))]] = tuple(coords[k])
    # One signed axis permutation plus an offset maps lattice to truth for every dot.
    (r0, c0), (a0, b0) = next(iter(matched.items()))
    rel = np.array([[r - r0, c - c0, a - a0, b - b0] for (r, c), (a, b) in matched.items()])
    T, *_ = np.linalg.lstsq(rel[:, 2:].astype(float), rel[:, :2].astype(float), rcond=None)
    assert np.allclose(T, np.round(T)) and np.allclose(rel[:, 2:] @ np.round(T), rel[:, :2])
    assert len(matched) >= 0.95 * len(truth)
    assert (4, 5) not in matched


def _synthetic_cylinder_view():
    grid = cylinder_grid()
    target = np.array([0.0, 0.0, 124.0])
    az = np.radians(80.0)
    R, t = look_at(target + 420 * np.array([np.cos(az), np.sin(az), 0.25]), target)
    cam = Camera(
        np.array([[2600.0, 0, 1232], [0, 2600.0, 1640], [0, 0, 1]]), np.zeros(5), R, t, (2464, 3280)
    )
    n = grid * [1, 1, 0] / 57.0
    ray = cam.center() - grid
    cosang = np.einsum("ijk,ijk->ij", n, ray) / np.linalg.norm(ray, axis=2)
    seen = cosang > np.cos(np.radians(65.0))
    ij = np.argwhere(seen)
    centers = cam.project(grid[seen]) + np.random.default_rng(5).normal(0, 0.2, (ij.shape[0], 2))
    lattice = np.column_stack([ij[:, 1] - 7, 3 - ij[:, 0]])  # some lattice frame
    return grid, cam, ij, centers, lattice


def test_symmetric_object_labelling_is_ambiguous_without_an_anchor():
    grid, cam, ij, centers, lattice = _synthetic_cylinder_view()
    assert 2 <= ij[:, 1].min() and ij[:, 1].max() <= 12  # neither end column in view
    valid = np.ones(ij.shape[0], dtype=bool)
    with pytest.raises(ValueError, match="fit equally well"):
        label_grid(centers, lattice, valid, grid, cam.image_size)
    k = 10
    lab = label_grid(centers, lattice, valid, grid, cam.image_size, anchors=[(k, None, ij[k, 1])])
    assert np.array_equal(lab.ij, ij)
    assert lab.calibration.rms < 0.5


def test_rigid_alignment_recovers_a_known_similarity():
    R, s, t = rotation([0.1, -0.2, 0.3]), 1.7, np.array([5.0, -3.0, 20.0])
    src = cylinder_grid().reshape(-1, 3)
    s_hat, R_hat, t_hat = rigid_align(src, s * src @ R.T + t, scale=True)
    assert np.isclose(s_hat, s) and np.allclose(R_hat, R) and np.allclose(t_hat, t)
    one, R1, t1 = rigid_align(src, src @ R.T + t)
    assert one == 1.0 and np.allclose(R1, R) and np.allclose(t1, t)


def test_spline_fits_the_cylinder_and_icp_recovers_a_motion_on_a_curved_patch():
    grid = cylinder_grid()
    ij = np.indices(grid.shape[:2]).reshape(2, -1).T
    uv = ij / (np.array(grid.shape[:2]) - 1.0)
    assert fit_surface(grid.reshape(-1, 3), uv, (4, 8)).rms < 0.01  # mm; a cubic arc ~ circle
    # ICP needs a surface without sliding symmetry: a doubly curved patch.
    g = np.linspace(-1.0, 1.0, 15)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack(
        [40 * x.ravel(), 40 * y.ravel(), (20 * x**2 - 15 * y**2 + 8 * x * y**2).ravel()]
    )
    uv = np.column_stack([(x.ravel() + 1) / 2, (y.ravel() + 1) / 2])
    surf = fit_surface(pts, uv, (6, 6))
    rng = np.random.default_rng(6)
    R, t = rotation([0.02, -0.03, 0.025]), np.array([0.8, -0.5, 0.6])
    inner = (np.abs(x.ravel()) < 0.8) & (np.abs(y.ravel()) < 0.8)  # stay inside the patch
    src = pts[inner]
    moved = (src - t) @ R + rng.normal(0, 0.01, src.shape)  # R^T (p - t), plus noise
    R_icp, t_icp, rms = icp_to_surface(moved, surf, uv[inner])
    assert rms < 0.03
    assert np.linalg.norm(moved @ R_icp.T + t_icp - src, axis=1).max() < 0.1
    assert np.allclose(R_icp, R, atol=2e-3)
