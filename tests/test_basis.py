"""Spline basis: partition of unity, derivatives, polynomial reproduction (eq. 2-9)."""

import numpy as np
import pytest

from symbolic.basis import BSplineBasis, VolumeBasis, clamped_uniform_knots
from symbolic.volume import VolumeSpline

RNG = np.random.default_rng(0)


def dense_samples(basis: BSplineBasis) -> np.ndarray:
    """Random points plus every knot and both ends."""
    return np.concatenate([RNG.random(400), basis.knots, [0.0, 1.0]])


@pytest.mark.parametrize("degree,n", [(0, 4), (1, 2), (2, 5), (3, 9), (3, 33), (5, 8)])
def test_partition_of_unity_1d(degree, n):
    basis = BSplineBasis(degree, n)
    values = basis.evaluate_dense(dense_samples(basis))
    assert np.max(np.abs(values.sum(axis=1) - 1.0)) < 1e-12
    assert values.min() > -1e-14


@pytest.mark.parametrize("weights", [False, True])
def test_partition_of_unity_volume(weights):
    w = RNG.uniform(0.5, 2.0, (5, 6, 2)) if weights else None
    basis = VolumeBasis((5, 6, 2), (3, 2, 1), w)
    corners = np.array([[0, 0, 0], [1, 1, 1], [1, 0, 1], [0.5, 1, 0]], dtype=float)
    points = np.vstack([RNG.random((500, 3)), corners])
    assert np.max(np.abs(basis.collocation(points).sum(axis=1) - 1.0)) < 1e-12
    for order in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (2, 0, 0)]:
        # derivatives of a partition of unity sum to zero
        assert np.max(np.abs(basis.collocation(points, order).sum(axis=1))) < 1e-10


@pytest.mark.parametrize("degree,n", [(2, 6), (3, 9), (4, 7)])
def test_derivatives_match_central_differences_1d(degree, n):
    basis = BSplineBasis(degree, n)
    t = RNG.uniform(0.02, 0.98, 200)
    h = 1e-5
    for order in (1, 2):
        lower = lambda s, o=order: basis.evaluate_dense(s, o - 1)  # noqa: E731
        fd = (lower(t + h) - lower(t - h)) / (2 * h)
        # skip points within h of a knot, where higher derivatives jump
        smooth = np.min(np.abs(t[:, None] - basis.knots[None, :]), axis=1) > 2 * h
        error = np.abs(fd - basis.evaluate_dense(t, order))[smooth]
        assert error.max() < 1e-6 * max(1.0, np.abs(fd).max())


@pytest.mark.parametrize("weights", [False, True])
def test_volume_derivatives_match_central_differences(weights):
    w = RNG.uniform(0.5, 2.0, (5, 5, 3)) if weights else None
    basis = VolumeBasis((5, 5, 3), (3, 3, 2), w)
    points = RNG.uniform(0.05, 0.95, (60, 3))
    h = 1e-5
    orders = [
        (1, 0, 0),
        (0, 1, 0),
        (0, 0, 1),
        (2, 0, 0),
        (0, 2, 0),
        (0, 0, 2),
        (1, 1, 0),
        (1, 0, 1),
        (0, 1, 1),
    ]
    for order in orders:
        axis = int(np.argmax(order))
        lower = list(order)
        lower[axis] -= 1
        step = np.zeros(3)
        step[axis] = h
        fd = (basis.collocation(points + step, lower) - basis.collocation(points - step, lower)) / (
            2 * h
        )
        exact = basis.collocation(points, order)
        assert abs(fd - exact).max() < 1e-6 * max(1.0, abs(exact).max()), order


def polynomial(params: np.ndarray) -> np.ndarray:
    """A map of degree (3, 3, 1): x = 40u, y = 40v, z = cubic(u) cubic(v) (1 + w) ..."""
    u, v, w = params.T
    z = (1 + 2 * u - u**3) * (0.5 - v + 2 * v**2 - v**3) * (1 + 3 * w) + 5 * w
    return np.column_stack([40 * u, 40 * v + 3 * w * u**2, z])


