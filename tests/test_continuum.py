"""Verification of the isogeometric linear elasticity (docs/continuum.md).

- identities: rigid motions carry no energy on any geometry; a uniform strain has
  the energy of eq. (C1) times the volume;
- patch test: a linear field on the boundary gives the same field inside, exactly on
  an affine map, to quadrature accuracy on a curved one;
- convergence orders under h- and p-refinement against a manufactured solution;
- agreement with scikit-fem (P2 tetrahedra) on the same slab and load;
- the inverse on scikit-fem data: E and nu recovered, nested = simultaneous.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse.linalg as spla
import skfem
from volumes import curved_volume

from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.basis import FIRST_DERIVATIVES
from symbolic.continuum import (
    PhysicalGradient,
    body_force_vector,
    box_volume,
    elasticity_matrices,
    lame,
    young_poisson,
)
from symbolic.energy import quadrature
from symbolic.sparse import ProductTerm, padded, term_matrix
from symbolic.volume import VolumeSpline


def vec(displacement: np.ndarray) -> np.ndarray:
    """vec of an (n, 3) array, x components first (the stacked order)."""
    return displacement.T.ravel()


def stiffness(volume, mu=0.3, lam=1.1, extra=0):
    k = elasticity_matrices(volume, extra)
    return (mu * k["shear"] + lam * k["volumetric"]).tocsr()


def test_lame_round_trip():
    mu_l, lam = lame(20.0, 0.45)
    assert young_poisson(mu_l, lam) == pytest.approx((20.0, 0.45), rel=1e-12)
    assert mu_l == pytest.approx(0.02 / 2.9)


@pytest.mark.parametrize(
    "field", [None, lambda p: 1.0 + p[:, 0] * p[:, 1], lambda p: np.where(p[:, 0] < 0.3, 1.0, 0.0)]
)
def test_block_assembly_equals_the_gram_of_the_strain_rows(field):
    """K_mu, K_lambda from the nine scalar blocks G_ab (element-batched; by sparse
    products for a local field) equal 2 int eps:eps and int (div u)^2 assembled row by
    row (``PhysicalGradient.gram``), also under a field and a local field, and are
    exactly symmetric."""
    gradient = PhysicalGradient.of(curved_volume())
    assert gradient._assembly is not None  # element-batched unless the field has zeros
    blocks = gradient.elasticity(field)
    rows = {
        "shear": gradient.gram(gradient.strain(), 2.0, field),
        "volumetric": gradient.gram([gradient.divergence()], 1.0, field),
    }
    for name, reference in rows.items():
        assert abs(blocks[name] - reference).max() <= 1e-14 * abs(reference).max()
        assert abs(blocks[name] - blocks[name].T).max() == 0.0


@pytest.mark.parametrize("field", [None, lambda p: 1.0 + p[:, 0] * p[:, 1]])
def test_matrix_free_product_equals_the_assembled_terms(field):
    """``elasticity_product`` applies K_mu and K_lambda of ``elasticity`` without forming
    them, for one vector and for several columns; a padded ``ProductTerm`` agrees with its
    padded matrix."""
    gradient = PhysicalGradient.of(curved_volume())
    blocks = gradient.elasticity(field)
    u = np.random.default_rng(3).standard_normal((blocks["shear"].shape[0], 4))
    for columns in (u, u[:, 0]):
        products = gradient.elasticity_product(columns, field)
        for name, matrix in blocks.items():
            reference = matrix @ columns
            assert np.abs(products[name] - reference).max() <= 1e-12 * np.abs(reference).max()
    size = blocks["shear"].shape[0]
    term = ProductTerm(
        size, lambda x: gradient.elasticity_product(x, field)["shear"], lambda: blocks["shear"]
    )
    grown = padded(term, size + 6)
    x = np.random.default_rng(4).standard_normal((size + 6, 2))
    expected = term_matrix(padded(blocks["shear"], size + 6)) @ x
    assert np.abs(grown @ x - expected).max() <= 1e-12 * np.abs(expected).max()
    assert abs(term_matrix(grown) - padded(blocks["shear"], size + 6)).max() == 0.0


@pytest.mark.parametrize("volume", [box_volume((10, 8, 3), (5, 4, 3), (2, 2, 2)), curved_volume()])
def test_rigid_motions_carry_no_energy(volume):
    """Translations and rotations are exactly in the spline space (sum N_i = 1)."""
    matrix, points = stiffness(volume), volume.control_points
    scale = np.abs(matrix).max()
    for axis in np.eye(3):
        assert np.abs(matrix @ vec(np.tile(axis, (len(points), 1)))).max() < 1e-12 * scale
        rotation = np.cross(axis, points - points.mean(axis=0))
        assert np.abs(matrix @ vec(rotation)).max() < 1e-12 * scale * 20


def test_uniform_strain_energy_is_exact_on_an_affine_map():
    """1/2 u^T K u = (mu eps:eps + lam/2 (tr eps)^2) V for u = A x on a sheared box."""
    box = box_volume((10.0, 8.0, 3.0), (5, 4, 3), (2, 2, 2))
    shear = np.array([[1.0, 0.2, 0.1], [0.0, 1.0, 0.3], [0.0, 0.0, 1.0]])
    volume = VolumeSpline(box.basis, box.control_points @ shear.T)
    gradient = np.array([[1e-2, 4e-3, -2e-3], [0.0, -5e-3, 1e-3], [2e-3, 1e-3, 3e-3]])
    eps = 0.5 * (gradient + gradient.T)
    mu, lam = 0.3, 1.1
    energy = 0.5 * vec(volume.control_points @ gradient.T) @ stiffness(volume, mu, lam)
    energy = energy @ vec(volume.control_points @ gradient.T)
    exact = (mu * np.sum(eps * eps) + 0.5 * lam * np.trace(eps) ** 2) * 240.0
    assert energy == pytest.approx(exact, rel=1e-12)


def patch_error(volume: VolumeSpline, extra: int = 0) -> float:
    """Boundary control points follow u = A x + b; the interior is solved with no load."""
    gradient = np.array([[1e-2, 4e-3, -2e-3], [1e-3, -5e-3, 1e-3], [2e-3, 1e-3, 3e-3]])
    exact = volume.control_points @ gradient.T + np.array([0.1, -0.2, 0.05])
    index = np.indices(volume.shape).reshape(3, -1).T
    inside = np.all((index > 0) & (index < np.array(volume.shape) - 1), axis=1)
    n = volume.basis.size
    free = np.concatenate([np.flatnonzero(inside) + k * n for k in range(3)])
    fixed = np.setdiff1d(np.arange(3 * n), free)
    matrix = stiffness(volume, extra=extra)
    solution = vec(exact).copy()
    right = -matrix[free][:, fixed] @ solution[fixed]
    solution[free] = spla.spsolve(matrix[free][:, free].tocsc(), right)
    return float(np.abs(solution - vec(exact)).max() / np.abs(exact).max())


def test_patch_test():
    """Exact on an affine map. On a randomly distorted map the interior rows integrate
    cof(G) grad N_i, a derivative of a polynomial of degree 3p (Piola identity): the
    default rule (p + 1 points) leaves a quadrature error (measured 4.7e-6), one more
    point per span makes the test exact."""
    box = box_volume((10.0, 8.0, 3.0), (6, 5, 4), (2, 2, 2))
    shear = np.array([[1.0, 0.2, 0.1], [0.0, 1.0, 0.3], [0.0, 0.0, 1.0]])
    assert patch_error(VolumeSpline(box.basis, box.control_points @ shear.T)) < 1e-11
    assert patch_error(curved_volume()) < 1e-11
    box = box_volume((20.0, 16.0, 4.0), (6, 5, 3), (3, 3, 2))
    shake = np.random.default_rng(0).uniform(-0.5, 0.5, box.control_points.shape)
    distorted = VolumeSpline(box.basis, box.control_points + shake * np.array([1.0, 1.0, 0.3]))
    assert 1e-9 < patch_error(distorted) < 1e-5
    assert patch_error(distorted, extra=1) < 1e-11


LENGTHS = np.array([10.0, 8.0, 3.0])
MU, LAM = 0.004, 0.03


def manufactured():
    """u vanishing on the box's boundary, and f = -div sigma(u) by CasADi's AD."""
    x = ca.SX.sym("x", 3)
    s = ca.sin(np.pi * x[0] / LENGTHS[0]) * ca.sin(np.pi * x[1] / LENGTHS[1])
    s = s * ca.sin(np.pi * x[2] / LENGTHS[2])
    u = ca.vertcat(0.1 * s, 0.05 * s * (1 + x[0] / LENGTHS[0]), -0.08 * s * x[1] / LENGTHS[1])
    grad = ca.jacobian(u, x)
    eps = 0.5 * (grad + grad.T)
    sigma = 2 * MU * eps + LAM * ca.trace(eps) * ca.SX.eye(3)
    div = [sum(ca.gradient(sigma[i, j], x)[j] for j in range(3)) for i in range(3)]
    functions = [ca.Function(n, [x], [e]) for n, e in (("u", u), ("f", -ca.vertcat(*div)))]
    functions.append(ca.Function("g", [x], [ca.vec(grad)]))
    return [lambda p, f=f: np.array(f.map(p.shape[0])(p.T)).T for f in functions]


def manufactured_errors(spans: int, degree: int) -> tuple[float, float]:
    """L2 and H1-seminorm errors of the IGA solution (Dirichlet on the whole boundary)."""
    exact_u, force, exact_grad = manufactured()
    volume = box_volume(tuple(LENGTHS), (spans + degree,) * 3, (degree,) * 3)
    n = volume.basis.size
    index = np.indices(volume.shape).reshape(3, -1).T
    inside = np.all((index > 0) & (index < np.array(volume.shape) - 1), axis=1)
    free = np.concatenate([np.flatnonzero(inside) + k * n for k in range(3)])
    matrix = stiffness(volume, MU, LAM)
    load = vec(body_force_vector(volume, force, extra_points=3))
    solution = np.zeros(3 * n)
    solution[free] = spla.spsolve(matrix[free][:, free].tocsc(), load[free])
    delta = solution.reshape(3, n).T
    points, weights = quadrature(volume.basis, 3)
    weights = weights * np.prod(LENGTHS)
    values = volume.collocation(points)
    physical = values @ volume.control_points
    l2 = np.sqrt(weights @ np.sum((values @ delta - exact_u(physical)) ** 2, axis=1))
    grads = [
        volume.collocation(points, d) @ delta / LENGTHS[a]
        for a, d in enumerate(FIRST_DERIVATIVES.values())
    ]
    discrete = np.stack(grads, axis=-1)  # (q, i, a) = d u_i / d x_a
    exact = exact_grad(physical).reshape(-1, 3, 3, order="F")
    h1 = np.sqrt(weights @ np.sum((discrete - exact) ** 2, axis=(1, 2)))
    return float(l2), float(h1)


@pytest.mark.parametrize("degree", [2, 3])
def test_h_refinement_orders(degree):
    """L2 error O(h^(p+1)), H1 error O(h^p) (measured: p=2 3.23/2.11, p=3 4.24/3.15)."""
    coarse, fine = manufactured_errors(4, degree), manufactured_errors(8, degree)
    l2_rate, h1_rate = (np.log2(c / f) for c, f in zip(coarse, fine))
    assert l2_rate > degree + 1 - 0.25
    assert h1_rate > degree - 0.25


def test_p_refinement_is_faster_than_any_fixed_order():
    """On 4 spans per direction each degree from 1 to 4 cuts both errors at least 5x."""
    errors = np.array([manufactured_errors(4, p) for p in (1, 2, 3, 4)])
    assert np.all(errors[:-1] / errors[1:] > 5.0)


def fe_top_displacement(cells, points, young_kpa=20.0, poisson=0.45, force=(2e-4, 1e-4, -5e-4)):
    """scikit-fem P2 tetrahedra: a 20 x 16 x 4 mm slab, base fixed, a body force [N/mm^3]."""
    from skfem.models.elasticity import linear_elasticity

    mu_l, lam = lame(young_kpa, poisson)
    mesh = skfem.MeshTet.init_tensor(
        *(np.linspace(0.0, length, n + 1) for length, n in zip((20.0, 16.0, 4.0), cells))
    )
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))

    @skfem.LinearForm
    def body(v, w):
        return force[0] * v[0] + force[1] * v[1] + force[2] * v[2]

    matrix = linear_elasticity(lam, mu_l).assemble(basis)
    load = body.assemble(basis)
    fixed = basis.get_dofs(lambda x: np.isclose(x[2], 0.0))
    free = basis.complement_dofs(fixed)
    solution = np.zeros(basis.N)
    factor = factorised(matrix[free][:, free].tocsc(), symmetric_lu)  # SPD: CHOLMOD
    solution[free] = factor.solve(load[free])
    return (basis.probes(points.T) @ solution).reshape(3, -1).T


def iga_top_displacement(points, young_kpa=20.0, poisson=0.45, force=(2e-4, 1e-4, -5e-4)):
    """The same slab as a 17 x 17 x 6 cubic volume spline."""
    volume = box_volume((20.0, 16.0, 4.0), (17, 17, 6), (3, 3, 3))
    mu_l, lam = lame(young_kpa, poisson)
    matrix = stiffness(volume, mu_l, lam)
    load = vec(body_force_vector(volume, lambda x: np.tile(force, (len(x), 1))))
    n = volume.basis.size
    layer = np.indices(volume.shape).reshape(3, -1)[2]
    free = np.concatenate([np.flatnonzero(layer > 0) + k * n for k in range(3)])
    solution = np.zeros(3 * n)
    solution[free] = factorised(matrix[free][:, free].tocsc(), symmetric_lu).solve(load[free])
    uvw = points / np.array([20.0, 16.0, 4.0])
    return volume.collocation(uvw) @ solution.reshape(3, n).T


def test_agreement_with_scikit_fem():
    """Top-surface displacements away from the clamped edges' singularities agree with
    scikit-fem's P2 tetrahedra to < 1 % of the largest, and the gap shrinks as the FE
    mesh is refined (measured: 2.7 % at 10 x 8 x 2 cells, 0.7 % at 20 x 16 x 4)."""
    grid = np.meshgrid(np.linspace(4, 16, 5), np.linspace(4, 12, 5), [4.0], indexing="ij")
    points = np.column_stack([g.ravel() for g in grid])
    spline = iga_top_displacement(points)
    scale = np.abs(spline).max()
    gaps = [
        np.abs(fe_top_displacement(cells, points) - spline).max() / scale
        for cells in ((10, 8, 2), (20, 16, 4))
    ]
    assert gaps[1] < 0.01
    assert gaps[1] < 0.5 * gaps[0]


def test_state_jacobian_matches_finite_differences():
    """The closed-form dg/dx of the continuum model (E, nu) against central differences."""
    from symbolic.continuum_model import ContinuumModel

    model = ContinuumModel(box_volume((20.0, 16.0, 4.0), (5, 5, 3), (2, 2, 2)))
    g = model.state_residual(("E", "nu"))
    rng = np.random.default_rng(3)
    state = rng.normal(0.0, 0.01, g.size1_in(0))
    force = rng.normal(0.0, 0.01, (model.n_free, 3))
    x = np.array([15.0, 0.4])
    jacobian = g.jacobian()(state, x, force, np.zeros((0, 3)), 0)
    analytic = np.array(jacobian[1])
    step = 1e-6 * np.abs(x)
    numeric = np.column_stack(
        [
            (
                np.array(g(state, x + step[k] * e, force, np.zeros((0, 3))))
                - np.array(g(state, x - step[k] * e, force, np.zeros((0, 3))))
            ).ravel()
            / (2 * step[k])
            for k, e in enumerate(np.eye(2))
        ]
    )
    assert np.abs(analytic - numeric).max() < 1e-6 * np.abs(numeric).max()


def test_continuum_model_rejects_what_it_lacks():
    from symbolic.continuum_model import ContinuumModel

    volume = box_volume((20.0, 16.0, 4.0), (4, 4, 2), (2, 2, 1))
    with pytest.raises(ValueError, match="k0"):
        ContinuumModel(volume, {"k0": 1.0})
    with pytest.raises(ValueError, match="nu must be < 0.5"):
        ContinuumModel(volume, {"nu": 0.5})


@pytest.fixture(scope="module")
def reference_data():
    """scikit-fem data of a 60 x 60 x 5 mm slab (E 20 kPa, nu 0.45) fixed at its base and
    far sides; 17 x 17 markers over the central 40 x 40 mm; 4 mm probes at 0.17 and
    0.25 N; noise 0.02 mm, occlusion and missing markers."""
    from experiments.phantom.fe import ReferenceSlab, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    slab = ReferenceSlab(lengths=(60.0, 60.0, 5.0), elements=(24, 24, 3))
    forces = np.array([[0.0, 0.0, -0.17], [0.0, 0.0, -0.25]])
    measurement = SimulationSettings(noise_mm=0.02, seed=1)
    return reference_dataset(slab, forces, np.zeros((2, 2)), 4.0, (17, 17), measurement)


def test_inverse_recovers_young_and_poisson_from_scikit_fem_data(reference_data):
    """The model (17 x 17 x 4 control points, free sides at the marked area's edge)
    differs from the truth in mesh, element and extent; E within 3 %, nu within 0.01,
    residual at the noise level, and the two inverse methods agree."""
    from experiments.problem.fitting import FitSettings, build_problem, solve

    settings = FitSettings(
        names=("E", "nu"), energy="linear-elastic", grid=(17, 17, 4), degrees=(3, 3, 2)
    )
    problem = build_problem(reference_data, settings)
    nested, simultaneous = solve(problem, "nested"), solve(problem, "simultaneous")
    assert nested.success and simultaneous.success
    assert np.allclose(nested.x, simultaneous.x, rtol=1e-6)
    assert nested.x[0] == pytest.approx(20.0, rel=0.03)
    assert nested.x[1] == pytest.approx(0.45, abs=0.01)
    errors = np.concatenate(problem.point_errors(nested.states))
    noise_level = np.sqrt(6.0) * 0.02  # rest and loaded markers, three coordinates each
    assert np.sqrt(np.mean(errors**2)) < 1.1 * noise_level


def test_casadi_copy_leaves_a_matrix_with_explicit_zeros_intact():
    """Element-batched K keeps exact zeros in its pattern; converting it for CasADi (which
    drops them) must not change the scipy matrix the linear path goes on using."""
    import scipy.sparse as sp

    from symbolic.sparse import to_casadi_sparse

    matrix = sp.csc_matrix((np.array([1.0, 0.0, 2.0]), np.array([0, 1, 1]), [0, 1, 3]), (2, 2))
    before = (matrix.data.copy(), matrix.indices.copy(), matrix.indptr.copy())
    dm = to_casadi_sparse(matrix)
    assert dm.nnz() == 2
    for now, then in zip((matrix.data, matrix.indices, matrix.indptr), before):
        np.testing.assert_array_equal(now, then)
