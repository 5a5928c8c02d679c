"""The stereo pipeline end to end on rendered images of the forehead phantom.

The phantom (9 x 9 markers; 0.17 N and 0.25 N at the centre) is rendered by the
virtual three-camera rig, with chessboard views for the calibration. The images
are then calibrated, detected, indexed and triangulated into a dataset, and the
dataset is fitted. The fast tests use 2 x 2 binned sensors (1024 x 768 px,
12.5 px/mm). The fit test uses the full sensors (25 px/mm) and is marked slow.
The numbers are printed with ``-s``.
"""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from experiments.data.dataset import load_dataset
from experiments.problem.fitting import FitSettings, build_problem
from experiments.stereo.cameras import Camera
from experiments.stereo.reconstruct import ReconstructSettings, main, reconstruct
from experiments.stereo.render import (
    Probe,
    Renderer,
    RenderSettings,
    write_synthetic_experiment,
)
from experiments.stereo.rig import RigCalibration, RigSettings
from experiments.stereo.surface import rigid_align
from solvers.inverse.nested import NestedSolver

TRUE_ALPHA = np.array([2.6, 0.18, 1.7])  # N/mm, experiments.phantom.forehead.TRUE_PARAMETERS


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stereo") / "experiment"
    return write_synthetic_experiment(folder, rig=RigSettings(scale=0.5))


@pytest.fixture(scope="module")
def reconstruction(experiment):
    return reconstruct(experiment.folder)


def rms(error: np.ndarray) -> float:
    """RMS length of (n, 3) errors, ignoring NaN rows."""
    error = error.reshape(-1, 3)
    error = error[np.isfinite(error[:, 0])]
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def marker_errors(experiment, dataset) -> list[np.ndarray]:
    """Reconstructed minus true markers, rest first, each (n, 3) [mm]."""
    scene = experiment.scene
    rest = dataset.outer_rest.reshape(-1, 3) - scene.rest
    return [rest] + [d.reshape(-1, 3) - t for d, t in zip(dataset.outer_loaded, scene.loaded)]


def clear_sight(experiment, k: int, render: RenderSettings | None = None) -> np.ndarray:
    """(C, n) True where camera c sees all of marker n's dot past the probe of load k.

    The line of sight of the dot's centre must pass the probe's axis farther than the probe
    radius plus the dot radius.
    """
    scene, render = experiment.scene, render or RenderSettings()
    axis = -scene.forces[k] / np.linalg.norm(scene.forces[k])
    tip, length = scene.tips[k], render.probe_length_mm
    radius = render.probe_radius_mm + 0.5 * render.dot_diameter_mm
    s = np.linspace(0.0, 1.0, 4001)[:, None]
    clear = np.zeros((len(experiment.cameras), len(scene.rest)), dtype=bool)
    for c, cam in enumerate(experiment.cameras):
        for n, marker in enumerate(scene.loaded[k]):
            sight = marker + s * (cam.center() - marker)  # the line of sight, sampled
            h = np.clip((sight - tip) @ axis, 0.0, length)
            clear[c, n] = np.linalg.norm(sight - tip - h[:, None] * axis, axis=1).min() > radius
    return clear


def copy_experiment(experiment, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(experiment.folder, folder)
    return folder


# --- rendering -----------------------------------------------------------------------------


def test_dot_coverage_integrates_to_the_projected_area():
    """A frontal dot covers pi r^2 (f / Z)^2 px in total, however it falls on the pixels."""
    K = np.array([[4000.0, 0, 99.5], [0, 4000.0, 99.5], [0, 0, 1]])
    cam = Camera(K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, 200.0]), (200, 200))
    view = Renderer(cam, RenderSettings(dot_diameter_mm=1.0, supersample=8))
    axes = np.eye(3)[:, [1, 0]][None]  # normal -z: facing the camera
    for offset in ([0.0, 0.0, 0.0], [0.013, -0.007, 0.0], [0.3, 0.2, 0.0]):
        cover = view.dot_coverage(np.array([offset]), axes)
        expected = np.pi * 0.5**2 * (4000.0 / 200.0) ** 2
        assert cover.sum() == pytest.approx(expected, rel=2e-3)


# --- the pipeline --------------------------------------------------------------------------


