"""The second FE generator (``experiments.phantom.tissue``): properties of its physics.

Small meshes throughout (5 mm or 2.5 mm cells); each test checks a property the
solution must have, not a stored output.
"""

from __future__ import annotations

import numpy as np
import pytest

from experiments.phantom.tissue import (
    TissuePatch,
    TissueSolution,
    on_skin,
    tissue_cases,
    tissue_dataset,
)

SMALL = dict(marked=(20.0, 16.0), extent_mm=4.0, thickness=5.0, spacing_mm=4.0, layers=2)
"""A patch of 7 x 6 x 2 Q2 cells: solves in about a second."""


def _curved(**changes) -> TissuePatch:
    values = dict(SMALL, curvature_radii=(50.0, 80.0), support="elastic", lateral_spring=0.002)
    return TissuePatch(**{**values, **changes})


def test_flat_clamped_monolayer_agrees_with_the_tuned_tet_generator():
    """Same slab and Gaussian probe: Q2 hexes against ``fe.SlabSolution``'s P2 tets.

    The tolerance is the tet generator's own discretisation error, measured by one
    refinement (4 x 4 x 2 mm cells -> 2.7 x 2.7 x 1.3 mm; the field moves by 14 % of
    its largest value). The hexes, on the coarse cells, must lie nearer the refined tet
    field than the coarse tets do, by a margin (measured: 6.5 % against 14 %), so the two
    generators converge to the same elasticity and differ only by discretisation.
    """
    from experiments.phantom.fe import ReferenceSlab, SlabSolution

    x, y = np.meshgrid(np.linspace(-8, 8, 9), np.linspace(-8, 8, 9))
    markers = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 4.0)])
    force, contact = np.array([0.05, 0.0, -0.2]), np.array([3.0, -2.0, 4.0])

    def tets(n: int) -> np.ndarray:
        slab = ReferenceSlab(
            lengths=(24.0, 24.0, 4.0), marked=(16.0, 16.0), elements=(3 * n, 3 * n, n)
        )
        solver = SlabSolution(slab)
        return solver.at(solver.displacement(force, contact, 4.0), markers)

    patch = TissuePatch(
        marked=(16.0, 16.0),
        extent_mm=4.0,
        thickness=4.0,
        support="clamped",
        spacing_mm=4.0,
        growth=1.0,
        layers=2,
        poisson=0.45,
    )
    hexes = TissueSolution(patch)
    ours = hexes.at(hexes.displacement(force, contact, 4.0, probe="gauss"), markers)
    coarse, fine = tets(2), tets(3)
    tet_error = np.abs(coarse - fine).max()
    assert tet_error > 0.05 * np.abs(fine).max()  # the coarse mesh is not converged
    assert np.abs(ours - fine).max() < 0.6 * tet_error
    assert np.abs(ours - coarse).max() < 1.5 * tet_error


def test_displacement_is_linear_in_the_force():
    """Doubling a force doubles the field; two forces superpose (curved, elastic sides)."""
    solver = TissueSolution(_curved())
    contact = solver.skin(np.array([[2.0, 1.0]]))[0]
    one = solver.displacement((0.0, 0.0, -0.1), contact, 3.0)
    two = solver.displacement((0.0, 0.0, -0.2), contact, 3.0)
    side = solver.displacement((0.04, 0.0, 0.0), contact, 3.0)
    both = solver.displacement((0.04, 0.0, -0.1), contact, 3.0)
    scale = np.abs(two).max()
    assert np.abs(two - 2 * one).max() < 1e-10 * scale
    assert np.abs(both - one - side).max() < 1e-10 * scale


def test_reciprocity_between_two_point_like_loads():
    """Maxwell-Betti: the work of load A on B's field equals B's on A's, exactly in the
    discrete system (symmetric stiffness with springs and layers), and to within the
    patch size at the contact points (1 mm Gaussian patches)."""
    solver = TissueSolution(_curved(skin_mm=1.5, skin_ratio=4.0, layers=3))
    a, b = solver.skin(np.array([[-5.0, 2.0], [4.0, -3.0]]))
    load_a = solver.load((0.0, 0.0, -0.1), a, 1.0, probe="gauss")
    load_b = solver.load((0.05, 0.0, -0.05), b, 1.0, probe="gauss")
    field_a, field_b = solver.solve(load_a), solver.solve(load_b)
    assert load_b @ field_a == pytest.approx(load_a @ field_b, rel=1e-9)
    at_b = solver.at(field_a, b[None])[0] @ np.array([0.05, 0.0, -0.05])
    at_a = solver.at(field_b, a[None])[0] @ np.array([0.0, 0.0, -0.1])
    assert at_b == pytest.approx(at_a, rel=0.05)


def test_a_clamped_side_holds_a_spring_side_gives_and_a_free_side_moves():
    """On the side face near the probe: |u| = 0 clamped < elastic < free."""
    moved = {}
    for support in ("clamped", "elastic", "free"):
        solver = TissueSolution(_curved(support=support, extent_mm=2.0))
        edge = solver.patch.lengths[0] / 2
        contact = solver.skin(np.array([[8.0, 0.0]]))[0]
        field = solver.displacement((0.0, 0.0, -0.2), contact, 2.0)
        side = solver.skin(np.array([[edge, 0.0]]))[0] - [0.0, 0.0, 2.5]
        moved[support] = np.linalg.norm(solver.at(field, side[None]))
    assert moved["clamped"] < 1e-12
    assert 1e-4 < moved["elastic"] < moved["free"]