def test_fit_reproduces_polynomials_of_the_spline_degree():
    u = np.linspace(0, 1, 15)
    v = np.linspace(0, 1, 12)
    basis = VolumeBasis((9, 8, 2), (3, 3, 1))
    grid = polynomial(basis.grid_points(u, v, [0.0, 1.0])).reshape(15, 12, 2, 3)
    volume, report = VolumeSpline.fit(grid, (9, 8, 2), (3, 3, 1), parameterization="uniform")
    assert report.rms < 1e-10
    anywhere = RNG.random((500, 3))
    assert np.max(np.abs(volume.evaluate(anywhere) - polynomial(anywhere))) < 1e-10


def test_fit_error_decreases_with_refinement():
    """A sphere is not polynomial: the fit error falls at about h^4 for cubics."""
    from experiments.phantom.forehead import PhantomSettings, segmented_surfaces

    data = segmented_surfaces(PhantomSettings(segmentation=(41, 41)))
    errors = [VolumeSpline.fit(data, (m, m, 2))[1].rms for m in (5, 9, 17)]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 3.0)


def test_knots_are_clamped_and_uniform():
    knots = clamped_uniform_knots(3, 9)
    assert knots.size == 13
    assert np.all(knots[:4] == 0) and np.all(knots[-4:] == 1)
    assert np.allclose(np.diff(knots[3:-3]), 1 / 6)


@pytest.mark.parametrize(
    "shape, degrees", [((15, 15, 2), None), ((15, 27, 4), (3, 3, 2)), ((9, 9, 5), (3, 3, 3))]
)
def test_refinement_into_a_nested_space_keeps_the_geometry(shape, degrees):
    """Twice or four times the spans (or a higher degree through a linear w): same map."""
    from experiments.phantom.forehead import PhantomSettings, segmented_surfaces

    volume, _ = VolumeSpline.fit(segmented_surfaces(PhantomSettings(segmentation=(21, 21))))
    refined, deviation = volume.refined(shape, degrees)
    anywhere = RNG.random((500, 3))
    assert refined.shape == shape and deviation < 1e-10
    assert np.max(np.abs(refined.evaluate(anywhere) - volume.evaluate(anywhere))) < 1e-10


def test_refinement_into_a_space_that_is_not_nested_reports_its_deviation():
    """17 points of degree 3 (14 spans) do not contain 9 (6 spans): close, not exact."""
    from experiments.phantom.forehead import PhantomSettings, segmented_surfaces

    volume, _ = VolumeSpline.fit(segmented_surfaces(PhantomSettings(segmentation=(21, 21))))
    refined, deviation = volume.refined((17, 17, 2))
    anywhere = RNG.random((2000, 3))
    measured = np.linalg.norm(refined.evaluate(anywhere) - volume.evaluate(anywhere), axis=1)
    assert 1e-9 < measured.max() <= 1.01 * deviation < 1e-3
    with pytest.raises(ValueError, match="coarser"):
        volume.refined((7, 9, 2))


def test_collocation_rows_are_each_points_span_in_canonical_csr():
    """``VolumeBasis.collocation`` writes CSR directly (no COO sort): each row must be its
    point's span, columns strictly increasing, equal to the triple product of the
    univariate values summed entry by entry, also at knots and at the ends."""
    basis = VolumeBasis((12, 9, 5), (3, 3, 2))
    rng = np.random.default_rng(0)
    grid = np.array(np.meshgrid(*[np.linspace(0.0, 1.0, 7)] * 3)).reshape(3, -1).T
    points = np.vstack([rng.random((300, 3)), grid])
    for derivative in ((0, 0, 0), (1, 0, 0), (0, 1, 1), (2, 0, 0)):
        matrix = basis.collocation(points, derivative, keep_zeros=True)
        assert np.all(np.diff(matrix.indptr) == 4 * 4 * 3)
        assert np.all(np.diff(matrix.indices.reshape(len(points), -1), axis=1) > 0)
        for i in rng.choice(len(points), 20, replace=False):
            parts = [
                b.evaluate_dense(points[i : i + 1, k], derivative[k]).ravel()
                for k, b in enumerate(basis.bases)
            ]
            dense = np.einsum("i,j,k->ijk", *parts).ravel()
            assert np.allclose(matrix[i].toarray().ravel(), dense, atol=1e-13)