def test_calibration_recovers_the_rig(experiment, reconstruction):
    cal = reconstruction.calibration
    truth = experiment.cameras
    print(
        f"\ncalibration RMS {np.round(cal.rms_px, 3)} px, stereo {np.round(cal.stereo_rms_px, 3)}"
    )
    assert max(cal.rms_px) < 0.1 and max(cal.stereo_rms_px) < 0.1
    R0, t0 = truth[0].R, truth[0].t
    for cam, true in zip(cal.cameras[1:], truth[1:]):
        centre = R0 @ true.center() + t0  # in camera 0's frame, as calibrated
        baseline = np.linalg.norm(centre)
        print(f"centre off by {np.linalg.norm(cam.center() - centre):.3f} mm of {baseline:.1f}")
        assert np.linalg.norm(cam.center() - centre) < 2e-3 * baseline
        assert abs(cam.K[0, 0] / true.K[0, 0] - 1) < 1e-3


def test_markers_within_0_02_mm_of_the_truth(experiment, reconstruction):
    errors = marker_errors(experiment, reconstruction.dataset)
    values = [rms(e) for e in errors]
    worst = [float(np.nanmax(np.linalg.norm(e, axis=1))) for e in errors]
    print(f"\nmarker RMS rest, 0.17 N, 0.25 N: {np.round(values, 4)} mm; max {np.round(worst, 4)}")
    print(
        f"registration RMS {reconstruction.registration_rms_mm:.4f} mm, "
        f"reprojection RMS {np.round(reconstruction.reprojection_rms_px, 3)} px"
    )
    assert max(values) < 0.02
    assert max(worst) < 0.05  # a wrong index would be a whole spacing (5 mm) off
    assert np.isfinite(reconstruction.dataset.outer_rest).all()


def test_occluded_markers_are_nan_not_mismatched(experiment, reconstruction):
    dataset = reconstruction.dataset
    for k in range(len(experiment.scene.forces)):
        clear = clear_sight(experiment, k)
        used = np.isfinite(reconstruction.observations[k + 1, ..., 0])  # (C, n)
        seen = np.isfinite(dataset.outer_loaded[k].reshape(-1, 3)[:, 0])
        hidden = ~clear.all(axis=0)
        print(f"\nload {k}: {hidden.sum()} markers hidden in some view, {np.sum(~seen)} NaN")
        assert not (used & ~clear).any()  # no view in which the probe covers part of the dot
        assert not seen[clear.sum(axis=0) < 2].any()  # fewer than two clear views: NaN
        assert (~seen).any() and np.all(seen == (used.sum(axis=0) >= 2))
    errors = marker_errors(experiment, dataset)[1:]
    assert max(float(np.nanmax(np.linalg.norm(e, axis=1))) for e in errors) < 0.05


def test_partly_covered_dots_are_dropped(experiment, reconstruction, tmp_path):
    """A probe of 4.8 mm radius cuts into the dots 5 mm from the contact: never used."""
    folder = copy_experiment(experiment, tmp_path)
    fat, scene = RenderSettings(probe_radius_mm=4.8), experiment.scene
    for c, cam in enumerate(experiment.cameras):
        view, rng = Renderer(cam, fat), np.random.default_rng([7, c])
        for k, (tip, force) in enumerate(zip(scene.tips, scene.forces)):
            probe = Probe(tip, -force / np.linalg.norm(force), 4.8, fat.probe_length_mm)
            image = view.skin(scene.loaded[k], scene.loaded_axes[k], probe, rng)
            cv2.imwrite(str(folder / f"cam{c}_load{k}.png"), image)
    cal = reconstruction.calibration
    careless = reconstruct(folder, cal, ReconstructSettings(ring_spread=np.inf))
    result = reconstruct(folder, cal)
    for k in range(len(scene.forces)):
        partly = ~clear_sight(experiment, k, fat)
        assert (np.isfinite(careless.observations[k + 1, ..., 0]) & partly).any()
        assert not (np.isfinite(result.observations[k + 1, ..., 0]) & partly).any()
    errors = marker_errors(experiment, result.dataset)[1:]
    print(f"\nfat probe: marker RMS {np.round([rms(e) for e in errors], 4)} mm")
    assert max(rms(e) for e in errors) < 0.02
    assert max(float(np.nanmax(np.linalg.norm(e, axis=1))) for e in errors) < 0.05


