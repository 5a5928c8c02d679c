"""The keloid checks (experiments/realskin/checks.py): data variants are built right.

The checks' outcomes (where the loop puts its region) are measurements reported in
docs/realskin.md, not asserted here.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import exit_code_and_stderr

from experiments.realskin.checks import main


@pytest.mark.parametrize("argv", [["--check", "nope"], ["--check", ","], ["--bad"]])
def test_bad_command_line_is_one_line_and_exit_2(argv, capsys):
    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err


@pytest.fixture(scope="module")
def keloid(shared_data):
    from experiments.realskin.setup import RealSkinSettings, build

    return build("keloid", RealSkinSettings())


def test_dropping_points_rebuilds_weight_and_cases(keloid):
    from experiments.realskin.cases import force_weight
    from experiments.realskin.checks import near_pads, with_points

    near = near_pads(keloid, 3.0)
    x = keloid.data.reference_mm[:, 0]
    moving, fixed = keloid.pad_rects
    assert np.all((x[~near] >= moving.x1 + 3.0) & (x[~near] <= fixed.x0 - 3.0))
    assert 0 < near.sum() < 0.3 * near.size
    fewer = with_points(keloid, ~near)
    assert len(fewer.cases) == len(keloid.cases)
    assert fewer.weight == pytest.approx(force_weight(fewer.data))
    for case, disp in zip(fewer.cases, fewer.data.displacement_mm):
        assert case.rows.shape[0] == len(disp) == (~near).sum()
    assert len(keloid.data.reference_mm) == near.size  # the original is untouched


def test_fixed_pad_slip_is_prescribed_and_grows_with_the_pull(keloid):
    from experiments.realskin.checks import fixed_pad_slip

    setup, slip = fixed_pad_slip(keloid)
    n = keloid.pads.n_moving
    for case, original, value in zip(setup.cases, keloid.cases, slip):
        np.testing.assert_array_equal(case.prescribed[n:, 0], value)
        np.testing.assert_array_equal(case.prescribed[:n], original.prescribed[:n])
        assert np.all(original.prescribed[n:] == 0.0)
    # the measured skin beside the fixed pad follows the pull (-x), more with more travel
    assert np.all(slip < 0) and np.all(np.diff(slip) < 0)
