"""The ``stiffer_region`` effect (eq. R1) and its family score test (eq. S1).

Off-at-zero and derivative checks run with every effect in tests/test_effects.py (on the
effect's default rectangle); here what only this effect has: cells that partition the
skin, one-parameter columns that the family's per-cell columns add up to, and the loop
on scikit-fem data of another discretisation with a stiff disc planted or not (on a
continuum volume step 0 did not check, so with its refinement survival: the bare loop
named the region on 2 of 8 null seeds, standing in for the coarse volume's error).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

from experiments.diagnosis.diagnose import BASE_NAMES, base_settings, diagnose_dataset
from experiments.phantom.designs import DIAGNOSIS_CONTACTS, DIAGNOSIS_TILT_DEG
from experiments.phantom.fe import ReferenceSlab, SlabSolution, design_cases, reference_dataset
from experiments.phantom.simulate import SimulationSettings, simulate_with_effects
from experiments.problem.fitting import ENERGY_NAMES, FitSettings, build_problem, dataset_loads
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from solvers.diagnosis.record import DiagnosisSettings
from solvers.diagnosis.stats import candidate_jacobian, family_columns, score_test
from symbolic.effects.library import ALL_EFFECT_NAMES, EFFECT_NAMES, effect_library
from symbolic.effects.region import CellGrid, CellStiffness, StiffnessRegion

SIGMA = 0.02
DISC = (6.0, -5.0, 12.0, 3.0)
"""The planted inclusion: a disc through the slab at (6, -5) mm, 12 mm across, E x 3."""


@pytest.fixture(scope="module")
def paper():
    """The phantom on the diagnosis design, the paper's energy, its base fit."""
    dataset = simulate_with_effects(
        {}, seed=5, contacts=DIAGNOSIS_CONTACTS, tilt_deg=DIAGNOSIS_TILT_DEG
    )
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), [], sigma=SIGMA)
    return problem, fit(problem)


def _fe_data(inclusion):
    """scikit-fem data (P2 tetrahedra, 60 x 60 mm clamped 10 mm beyond the markers, 4 mm
    probes) of the diagnosis design, 9 x 9 markers, noise 0.02 mm."""
    slab = ReferenceSlab(elements=(12, 12, 2), inclusion=inclusion)
    forces, contacts = design_cases("diagnosis", slab)
    measurement = SimulationSettings(noise_mm=SIGMA, seed=3)
    return reference_dataset(
        slab, forces, contacts, 4.0, (9, 9), measurement, solver=SlabSolution(slab)
    )


BASE = base_settings(energy="linear-elastic")
"""The continuum on a volume of the data's grid (9 x 9 x 2, over the markers): a grid step 0
did not check, so an effect must also survive its refinement (``Survival``)."""


@pytest.fixture(scope="module")
def planted():
    return _fe_data(DISC)


@pytest.fixture(scope="module")
def null():
    return _fe_data(None)


def _overlap(model, rect, disc, n: int = 300) -> float:
    """|R n D| / |R u D| on the rest skin (physical area): R the rectangle (u0, u1, v0, v1),
    D the disc (x, y, diameter)."""
    u = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(u, u, indexing="ij")
    params = np.column_stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    xyz = model.volume.evaluate(params)
    du, dv = (model.volume.evaluate(params, d) for d in ((1, 0, 0), (0, 1, 0)))
    area = np.linalg.norm(np.cross(du, dv), axis=1)
    u0, u1, v0, v1 = rect
    in_r = (params[:, 0] >= u0) & (params[:, 0] < u1) & (params[:, 1] >= v0) & (params[:, 1] < v1)
    in_d = np.hypot(xyz[:, 0] - disc[0], xyz[:, 1] - disc[1]) <= disc[2] / 2
    return float(area[in_r & in_d].sum() / area[in_r | in_d].sum())


def test_the_region_is_opt_in_and_one_sided():
    assert "stiffer_region" not in EFFECT_NAMES and "stiffer_region" in ALL_EFFECT_NAMES
    assert "stiffer_region" not in effect_library()
    assert DiagnosisSettings(candidates=("stiffer_region",)).candidates == ("stiffer_region",)
    effect = StiffnessRegion()
    assert (effect.lower, effect.upper, effect.dim) == ((0.0,), (99.0,), 1)
    with pytest.raises(ValueError, match="rectangle"):
        effect.choose((0.5, 0.4, 0.1, 0.2))


def test_box_sums_and_forms_are_those_of_the_masks():
    """The cumulative sums give w_b^T g and w_b^T G w_b of every box's 0/1 mask."""
    grid = CellGrid(np.linspace(0.0, 1.0, 7), np.linspace(0.0, 1.0, 6))
    boxes = grid.boxes()
    assert len(boxes) == 10 * 6  # C(5, 2) x C(4, 2): inside the edge cells
    assert boxes[:, 0].min() == 1 and boxes[:, 1].max() == 5 and boxes[:, 3].max() == 4
    rng = np.random.default_rng(0)
    g = rng.normal(size=grid.n_cells)
    a = rng.normal(size=(50, grid.n_cells))
    masks = np.array([grid.mask(b) for b in boxes])
    np.testing.assert_allclose(grid.box_sums(g, boxes), masks @ g, rtol=1e-12, atol=1e-12)
    expected = np.einsum("bi,ij,bj->b", masks, a.T @ a, masks)
    np.testing.assert_allclose(grid.box_forms(a.T @ a, boxes), expected, rtol=1e-11)