def test_camera0_frame_keeps_the_shape(experiment, reconstruction, tmp_path):
    """Without a segmentation the grid stays in camera 0's frame, with the same shape."""
    folder = copy_experiment(experiment, tmp_path)
    spec = json.loads((folder / "experiment.json").read_text())
    cam0 = experiment.cameras[0]
    for load in spec["loads"]:
        load["force_N"] = (cam0.R @ load["force_N"]).tolist()
        load["contact_mm"] = (cam0.R @ load["contact_mm"] + cam0.t).tolist()
    spec.update(frame="camera0", thickness_mm=5.0)
    (folder / "experiment.json").write_text(json.dumps(spec))
    data = reconstruct(folder, reconstruction.calibration).dataset
    truth = cam0.to_camera(experiment.scene.rest)
    rest = data.outer_rest.reshape(-1, 3)
    assert rms(rest - truth) < 1.0  # camera 0's calibrated frame: rays off by its intrinsics
    _, R, t = rigid_align(rest, truth)
    assert rms(rest @ R.T + t - truth) < 0.02
    thickness = np.linalg.norm(data.outer_rest - data.inner_rest, axis=-1)
    assert np.allclose(thickness, 5.0)
    assert np.all(data.inner_rest[..., 2] > data.outer_rest[..., 2])  # deeper, away from cam 0


