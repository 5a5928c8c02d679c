"""Real skin with the continuum energies (experiments/realskin/skincontinuum.py, docs/realskin.md).

On the measured extensometer data (``shared_data``): the continuum membrane fits the
DIC displacements better than the paper's energy on the same slab, pads and frames,
and its E t and nu are compared with the original authors' 2D neo-Hookean values. The
neo-Hookean fits (about 75 and 130 s) are marked slow.
"""

from __future__ import annotations

import copy

import casadi as ca
import numpy as np
import pytest

from experiments.realskin.setup import RealSkinSettings, build
from experiments.realskin.skincontinuum import fit_energy, paper_fit, summary
from experiments.realskin.skinstudy import AUTHORS

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
def test_neo_hookean_membrane_against_the_authors(shared_data, case):
    """The neo-Hookean membrane on its foundation (the base of the continuum loop):
    the keloid's E t lies in the authors' 0.07-0.14 N/mm (measured 0.096); healthy E t
    is about 3x below their 0.027-0.031 N/mm (measured 0.0096), the fixed edge ring's
    effect (docs/realskin.md, "Reproducing the authors").

    Without the foundation the membrane buckles out of its plane and its fit depends on
    Newton's path: when the nested solver moved to the shared one (2026-11-27) the
    keloid's nu went 0.414 -> 0.455 and the healthy fit no longer converged in 80
    evaluations, so that configuration is not tested (docs/realskin.md)."""
    from experiments.realskin.skincontinuum import BOUNDS, continuum_setup
    from experiments.realskin.stages import fit_stage
    from solvers.inverse.space import SkinParameterSpace

    membrane = continuum_setup(build(case, SETTINGS), SETTINGS.thickness_mm)
    space = SkinParameterSpace.build(("E", "nu"), membrane.start, BOUNDS)
    fit = fit_stage(membrane.model, membrane.cases, space, f"{case}, neo-Hookean", lambda *a: None)
    assert fit.success
    membrane_et = summary(case, fit, SETTINGS.thickness_mm)["E_times_thickness_n_per_mm"]
    low, high = AUTHORS[case]["E"]
    if case == "keloid":
        assert low <= membrane_et <= high
    else:
        assert 2.5 < 0.5 * (low + high) / membrane_et < 3.5


@pytest.mark.slow
@pytest.mark.parametrize("case", ["healthy", "keloid"])
def test_the_loop_on_the_membrane_finds_strain_stiffening(shared_data, case):
    """The real-skin loop on the neo-Hookean membrane (``stiffening_loop``, on its
    foundation): the score test ranks the exponential stiffening k1 first (ahead of the
    fibre family) and significant, its refit is accepted, and the stiffened membrane
    follows the force curve better without losing the DIC field (docs/realskin.md, "The
    loop on the continuum membrane"; measured force RMS 0.034 -> 0.0056 N and 0.61 ->
    0.021 N, displacement RMS 0.1134 -> 0.1131 mm and 0.356 -> 0.224 mm)."""
    from experiments.realskin.skincontinuum import stiffening_loop

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


def _membrane_with_cell_scaled(model, points: np.ndarray, factor: float):
    """A copy of a large-strain model whose energy density is ``factor`` times the
    model's at the Gauss points ``points`` (boolean, n_q): a cell made stiffer."""
    from symbolic.hyperelastic import NeoHookeanForce, NeoHookeanTangent

    scaled = copy.copy(model)
    gradient = model.gradient
    volume = np.where(points, factor, 1.0) * gradient.volume
    scaled.force = NeoHookeanForce(
        [p[:, model.free] for p in gradient.operators],
        volume,
        exponential=model.exponential,
        fibres=model.fibres,
    )
    scaled._tangent = NeoHookeanTangent(
        model.volume.collocation(gradient.points), gradient.operators, volume, model.free
    )
    return scaled


@pytest.mark.parametrize("energy", ["exponential", "fibres"])
def test_membrane_cell_columns_equal_the_sensitivity_of_a_stiffer_cell(energy):
    """The continuum map's column of a cell (eq. M2 of ``continuum_cells``) equals the
    central difference of the residual of a membrane whose energy in that cell is
    exp(+-h) times its own; and the cells' internal forces sum to the tissue's (the
    foundation excluded). On an exponential membrane on its foundation, pads pulled
    1 mm apart, no measured data."""
    from test_realskin import FIXED, MOVING, REGION, _marker_case

    from experiments.realskin.continuum_cells import ContinuumCells
    from experiments.realskin.scan import CellGrid, cell_columns
    from experiments.realskin.slab import Pads, slab_volume
    from experiments.realskin.stages import stage_solver
    from solvers.inverse.problem import PlanarProblem
    from solvers.inverse.space import SkinParameterSpace
    from symbolic.constraints import BoundaryConditions
    from symbolic.continuum_model import ENERGIES

    pads = Pads.build(REGION, MOVING, FIXED, per_side=3)
    names, x = ("E", "nu", "k1"), np.array([6.0, 0.3, 20.0])
    fibres = {"kf1": 40.0, "fibre_angle": 20.0} if energy == "fibres" else {}
    model = ENERGIES[energy](
        slab_volume(REGION, 2.0, (9, 5)),
        {**dict(zip(names, x)), **fibres},
        BoundaryConditions(fix_inner=False, fix_lateral=True),
        prescribed=pads.prescribed,
        support=1e-2,
    )
    case = _marker_case(model, pads, *_MARKERS, [-1.0, 0.0])
    bounds = {"E": (0.1, 1e4), "nu": (0.0, 0.49), "k1": (0.0, 1e4)}
    space = SkinParameterSpace.build(names, dict(zip(names, x)), bounds)

    def residual(m):
        solver = stage_solver(PlanarProblem(m, [case], space))
        r, _ = solver.evaluate(space.to_internal(x))
        return r, solver.states[0]

    r, state = residual(model)
    grid = CellGrid.of(model, REGION)
    cells = ContinuumCells.build(model, grid)
    problem = PlanarProblem(model, [case], space)
    columns = cell_columns(model, problem, x, [state], cells)

    delta = np.zeros_like(model.rest)
    delta[model.free] = state[: 3 * model.n_free].reshape(3, -1).T
    parts = cells.force_columns(model, names, x, delta).sum(axis=1)
    tissue = ENERGIES[energy](
        model.volume, {**dict(zip(names, x)), **fibres}, model.boundary, prescribed=pads.prescribed
    )
    whole = tissue.force(ca.DM(delta[model.free]), *tissue._energy_coefficients(model.values({})))
    assert np.allclose(parts, np.asarray(whole).T.ravel(), rtol=1e-9, atol=1e-12 * abs(parts).max())

    in_cell = grid.cell_of(model.gradient.points)
    h = 1e-5
    for cell in (2 * grid.shape[1] + 2, 4 * grid.shape[1] + 2):
        up, _ = residual(_membrane_with_cell_scaled(model, in_cell == cell, np.exp(h)))
        down, _ = residual(_membrane_with_cell_scaled(model, in_cell == cell, np.exp(-h)))
        difference = (up - down) / (2 * h)
        assert np.abs(columns[:, cell]).max() > 1e-4 * np.abs(r).max()
        assert np.allclose(
            columns[:, cell], difference, rtol=1e-5, atol=1e-7 * abs(difference).max()
        )


_MARKERS = (
    np.array([[45.0, 18.0], [55.0, 22.0], [40.0, 25.0], [60.0, 15.0]]),
    np.array([[0.1, -0.2, 0.0], [0.3, 0.0, 0.0], [0.2, 0.1, 0.0], [0.0, 0.1, 0.0]]),
)
