"""Real skin with the continuum energies (experiments/realskin/continuum.py, docs/realskin.md).

On the measured extensometer data (``shared_data``): the continuum membrane fits the
DIC displacements better than the paper's energy on the same slab, pads and frames,
and its E t and nu are compared with the original authors' 2D neo-Hookean values. The
neo-Hookean fits (about 75 and 130 s) are marked slow.
"""

from __future__ import annotations

import pytest

from experiments.realskin.continuum import fit_energy, paper_fit, summary
from experiments.realskin.setup import RealSkinSettings, build
from experiments.realskin.study import AUTHORS

SETTINGS = RealSkinSettings(boundary="lateral")


def test_keloid_linear_continuum_beats_the_paper_energy_and_meets_the_authors(shared_data):
    """Measured: displacement RMS 0.520 -> 0.354 mm; E t 0.107 N/mm in the authors'
    0.07-0.14; nu at its bound 0.49 (the linear membrane cannot stiffen, so it stiffens
    laterally instead: the neo-Hookean fit gives 0.41, test below)."""
    setup = build("keloid", SETTINGS)
    paper = paper_fit(setup, SETTINGS.bounds, log=lambda *a: None)
    continuum = fit_energy(setup, "linear-elastic", SETTINGS.thickness_mm, log=lambda *a: None)
    assert continuum.rms_displacement_mm < 0.8 * paper.rms_displacement_mm
    row = summary("keloid", continuum, SETTINGS.thickness_mm)
    low, high = AUTHORS["keloid"]["E"]
    assert low <= row["E_times_thickness_n_per_mm"] <= high


@pytest.mark.slow
@pytest.mark.parametrize("case", ["healthy", "keloid"])
def test_neo_hookean_poisson_ratio_matches_the_authors(shared_data, case):
    """nu of the neo-Hookean membrane lies in the authors' range for both cases
    (measured 0.163 and 0.414); E t does for the keloid (0.124 N/mm) and is ~3x below
    it for healthy skin (0.010 against 0.027-0.031 N/mm; docs/realskin.md)."""
    setup = build(case, SETTINGS)
    fit = fit_energy(setup, "neo-hookean", SETTINGS.thickness_mm, log=lambda *a: None)
    assert fit.success
    row = summary(case, fit, SETTINGS.thickness_mm)
    low, high = AUTHORS[case]["nu"]
    assert low <= row["parameters"]["nu"]["value"] <= high


@pytest.mark.slow
@pytest.mark.parametrize("case", ["healthy", "keloid"])
def test_the_loop_on_the_membrane_finds_strain_stiffening(shared_data, case):
    """The real-skin loop on the neo-Hookean membrane (``stiffening_loop``, on its
    foundation): the score test ranks the exponential stiffening k1 first and
    significant, its refit is accepted, and the stiffened membrane follows the force
    curve better without losing the DIC field (docs/realskin.md, "The loop on the
    continuum membrane"; measured force RMS 0.034 -> 0.0056 N and 0.61 -> 0.023 N,
    displacement RMS 0.1134 -> 0.1131 mm and 0.356 -> 0.253 mm)."""
    from experiments.realskin.continuum import stiffening_loop

    result = stiffening_loop(build(case, SETTINGS), SETTINGS, SETTINGS.thickness_mm, log=print)
    scores = result["rounds"][0]["scores"]
    assert max(scores, key=lambda name: scores[name].statistic) == "k1"
    assert scores["k1"].p_value < 1e-3
    assert result["rounds"][0]["chosen"] == "k1"
    before, after = result["stages"][0], result["stages"][-1]
    print(case, "force RMS", before.rms_force_n, "->", after.rms_force_n)
    print(case, "displacement RMS", before.rms_displacement_mm, "->", after.rms_displacement_mm)
    assert after.rms_force_n < 0.5 * before.rms_force_n
    assert after.rms_displacement_mm < 1.01 * before.rms_displacement_mm
