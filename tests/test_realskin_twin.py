"""The synthetic keloid twin (experiments/realskin/twin.py).

The slow test builds one twin (ratio 3.5, seed 0) and checks what must hold whatever
the scan finds: the truth reproduces its own clean data, the homogeneous linear model
cannot, the twin's forces have the real data's scale, the noise has the stated level,
and the reported metrics are well-formed. It does NOT check the localisation outcome.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import exit_code_and_stderr

from experiments.realskin.twin import FORCE_NOISE_N, main


@pytest.mark.parametrize(
    "argv",
    [
        ["--ratios", "abc"],
        ["--ratios", "-1"],
        ["--seeds", "1.5"],
        ["--seeds", ""],
        ["--k0", "-1"],
        ["--k0", "nan"],
        ["--nope"],
    ],
)
def test_bad_command_line_is_one_line_and_exit_2(argv, capsys):
    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.slow
def test_keloid_twin_is_consistent(shared_data):
    from experiments.realskin.setup import RealSkinSettings, build
    from experiments.realskin.stages import fit_stage
    from experiments.realskin.twin import (
        TRUTH_NAMES,
        base_parameters,
        cost_at,
        make_twin,
        run_twin,
        truth_model,
    )
    from solvers.inverse.space import SkinParameterSpace

    settings = RealSkinSettings()
    real = build("keloid", settings)
    truth = truth_model(real, 3.5, settings)
    params = base_parameters(real, truth, settings)
    x = np.array([params["alpha_u"], params["alpha_w"], 3.5])
    noisy, clean = make_twin(real, truth, x, 0, real.noise_mm)

    # noise-free: the truth fits its own data exactly, the homogeneous linear model cannot
    exact = cost_at(truth, clean.cases, TRUTH_NAMES, x, settings)
    space = SkinParameterSpace.build(real.base_names, real.start, settings.bounds)
    linear = fit_stage(real.model, clean.cases, space, "linear", log=lambda *_: None)
    assert linear.cost > 0.1 and exact < 1e-8 * linear.cost

    # the twin's forces have the real data's sign and scale (factor 2)
    assert np.all(clean.data.force_n < 0)
    scale = np.sqrt(np.mean(clean.data.force_n**2) / np.mean(real.data.force_n**2))
    assert 0.5 < scale < 2.0

    # the noise has the stated level: the truth's cost on the noisy twin is the noise's
    n_u = sum(d.size for d in noisy.data.displacement_mm if d is not None)
    n_f = noisy.data.force_n.size
    expected = 0.5 * (n_u * real.noise_mm**2 + n_f * (noisy.weight * FORCE_NOISE_N) ** 2)
    assert cost_at(truth, noisy.cases, TRUTH_NAMES, x, settings) == pytest.approx(expected, rel=0.2)

    # a stiffening truth (k0 > 0) is nonlinear and also reproduces its own clean data
    stiff = truth_model(real, 3.5, settings, k0=3.3)
    assert not stiff.is_linear(TRUTH_NAMES) and real.model.parameters["k0"] == 0.0
    _, clean_k0 = make_twin(real, stiff, x, 0, real.noise_mm)
    assert cost_at(stiff, clean_k0.cases, TRUTH_NAMES, x, settings) < 1e-8 * linear.cost

    # one run of the pipeline: well-formed outputs, whatever it localises
    run = run_twin(3.5, 0, settings, real=real)
    assert run["truth"]["region_ratio"] == 3.5
    assert 0.5 < run["force_scale"] < 2.0
    region = real.case.geometry.region
    for entry in (run["first_scan"], run["found"]):
        if entry is None:
            continue
        assert 0.0 <= entry["p_value"] <= 1.0
        x0, x1, y0, y1 = entry["rect_mm"]
        assert region.x0 < x0 < x1 < region.x1 and region.y0 < y0 < y1 < region.y1
        overlap = entry["overlap"]
        for key in ("inside_fraction", "chance", "iou", "recall"):
            assert 0.0 <= overlap[key] <= 1.0
        assert overlap["iou"] <= min(overlap["inside_fraction"], overlap["recall"]) + 1e-12
        assert isinstance(overlap["centroid_inside"], bool)
    assert run["first_scan"] is not None  # round 1 always scans
    assert 0.0 < run["best_possible"]["iou"] <= 1.0