def test_command_line(experiment, tmp_path, capsys):
    out = tmp_path / "dataset.npz"
    assert main([str(experiment.folder), "--out", str(out)]) == 0
    assert load_dataset(out).outer_loaded.shape == (2, 9, 9, 3)
    assert main([str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert "no experiment.json" in capsys.readouterr().err


def fit_alpha(dataset, cases=None) -> np.ndarray:
    """alpha_u, alpha_v, alpha_w [N/mm] by the nested inverse (all loads jointly by default)."""
    problem = build_problem(dataset, FitSettings(names=("alpha_u", "alpha_v", "alpha_w")), cases)
    return NestedSolver(problem).solve().x


def test_given_intrinsics_are_kept_and_only_the_poses_estimated(experiment, tmp_path, capsys):
    """``--intrinsics FILE``: the cameras' K and distortion from a separate calibration
    (here the truth) are used as given; the markers are as accurate as with the rig's own."""
    from experiments.stereo.intrinsics import load_intrinsics, save_intrinsics

    path = tmp_path / "intrinsics.json"
    save_intrinsics(path, experiment.cameras)
    given = load_intrinsics(path)
    rec = reconstruct(experiment.folder, intrinsics=given)
    for camera, true in zip(rec.calibration.cameras, experiment.cameras):
        np.testing.assert_array_equal(camera.K, true.K)
        np.testing.assert_array_equal(camera.dist, true.dist)
    assert max(rec.calibration.rms_px) < 0.1
    assert max(rms(e) for e in marker_errors(experiment, rec.dataset)) < 0.02
    out = tmp_path / "dataset.npz"
    assert main([str(experiment.folder), "--out", str(out), "--intrinsics", str(path)]) == 0
    assert "intrinsics given" in capsys.readouterr().out
    save_intrinsics(path, experiment.cameras[:2])
    assert main([str(experiment.folder), "--out", str(out), "--intrinsics", str(path)]) == 2
    assert "intrinsics are for 2 cameras, the rig has 3" in capsys.readouterr().err


@pytest.mark.parametrize(
    "text, message",
    [
        ("not json", "cannot read"),
        ('{"schema": "other"}', "not an intrinsics file"),
        ('{"schema": "dvs-intrinsics/1", "cameras": []}', "non-empty"),
        ('{"schema": "dvs-intrinsics/1", "cameras": [{"K": 1}]}', "needs K"),
        (
            '{"schema": "dvs-intrinsics/1", "cameras": [{"K": [[1,0,0],[0,1,0],[0,0,1]], '
            '"dist": [0, 0, 0], "image_size": [640, 480]}]}',
            "dist needs",
        ),
        (
            '{"schema": "dvs-intrinsics/1", "cameras": [{"K": [[-1,0,0],[0,1,0],[0,0,1]], '
            '"dist": [0, 0, 0, 0, 0], "image_size": [640, 480]}]}',
            "K must be",
        ),
    ],
)
def test_a_bad_intrinsics_file_is_refused_in_one_line(tmp_path, text, message):
    from experiments.stereo.intrinsics import load_intrinsics

    path = tmp_path / "intrinsics.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        load_intrinsics(path)
    assert "\n" not in str(error.value)


def test_fit_recovers_alpha(reconstruction):
    """Both loads jointly: within 5 % (about two standard deviations of alpha_u here)."""
    x = fit_alpha(reconstruction.dataset)
    print(f"\nalpha error, both loads: {np.round(100 * (x / TRUE_ALPHA - 1), 2)} %")
    np.testing.assert_allclose(x, TRUE_ALPHA, rtol=0.05)


@pytest.mark.slow
def test_fit_recovers_alpha_at_full_resolution(tmp_path):
    experiment = write_synthetic_experiment(tmp_path / "full")
    dataset = reconstruct(experiment.folder).dataset
    values = [rms(e) for e in marker_errors(experiment, dataset)]
    print(f"\nfull sensors: marker RMS rest, 0.17 N, 0.25 N {np.round(values, 4)} mm")
    for cases in ([0], [1]):
        x = fit_alpha(dataset, cases)
        print(f"alpha error, load {cases[0]} alone: {np.round(100 * (x / TRUE_ALPHA - 1), 2)} %")
    x = fit_alpha(dataset)
    print(f"alpha error, both loads: {np.round(100 * (x / TRUE_ALPHA - 1), 2)} %")
    np.testing.assert_allclose(x, TRUE_ALPHA, rtol=0.05)


# --- errors --------------------------------------------------------------------------------


def test_missing_images_are_named(experiment, tmp_path):
    folder = copy_experiment(experiment, tmp_path)
    (folder / "cam1_load1.png").unlink()
    (folder / "cam2_board3.png").unlink()
    with pytest.raises(ValueError, match="missing images cam1_load1.png, cam2_board3.png"):
        reconstruct(folder)


def test_image_without_a_grid(experiment, reconstruction, tmp_path):
    folder = copy_experiment(experiment, tmp_path)
    view = Renderer(experiment.cameras[1])
    blank = view.skin(np.zeros((0, 3)), np.zeros((0, 3, 2)))
    cv2.imwrite(str(folder / "cam1_rest.png"), blank)
    with pytest.raises(ValueError, match="cam1_rest.png: no dot grid found"):
        reconstruct(folder, reconstruction.calibration)


def test_mismatched_calibration(experiment, reconstruction):
    cal = reconstruction.calibration
    swapped = RigCalibration(
        (cal.cameras[0], cal.cameras[2], cal.cameras[1]),
        cal.rms_px,
        cal.stereo_rms_px,
        cal.working_distance_mm,
    )
    with pytest.raises(ValueError, match="calibration does not match these images"):
        reconstruct(experiment.folder, swapped)
    bigger = RigCalibration(
        tuple(Camera(c.K * [[2], [2], [1]], c.dist, c.R, c.t, (2048, 1536)) for c in cal.cameras),
        cal.rms_px,
        cal.stereo_rms_px,
        cal.working_distance_mm,
    )
    with pytest.raises(ValueError, match="calibration of camera 0 is for 2048x1536"):
        reconstruct(experiment.folder, bigger)


def test_degenerate_geometry_from_images(tmp_path):
    """Three cameras 0.7 mm apart at 200 mm: calibrated from images, then refused."""
    rig = RigSettings(scale=0.25, azimuths_deg=(0.0, 0.2, -0.2))
    folder = write_synthetic_experiment(tmp_path / "degenerate", rig=rig, n_boards=6).folder
    with pytest.raises(ValueError, match="degenerate camera geometry"):
        reconstruct(folder)


def test_board_corners_found_on_a_scaled_copy_are_refined_to_the_truth():
    """A rendered 2048 x 1536 board (above DETECT_SIZE, so found on a scaled-down copy)
    gives corners within a tenth of a pixel of their true projections."""
    from experiments.stereo.chessboard import DETECT_SIZE, find_corners
    from experiments.stereo.render import Renderer
    from experiments.stereo.rig import BoardTarget, board_poses, default_rig

    camera, target = default_rig()[0], BoardTarget()
    assert max(camera.image_size) > DETECT_SIZE
    R, t = board_poses(target, 3)[1]
    image = Renderer(camera).board((R, t), target, np.random.default_rng(0))
    truth = camera.project(target.object_points() @ R.T + t)
    found = find_corners(image, target.pattern)
    if np.linalg.norm(found[0] - truth[0]) > np.linalg.norm(found[-1] - truth[0]):
        found = found[::-1]
    error = np.linalg.norm(found - truth, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.05 and error.max() < 0.1


def _object_view(dist, noise_px=0.3, seed=0):
    """The MultiDIC cylinder seen by a 2464 x 3280 camera with lens ``dist``, noisy pixels."""
    from experiments.stereo.cameras import Camera

    th = np.radians(12.06) * np.arange(14) - np.radians(78.0)
    z = 10.0 + 12.0 * np.arange(20)
    grid = np.stack(
        np.broadcast_arrays(57 * np.cos(th)[None], 57 * np.sin(th)[None], z[:, None]), axis=-1
    ).reshape(-1, 3)
    R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    t = -R @ np.array([450.0, 0.0, 124.0])
    K = np.array([[3000.0, 0.0, 1240.0], [0.0, 3000.0, 1650.0], [0.0, 0.0, 1.0]])
    camera = Camera(K, np.asarray(dist, float), R, t, (2464, 3280))
    facing = grid[:, 0] > 15.0
    pixels = camera.project(grid[facing])
    pixels += np.random.default_rng(seed).normal(0.0, noise_px, pixels.shape)
    return grid[facing], pixels, camera


def test_the_spatial_hold_out_does_not_pick_terms_the_lens_lacks():
    """Radial distortion only: the richer models fit the seen dots better but the
    spatial hold-out keeps k1 k2; a decentred lens gets decentring terms (tangential or
    thin prism, which to first order are the same distortion)."""
    from experiments.stereo.calibration import select_distortion_model

    X, x, camera = _object_view([-0.08, 0.05, 0.0, 0.0, 0.0])
    name, table = select_distortion_model(X, x, camera.image_size)
    assert name == "k1 k2"
    assert min(r["in_sample_rms_px"] for r in table.values()) < table["k1 k2"]["in_sample_rms_px"]
    X, x, camera = _object_view([-0.08, 0.05, 0.004, -0.003, 0.0])
    name, table = select_distortion_model(X, x, camera.image_size)
    assert "p1 p2" in name or "prism" in name
    assert table[name]["holdout_rms_px"] < 0.7 * table["k1 k2"]["holdout_rms_px"]


def test_the_block_jackknife_agrees_with_the_covariance_for_independent_noise():
    """With independent pixel noise both standard errors of the principal point measure
    the same thing: they agree within a factor of two, and the truth is within 3 of them."""
    from experiments.stereo.calibration import calibrate_from_object, principal_point_spread

    X, x, camera = _object_view([-0.08, 0.05, 0.0, 0.0, 0.0], noise_px=0.5)
    cal = calibrate_from_object(X, x, camera.image_size)
    spread = principal_point_spread(X, x, camera.image_size)
    ratio = spread / cal.principal_point_std
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    error = np.abs(cal.camera.K[:2, 2] - camera.K[:2, 2])
    assert np.all(error < 3.0 * np.maximum(spread, cal.principal_point_std))


def test_the_pose_from_the_object_with_given_intrinsics():
    """Intrinsics from elsewhere, pose from the object: the true camera centre to 0.5 mm
    at 450 mm, and the reprojection at the noise level."""
    from experiments.stereo.calibration import pose_from_object

    X, x, camera = _object_view([-0.08, 0.05, 0.0, 0.0, 0.0], noise_px=0.3)
    given = Camera(camera.K, camera.dist, np.eye(3), np.zeros(3), camera.image_size)
    cal = pose_from_object(X, x, given)
    assert np.linalg.norm(cal.camera.center() - camera.center()) < 0.5
    assert cal.rms < 0.5 and np.all(cal.principal_point_std == 0)