def test_a_compliant_base_gives_and_tends_to_the_fixed_one_as_it_stiffens():
    """On base springs the base under the probe moves and the skin sags more than on a
    fixed base; the difference falls monotonically as the springs stiffen."""
    contact = np.array([0.0, 0.0, 5.0])
    fixed = TissueSolution(TissuePatch(**SMALL))
    reference = fixed.at(fixed.displacement((0, 0, -0.2), contact, 2.5), contact[None])[0, 2]
    gaps = []
    for spring in (0.002, 0.02, 0.2, 2.0):
        solver = TissueSolution(TissuePatch(**SMALL, base_spring=spring))
        field = solver.displacement((0, 0, -0.2), contact, 2.5)
        top = solver.at(field, contact[None])[0, 2]
        bottom = solver.at(field, np.array([[0.0, 0.0, 0.0]]))[0, 2]
        assert top < reference < 0 and bottom < 0
        gaps.append(reference - top)
    assert all(b < a for a, b in zip(gaps, gaps[1:]))
    assert gaps[-1] < 0.05 * gaps[0]


def test_a_skin_layer_of_ratio_one_is_the_monolayer_and_a_stiffer_one_resists():
    """skin_ratio 1 gives the monolayer's field (same node planes); ratio 5 less sag."""
    flat = dict(SMALL, thickness=6.0, layers=4)
    contact = np.array([0.0, 0.0, 6.0])
    mono = TissueSolution(TissuePatch(**flat)).displacement((0, 0, -0.2), contact, 2.5)
    same = TissueSolution(TissuePatch(**flat, skin_mm=1.5, skin_ratio=1.0))
    stiff = TissueSolution(TissuePatch(**flat, skin_mm=1.5, skin_ratio=5.0))
    assert np.abs(same.displacement((0, 0, -0.2), contact, 2.5) - mono).max() < 1e-12
    top = stiff.at(stiff.displacement((0, 0, -0.2), contact, 2.5), contact[None])[0, 2]
    assert abs(top) < 0.8 * abs(same.at(mono, contact[None])[0, 2])


def test_forces_follow_the_curved_skin_and_markers_lie_on_it():
    """A normal press on the curved skin is along -normal; markers sit on the skin."""
    patch = _curved()
    xy = np.array([6.0, -4.0])
    pressed = on_skin(patch, np.array([0.0, 0.0, -0.2]), xy)
    assert pressed == pytest.approx(-0.2 * patch.normal(*xy))
    forces, contacts = tissue_cases("corners", patch)
    assert forces.shape == (8, 3) and np.all(np.linalg.norm(contacts, axis=1) > 0)
    data = tissue_dataset(patch, forces[:1], contacts[:1], markers=(6, 4))
    rest = data.outer_rest.reshape(-1, 3)
    expected = patch.thickness - patch.sag(rest[:, 0], rest[:, 1])
    assert np.abs(rest[:, 2] - expected).max() < 0.1  # noise 0.02 mm + bilinear skin


def test_a_dataset_without_a_probe_radius_loads_and_is_diagnosed(tmp_path):
    """The radius stays undeclared through save and load; ``dvs diagnose`` accepts it.

    With the paper's energy (``--energy dnurbs``): what is tested is the generator's file
    and the command's acceptance of it. Step 0 on an undeclared radius (estimated, not 0)
    is test_basemodel's, on a patch of this generator."""
    from experiments.command.cli import main
    from experiments.data.dataset import load_dataset, save_dataset

    patch = _curved(marked=(16.0, 12.0))
    forces, contacts = tissue_cases("paper", patch)
    data = tissue_dataset(patch, forces, contacts, radius=2.0, markers=(5, 4))
    path = save_dataset(tmp_path / "tissue.npz", data)
    loaded = load_dataset(path)
    assert loaded.probe_radius is None and loaded.marker_shape == (5, 4)
    out = str(tmp_path / "diag")
    assert main(["diagnose", str(path), "--energy", "dnurbs", "--out", out]) == 0
    assert (tmp_path / "diag" / "diagnosis.json").exists()


def test_the_block_assembly_is_the_vector_form():
    """``_elasticity`` (six scalar blocks) equals skfem's vector form of
    2 mu eps:eps + lambda div div on a curved, layered, graded mesh."""
    import skfem
    from skfem.helpers import ddot, div, sym_grad

    from experiments.phantom.tissue import _elasticity

    solver = TissueSolution(_curved(skin_mm=1.5, skin_ratio=3.0, layers=3, gradient=0.4))
    mesh, mu_l, lam = solver.mesh, 0.007, 0.06

    def factor(x):
        return 1.0 + 0.01 * x[0] + 0.02 * x[2] ** 2

    @skfem.BilinearForm
    def vector(u, v, w):
        return factor(w.x) * (2 * mu_l * ddot(sym_grad(u), sym_grad(v)) + lam * div(u) * div(v))

    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementHex2()), intorder=4)
    expected = vector.assemble(basis)
    ours = _elasticity(skfem, mesh, factor, mu_l, lam)
    assert abs(ours - expected).max() < 1e-12 * abs(expected).max()
