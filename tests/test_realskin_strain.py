"""Model-free axial strain along the pull (experiments/realskin/strain.py)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import exit_code_and_stderr

from experiments.realskin.strain import axial_strain, main


@pytest.mark.parametrize("window", [1, 2, 5])
def test_axial_strain_of_a_linear_field_is_its_slope(window):
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.uniform(0.5, 1.0, 20))
    mid, strain = axial_strain(x, 0.07 * x - 1.3, window)
    np.testing.assert_allclose(strain, 0.07, rtol=1e-12)
    np.testing.assert_allclose(mid, 0.5 * (x[window:] + x[:-window]))


def test_bad_window_is_refused():
    with pytest.raises(ValueError, match="window"):
        axial_strain(np.arange(3.0), np.zeros(3), 3)


@pytest.mark.parametrize("argv", [["--frames", "a"], ["--frames", "999"], ["--case", "x"]])
def test_bad_command_line_is_one_line_and_exit_2(argv, capsys, shared_data):
    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err


def test_keloid_strain_is_not_that_of_one_material(shared_data):
    """The measured keloid strip: no strain at rest; under load the segment at the fixed
    pad strains more than 3x the left lobe (0.151 against 0.041 at frame 84), although
    at 0.7 mm of travel the two differ by less than 1.5x (0.017, 0.013)."""
    from experiments.realskin.data import load_case
    from experiments.realskin.strain import segment_strain

    case = load_case("keloid")
    np.testing.assert_allclose(segment_strain(case, 0), 0.0, atol=1e-12)
    early, late = segment_strain(case, 14), segment_strain(case, 84)
    assert np.all(early > 0) and np.all(late > early)
    assert early[-1] < 1.5 * early[0]
    assert late[-1] > 3.0 * late[0]