@pytest.mark.parametrize("energy", ["dnurbs", "linear-elastic"])
def test_the_cells_partition_the_skin_and_a_region_is_linear_in_s(energy):
    """Eq. (R1): the cells' terms add up to a rectangle's and, over all cells, to the base
    stiffness; K(s) - K = s K_R, zero at s = 0."""
    dataset = simulate_with_effects({}, seed=4)
    names = BASE_NAMES if energy == "dnurbs" else ENERGY_NAMES[energy]
    model = build_problem(dataset, FitSettings(names=names, energy=energy)).model
    values = dict(model.parameters)
    theta = ca.MX.sym("theta")
    region = StiffnessRegion()
    grid = region.family(model).grid
    box = (1, 3, 2, 4)
    region.choose(grid.rect(box))
    k_region = ca.Function("K", [theta], [region.stiffness(model, values, theta)])
    cells = CellStiffness(grid)
    weights = ca.MX.sym("w", cells.dim)
    k_cells = ca.Function("K", [weights], [cells.stiffness(model, values, weights)])
    summed = sp.csc_matrix(k_cells(grid.mask(box)).sparse())
    unit = sp.csc_matrix(k_region(1.0).sparse())
    assert abs(summed - unit).max() <= 1e-12 * abs(unit).max()
    for s in (0.0, 0.5, 7.0):
        difference = sp.csc_matrix(k_region(s).sparse()) - s * unit
        assert abs(difference).max() <= 1e-12 * s * abs(unit).max()
    if energy == "dnurbs":
        base = sp.kron(sp.identity(3), model.free_block(model.stiffness_matrix()))
    else:
        base = model.stiffness_matrix()
    whole = sp.csc_matrix(k_cells(np.ones(cells.dim)).sparse())
    assert abs(whole - base).max() <= 1e-12 * abs(base).max()


@pytest.mark.parametrize("setting", ["paper", "planted"])
def test_a_boxs_family_column_is_the_one_parameter_sensitivity(request, setting):
    """The sum of a box's cell columns equals d rho / d s of ``stiffer_region`` on that box
    (its own linearisation); the family's statistic of the box it chooses is the ordinary
    score test's of that box, and its log p that plus log(1/2) and log(boxes)."""
    if setting == "paper":
        problem, base_fit = request.getfixturevalue("paper")
    else:
        data = request.getfixturevalue("planted")
        base = build_problem(data, BASE)
        problem = ExtendedProblem(base, dataset_loads(data, base.model.volume), [], sigma=SIGMA)
        base_fit = fit(problem)
    family, columns, _ = family_columns(base_fit, StiffnessRegion())
    boxes = family.boxes
    worst = 0.0
    for box in boxes[[0, len(boxes) // 2, -1]]:
        own = StiffnessRegion(family.grid.rect(box))  # a new effect per box: its own Functions
        _, _, jacobian = candidate_jacobian(base_fit, own)
        expected = jacobian[:, -1]
        summed = columns @ family.grid.mask(box)
        worst = max(worst, np.abs(summed - expected).max() / np.abs(expected).max())
    assert worst < 1e-8, worst
    effect = StiffnessRegion()
    test = score_test(base_fit, effect, SIGMA)
    assert effect.rect == tuple(test.detail["rect_uv"])
    single = score_test(base_fit, StiffnessRegion(effect.rect), SIGMA, family=False)
    assert test.statistic == pytest.approx(single.statistic, rel=1e-8)
    if test.statistic > 0:
        bonferroni = single.log_p + np.log(test.detail["n_boxes"])
        assert test.log_p == pytest.approx(min(bonferroni, 0.0), rel=1e-8, abs=1e-12)
        np.testing.assert_allclose(test.step, single.step, rtol=1e-8)


def _diagnosis(data):
    """The loop with the gradient as the region's rival, on the continuum ``BASE``."""
    settings = DiagnosisSettings(candidates=("heterogeneity", "stiffer_region"))
    return diagnose_dataset(data, settings, base=BASE)


def test_the_loop_names_a_planted_stiff_disc_where_it_is(planted):
    """FE data with a disc three times as stiff: the loop names stiffer_region, refits the
    rectangle its score test chose, and that rectangle overlaps the disc (IoU > 0.3)."""
    diagnosis = _diagnosis(planted)
    assert diagnosis.selected[:1] == ["stiffer_region"], diagnosis.document()["rejected"]
    step = diagnosis.steps[1]
    (effect,) = [e for e in step.fit.problem.effects if e.name == "stiffer_region"]
    (test,) = [t for t in diagnosis.steps[0].scores if t.effect == "stiffer_region"]
    assert effect.rect == tuple(test.detail["rect_uv"])
    s = step.fit.p[step.fit.problem.slice_of("stiffer_region")][0]
    assert 0.0 < s < 99.0
    assert _overlap(step.fit.problem.model, effect.rect, DISC) > 0.3


def test_on_null_data_the_region_is_not_named(null):
    """The same FE slab without the disc: stiffer_region is not named."""
    diagnosis = _diagnosis(null)
    assert "stiffer_region" not in diagnosis.selected
    (test,) = [t for t in diagnosis.steps[0].scores if t.effect == "stiffer_region"]
    assert test.detail["n_boxes"] == 100  # 6 x 6 cells, rectangles inside the edge
