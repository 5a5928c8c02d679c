"""Acceptance checks of the stereo pipeline on real images (../shared/data).

OpenCV's stereo sample: 13 chessboard pairs (9 x 6 inner corners, lengths in
squares). MultiDIC's calibration cylinder: two views of a 20 x 14 grid of
dots with known 3D positions ``P3d`` [mm]. Every assertion is a threshold
on a number measured here; nothing is compared with stored outputs.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from experiments.stereo import holdout
from experiments.stereo import multidic as md
from experiments.stereo.chessboard import calibrate_stereo_images
from experiments.stereo.realcheck import (
    BOARD,
    SURFACE_GRID,
    board_neighbour_distances,
    index_check,
    read_image_list,
)
from experiments.stereo.surface import fit_surface, grid_parameters

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def board(shared_data):
    left, right = read_image_list(shared_data / "opencv-stereo")
    imgs_l = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in left]
    imgs_r = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in right]
    return len(left), calibrate_stereo_images(imgs_l, imgs_r, BOARD)


@pytest.fixture(scope="module")
def cylinder(shared_data):
    data = shared_data / "multidic-calibration-object"
    grid = md.load_grid(data)
    views = {name: md.load_view(data / f"{name}.jpg", grid) for name in ("201", "202")}
    return grid, views


@pytest.fixture(scope="module")
def stereo(cylinder):
    grid, views = cylinder
    pair = (views["201"], views["202"])
    return holdout.stereo_check(pair, (pair[0].camera, pair[1].camera), grid)


@pytest.fixture(scope="module")
def index_checks(cylinder):
    """``index_check`` of each view, by its name."""
    grid, views = cylinder
    return {name: index_check(view, grid) for name, view in views.items()}


# --- OpenCV stereo sample -------------------------------------------------------------


def test_every_chessboard_pair_is_detected(board):
    n_pairs, cal = board
    assert n_pairs == 13 and cal.used == list(range(13)) and not cal.skipped
    assert len(cal.left_corners) == len(cal.right_corners) == n_pairs
    cols = BOARD[0]
    for lc, rc in zip(cal.left_corners, cal.right_corners):
        assert lc.shape == rc.shape == (BOARD[0] * BOARD[1], 2)
        # Same corner order in both images: row directions agree.
        assert (lc[cols - 1] - lc[0]) @ (rc[cols - 1] - rc[0]) > 0


def test_a_pair_without_a_board_is_skipped_and_named(shared_data):
    """One unusable pair (a blank right image) costs that pair, not the calibration;
    too few usable pairs fail with one line that says how many were found."""
    left, right = read_image_list(shared_data / "opencv-stereo")
    imgs_l = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in left[:5]]
    imgs_r = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in right[:5]]
    imgs_r[2] = np.full_like(imgs_r[2], 200)
    cal = calibrate_stereo_images(imgs_l, imgs_r, BOARD)
    assert cal.used == [0, 1, 3, 4] and cal.skipped == {2: "no board in the right image"}
    assert len(cal.left_corners) == 4 and cal.left.rms < 0.5 and cal.right.rms < 0.5
    with pytest.raises(ValueError, match="only 2 of 5 pairs") as error:
        calibrate_stereo_images(imgs_l, [*imgs_r[:2], *[imgs_r[2]] * 3], BOARD)
    assert "\n" not in str(error.value)


def test_single_camera_rms_below_half_a_pixel(board):
    _, cal = board
    print(f"single-camera RMS: left {cal.left.rms:.3f} px, right {cal.right.rms:.3f} px")
    assert cal.left.rms < 0.5
    assert cal.right.rms < 0.5


def test_stereo_rms_below_0_65_px(board):
    _, cal = board
    print(f"stereo RMS {cal.stereo.rms:.3f} px, baseline {cal.stereo.baseline:.3f} squares")
    assert cal.stereo.rms < 0.65


def test_triangulated_neighbouring_corners_are_one_square_apart(board):
    _, cal = board
    per_pair = board_neighbour_distances(cal)
    d = np.concatenate(per_pair)
    pair_dev = np.array([abs(x.mean() - 1.0) for x in per_pair])
    rms_dev = np.sqrt(np.mean((d - 1.0) ** 2))
    print(
        f"neighbour distance: mean {d.mean():.4f} squares, worst pair mean off by "
        f"{100 * pair_dev.max():.2f}%, RMS deviation {100 * rms_dev:.2f}%, max single "
        f"{100 * np.abs(d - 1).max():.1f}%, {100 * np.mean(np.abs(d - 1) > 0.02):.1f}% of "
        "single distances off by more than 2%"
    )
    assert np.all(pair_dev < 0.02)
    assert rms_dev < 0.02


# --- MultiDIC calibration cylinder ----------------------------------------------------


def test_column_labels_follow_the_printed_numbers(cylinder):
    """j increases left to right (as the printed numbers) and i (height) upwards."""
    grid, views = cylinder
    for view in views.values():
        pix = view.pixel_grid(grid.shape[:2])
        du = np.nanmean(np.diff(pix[..., 0], axis=1))
        dv = np.nanmean(np.diff(pix[..., 1], axis=0))
        assert du > 0 and dv < 0
        assert view.reading.counts[view.reading.first_two_digit] == 2


@pytest.mark.parametrize(
    "name",
    [
        "201",
        pytest.param(
            "202",
            marks=pytest.mark.xfail(
                strict=True,
                reason="column j=1 faces camera 202 at 89.5 deg: its centre is in front of the "
                "silhouette but the dot is < 1 px wide and half behind it, so 20 of the 260 "
                "'visible' dots cannot be detected (236/260 = 90.8%); see docs/stereo.md",
            ),
        ),
    ],
)
def test_visible_dots_detected_and_correctly_indexed(index_checks, name):
    r = index_checks[name]
    print(
        f"{name}: {r['visible_labelled_ok']}/{r['visible']} visible dots detected and "
        f"correctly indexed ({100 * r['visible_frac']:.1f}%)"
    )
    assert r["visible_frac"] >= 0.95


@pytest.mark.parametrize("name", ["201", "202"])
def test_wholly_visible_dots_detected_and_correctly_indexed(index_checks, name):
    """Same count, for dots that face the camera across their whole width."""
    r = index_checks[name]
    print(
        f"{name}: {100 * r['fully_visible_frac']:.1f}% of {r['fully_visible']} dots facing "
        f"the camera across their whole width (dot/pitch {r['dot_fraction']:.3f})"
    )
    assert r["fully_visible_frac"] >= 0.95


@pytest.mark.parametrize("name", ["201", "202"])
def test_no_dot_is_misindexed(index_checks, name):
    """Every label agrees with a calibration that never saw that dot."""
    r = index_checks[name]
    assert r["labelled_not_visible"] == 0
    assert r["holdout_reproj_ok_frac"] == 1.0


def test_triangulated_dots_match_p3d(stereo):
    err = np.linalg.norm(stereo.errors, axis=1)
    print(
        f"MultiDIC: {stereo.mask.sum()} dots, RMS 3D error {stereo.rms:.4f} mm "
        f"(max {err.max():.3f} mm); MultiDIC's authors report about 0.06 mm"
    )
    assert stereo.mask.sum() >= 150
    assert stereo.rms <= 0.1


def test_holdout_triangulation(cylinder):
    """Interleaved halves: every held-out dot has calibrated neighbours (near in-sample)."""
    grid, views = cylinder
    hold = holdout.holdout_check((views["201"], views["202"]), grid)
    print(
        f"hold-out (calibrate on one checkerboard half, triangulate the other): RMS 3D "
        f"error {hold['rms']:.4f} mm over {hold['n']} dots, folds "
        f"{[round(x, 4) for x in hold['fold_rms']]}"
    )
    assert hold["n"] >= 150
    assert hold["rms"] <= 0.1


@pytest.fixture(scope="module")
def reports(cylinder):
    grid, views = cylinder
    return {name: md.calibration_report(view, grid) for name, view in views.items()}


@pytest.mark.parametrize("name", ["201", "202"])
def test_principal_point_error_matches_its_spatial_spread(reports, name):
    """The reported (block jackknife) standard error of the principal point agrees with
    half the difference between the estimates from the two ends of the cylinder (its
    expected size for a consistent error); the covariance's is several times too small,
    the residuals being correlated in space."""
    r = reports[name]
    std, half = np.array(r["principal_point_std_px"]), np.array(r["principal_point_half_spread_px"])
    cov = np.array(r["principal_point_cov_std_px"])
    print(f"{name}: model {r['model']}, std {std.round(1)}, half spread {half.round(1)}, cov {cov}")
    assert np.all(half < 3.0 * std) and np.all(std < 3.0 * np.maximum(half, 1.0))
    assert np.max(std / cov) > 4.0
    assert r["warning"] is None and std.max() <= 25.0
    # the well-conditioned models: not the thin-prism model whose principal point moved
    assert "prism" not in r["model"]


def test_spatial_holdout_triangulation(cylinder, reports):
    """Calibrated without one of 12 blocks of dots at a time, triangulated there."""
    from experiments.stereo.calibration import DISTORTION_MODELS

    grid, views = cylinder
    pair = (views["201"], views["202"])
    flags = tuple(DISTORTION_MODELS[reports[n]["model"]] for n in ("201", "202"))
    spatial = holdout.spatial_holdout_check(pair, grid, flags)
    in_sample = holdout.stereo_check(pair, (pair[0].camera, pair[1].camera), grid).rms
    print(
        f"3D RMS: in-sample {in_sample:.4f} mm, spatial blocks {spatial['blocks_rms']:.4f} "
        f"mm, one end from the other {spatial['ends_rms']:.4f} mm"
    )
    assert spatial["n"] >= 150 and spatial["blocks_rms"] <= 0.1
    assert in_sample < spatial["blocks_rms"] < spatial["ends_rms"]


def test_triangulation_covariance_matches_errors(stereo):
    """The Gauss-Newton covariance predicts the size of the real 3D errors."""
    tri = stereo.triangulation
    predicted = np.sqrt(np.mean(np.trace(tri.covariances, axis1=1, axis2=2)))
    ratio = stereo.rms / predicted
    print(f"actual/predicted 3D RMS = {ratio:.2f}")
    assert 0.5 < ratio < 2.0


def test_spline_surface_through_triangulated_dots(stereo):
    ij = np.argwhere(stereo.mask)
    surf = fit_surface(stereo.triangulation.points, grid_parameters(ij), SURFACE_GRID)
    print(f"bicubic {SURFACE_GRID} surface: residual RMS {surf.rms:.4f} mm, max {surf.max:.3f} mm")
    assert surf.rms < 0.1
