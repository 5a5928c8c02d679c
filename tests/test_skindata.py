"""Tests of experiments.realskin.data: synthetic checks of each rule, then the real data."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.realskin.data import force_at_travel, load_case
from experiments.realskin.dicnoise import spatial_noise_per_frame, spurious_points
from experiments.realskin.geometry import geometry_from_geo, points_in_polygon

EXPECTED = {  # case: (frames, points, force samples, pad gap [mm], max |F| [N], at ux [mm])
    "healthy": (50, 537, 827, 32.0, 0.31, -8.4),
    "keloid": (105, 630, 412, 40.727, 2.5, -4.1),
}

GEO = """
a = 2; b = a*3 - 1;   // b = 5
/* block comment ; with a semicolon */
Point(1) = {0, 0, 0, 1}; Point(2) = {10, 0, 0, 1}; Point(3) = {10, b, 0, 1};
Point(4) = {0, b, 0, 1}; Point(5) = {2, 2, 0}; Point(6) = {3, 2, 0}; Point(7) = {3, 3, 0};
Point(8) = {2, 3, 0}; Point(9) = {7, 2, 0}; Point(10) = {8, 2, 0}; Point(11) = {8, 3, 0};
Point(12) = {7, 3, 0}; Point(13) = {4, 2.5, 0}; Point(14) = {5, 2 - 1^2, 0};
Point(15) = {6, 2.5, 0}; Point(16) = {5, 4, 0}; Point(17) = {99, 99, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Line(5) = {5, 6}; Line(6) = {6, 7}; Line(7) = {7, 8}; Line(8) = {8, 5};
Line(9) = {9, 10}; Line(10) = {10, 11}; Line(11) = {11, 12}; Line(12) = {12, 9};
Spline(13) = {13, 14, 15}; Spline(14) = {13, 16, 15};
Recursive Delete { Point{17}; }
Curve Loop(1) = {13, -14};
Plane Surface(1) = {1};
Physical Surface("keloid", 1) = {1};
Physical Line("boundary_bottom", 1) = {1, 2, 3, 4};
Physical Line("moving_pad", 2) = {5, 6, 7, 8};
Physical Line("fixed_pad", 3) = {9, 10, 11, 12};
"""


# ------------------------------------------------------------------ synthetic checks
def test_geo_parser_evaluates_variables_and_chains_signed_curves():
    geom = geometry_from_geo(GEO)
    assert geom.variables == {"a": 2.0, "b": 5.0}
    assert (geom.region.width, geom.region.height) == (10.0, 5.0)
    assert (geom.pad_moving.x0, geom.pad_moving.x1, geom.pad_fixed.x0) == (2.0, 3.0, 7.0)
    assert geom.pad_gap_mm == pytest.approx(4.0)
    # spline 13 forward, spline 14 reversed: 13 -> 14 -> 15 -> 16 (back to 13)
    np.testing.assert_allclose(geom.keloid, [[4, 2.5], [5, 1], [6, 2.5], [5, 4]])


def test_points_in_polygon():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    mask = points_in_polygon(np.array([[1, 1], [3, 1], [1, -0.5], [1.9, 1.9]]), square)
    assert mask.tolist() == [True, False, False, True]


def test_force_sync_drops_reversals_and_relaxation_dips():
    ux = -np.array([0.0, 1.0, 2.0, 1.5, 3.0, 4.0])  # travel reverses at sample 3
    fx = -np.array([0.0, 1.0, 2.0, 9.0, 1.8, 4.0])  # dip at 3.0 mm after 2.0 N
    query = -np.array([0.0, 0.5, 2.0, 2.5, 3.0, 4.0, 4.5, -0.1])
    out = -force_at_travel(ux, fx, query)
    np.testing.assert_allclose(out[:6], [0.0, 0.5, 1.9, 1.9, 1.9, 4.0])  # dip pooled: 1.9
    assert np.isnan(out[6:]).all()  # outside the record: no extrapolation
    assert np.all(np.diff(out[:6]) >= 0)


def _grid(nx=30, ny=12, h=0.5):
    x, y = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h)
    return np.c_[x.ravel(), y.ravel()]


def test_noise_estimate_recovers_known_noise_on_smooth_field():
    rng = np.random.default_rng(1)
    ref = _grid()
    smooth = np.stack([0.05 * t * np.c_[ref[:, 0], 0.3 * ref[:, 1]] for t in range(8)])
    sigma = 0.01
    noise = spatial_noise_per_frame(ref, smooth + rng.normal(0, sigma, smooth.shape))
    assert np.median(noise) == pytest.approx(sigma, rel=0.15)


def test_spurious_rule_flags_an_injected_glitch_and_little_else():
    rng = np.random.default_rng(2)
    ref = _grid()
    disp = np.stack([0.1 * t * np.c_[np.sin(ref[:, 0] / 5), ref[:, 1] / 10] for t in range(10)])
    disp += rng.normal(0, 0.005, disp.shape)
    disp[6, 100, 0] += 0.2  # one point jumps by 40 sigma in one frame
    disp[:, 200, 1] = np.nan  # one point without valid values
    flagged = spurious_points(ref, disp)
    assert flagged[100] and flagged[200]
    assert flagged.sum() <= 4


# -------------------------------------------------------------------------- real data
@pytest.fixture(scope="module", params=list(EXPECTED))
def case(request, shared_data):
    return load_case(request.param, shared_data)


@pytest.mark.realdata
def test_counts_match_readme_and_files(case, shared_data):
    frames, points, samples = EXPECTED[case.name][:3]
    base = shared_data / "skin-extensometer" / case.name
    dic_files = sorted((base / "displacement").glob("xt_dic_*.out"))
    assert case.dic_positions_mm.shape == (frames, points, 2) == (len(dic_files), points, 2)
    for path in (dic_files[0], dic_files[-1]):
        assert len(path.read_text().split("\n")) - 1 == points
    assert case.pad_moving_mm.shape == case.pad_fixed_mm.shape == (frames, 2)
    assert case.force_ux_mm.shape == case.force_fx_n.shape == (samples,)


@pytest.mark.realdata
def test_values_agree_with_raw_lines(case, shared_data):
    base = shared_data / "skin-extensometer" / case.name
    line = (base / "displacement" / "xt_dic_0017.out").read_text().splitlines()[99]
    assert case.dic_positions_mm[17, 99].tolist() == [float(v) for v in line.split()]
    force_line = (base / "reactionforce" / "fx_pad_mov.out").read_text().splitlines()[200]
    assert case.force_fx_n[200] == float(force_line)


@pytest.mark.realdata
def test_force_record_peak(case):
    peak_n, at_mm = EXPECTED[case.name][4:]
    i = int(np.argmin(case.force_fx_n))
    assert -case.force_fx_n[i] == pytest.approx(peak_n, rel=0.05)
    assert case.force_ux_mm[i] == pytest.approx(at_mm, abs=0.1)


@pytest.mark.realdata
def test_healthy_skin_stiffens(shared_data):
    c = load_case("healthy", shared_data)
    travel, force = -c.force_ux_mm, -c.force_fx_n
    early = travel <= 0.2 * travel.max()
    secant_early = np.median(force[early][1:] / travel[early][1:])
    secant_late = force[-1] / travel[-1]
    assert secant_late > 1.3 * secant_early


@pytest.mark.realdata
def test_pad_files_and_frame_sync(case):
    assert case.pad_moving_mm[0].tolist() == [0.0, 0.0]
    assert np.ptp(case.pad_fixed_mm, axis=0).max() < 1e-9  # the fixed pad does not move
    assert np.all(np.diff(case.pad_moving_mm[:, 0]) < 0)  # moving pad travels along -x
    valid = case.force_valid
    beyond = -case.pad_displacement_mm[:, 0] > -case.force_ux_mm.min()
    assert np.array_equal(~valid, beyond)  # NaN exactly where the record ends
    assert abs(case.force_at_frame_n[0]) < 1e-3  # record starts near zero (sensor noise)
    assert np.all(np.diff(case.force_at_frame_n[valid]) <= 0)
    # the synchronised force stays within the raw samples that bracket each frame
    travel, raw = -case.force_ux_mm, case.force_fx_n
    for f in np.flatnonzero(valid)[1:]:
        j = np.searchsorted(travel, -case.pad_displacement_mm[f, 0])
        lo, hi = sorted((raw[j - 1], raw[j]))
        assert lo - 2e-3 <= case.force_at_frame_n[f] <= hi + 2e-3


@pytest.mark.realdata
def test_geometry_and_frames_agree(case):
    g = case.geometry
    assert (g.pad_moving.width, g.pad_moving.height) == pytest.approx((8.0, 8.0))
    assert (g.pad_fixed.width, g.pad_fixed.height) == pytest.approx((8.0, 8.0))
    assert (g.region.width, g.region.height) == pytest.approx((100.0, 50.0))
    assert g.pad_gap_mm == pytest.approx(EXPECTED[case.name][3], abs=1e-3)
    ref = case.dic_reference_model_mm
    assert g.region.contains(ref).all()
    assert not (g.pad_moving.contains(ref) | g.pad_fixed.contains(ref)).any()
    assert np.all((ref[:, 0] >= g.pad_moving.x1 - 1e-3) & (ref[:, 0] <= g.pad_fixed.x0 + 1e-3))


@pytest.mark.realdata
def test_keloid_dic_edge_moves_with_the_pad(shared_data):
    c = load_case("keloid", shared_data)
    edge = np.abs(c.dic_reference_mm[:, 0]) < 1e-6  # DIC column on the moving pad's edge
    far = np.abs(c.dic_reference_mm[:, 0] - c.pad_fixed_mm[0, 0]) < 1e-6  # fixed pad's edge
    u_last = c.dic_displacement_mm[-1]
    assert np.median(u_last[edge, 0]) == pytest.approx(c.pad_displacement_mm[-1, 0], abs=0.1)
    assert abs(np.median(u_last[far, 0])) < 0.1


@pytest.mark.realdata
def test_keloid_outline(shared_data):
    assert load_case("healthy", shared_data).geometry.keloid is None
    g = load_case("keloid", shared_data).geometry
    poly = g.keloid
    assert poly.ndim == 2 and len(poly) > 10
    assert len(np.unique(poly, axis=0)) == len(poly)  # simple chain, closure implicit
    x, y = poly.T
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert area > 100.0
    pads_mid = np.array([0.5 * (g.pad_moving.x1 + g.pad_fixed.x0), 20.0])
    assert points_in_polygon(pads_mid[None], poly)[0]
    assert g.pad_moving.x1 < poly.mean(axis=0)[0] < g.pad_fixed.x0
    assert not (g.pad_moving.contains(poly) | g.pad_fixed.contains(poly)).any()


@pytest.mark.realdata
def test_spurious_rule_discards_few_points(case):
    assert 0.0 <= case.spurious.mean() < 0.05


@pytest.mark.realdata
def test_noise_is_small_against_displacement(case):
    from experiments.realskin.data import dic_noise_mm

    noise = dic_noise_mm(case)
    typical = np.median(np.linalg.norm(case.dic_displacement_mm[-1, ~case.spurious], axis=1))
    assert 0.0 < noise < 0.05 * typical
    assert 0.0 < dic_noise_mm(case, "temporal") < noise


@pytest.mark.realdata
def test_frames_for_fit(case):
    frames = case.frames_for_fit(8)
    assert len(frames) == 8 and np.all(np.diff(frames) > 0) and frames[0] > 0
    assert case.force_valid[frames].all()
    travel = -case.pad_displacement_mm[:, 0]
    assert travel[frames[-1]] == pytest.approx(travel[case.force_valid].max())
    fit = case.fit_subset(8)
    assert fit["displacement_mm"].shape == (8, int((~case.spurious).sum()), 2)
    assert np.all(np.isfinite(fit["force_n"])) and np.all(fit["force_n"] < 0)


def test_load_case_errors(tmp_path):
    with pytest.raises(ValueError, match="unknown case"):
        load_case("scar")
    with pytest.raises(ValueError, match="DVS_SHARED_DATA"):
        load_case("healthy", tmp_path)
