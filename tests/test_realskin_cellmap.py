"""The cell map of real skin (experiments/realskin/cellmap.py, eq. R1).

The form and the prior are checked as identities on a grid of cells; the map itself on
the synthetic keloid twin (``twin.py``): the real case's slab, pads, frames and DIC
points, with data made by the model with and without a stiffer material inside the
keloid outline, plus the measured noise level.
"""

import numpy as np
import pytest

from experiments.realskin.cellmap import gradient_form, prior_precision
from experiments.realskin.geometry import Rect
from experiments.realskin.scan import CellGrid


def grid_of(n_x: int, n_y: int) -> CellGrid:
    region = Rect(0.0, -5.0, 100.0, 45.0)
    return CellGrid(
        region,
        np.linspace(region.x0, region.x1, n_x + 1),
        np.linspace(region.y0, region.y1, n_y + 1),
    )


def test_gradient_form_is_exact_for_linear_maps_and_blind_to_constants():
    """s^T L s is the area mean of the squared difference quotients: 0 for a constant
    map; for s = a x + b y on uniform cells, every quotient is exact, and the x pairs
    cover (n_x - 1) / n_x of the area, the y pairs (n_y - 1) / n_y."""
    n_x, n_y = 18, 8
    grid = grid_of(n_x, n_y)
    form = gradient_form(grid)
    assert np.allclose(form, form.T)
    assert np.allclose(form @ np.ones(grid.n_cells), 0.0, atol=1e-15)
    assert np.linalg.eigvalsh(form).min() > -1e-12
    cx = 0.5 * (grid.x_edges[1:] + grid.x_edges[:-1])
    cy = 0.5 * (grid.y_edges[1:] + grid.y_edges[:-1])
    a, b = 0.03, -0.05  # [1/mm]
    s = (a * cx[:, None] + b * cy[None, :]).ravel()
    expected = a**2 * (n_x - 1) / n_x + b**2 * (n_y - 1) / n_y
    assert s @ form @ s == pytest.approx(expected, rel=1e-12)


def test_prior_gives_a_constant_map_the_mean_square_tau_squared():
    """Under Q of eq. (R1) a constant map s = c costs n_cells c^2 / tau^2, so the prior's
    mean square of s per cell is tau^2, as eq. (F2) of the loop's field."""
    grid = grid_of(18, 8)
    tau, c = 0.5, 0.3
    precision = prior_precision(grid, tau)
    s = np.full(grid.n_cells, c)
    assert s @ precision @ s == pytest.approx(grid.n_cells * c**2 / tau**2, rel=1e-12)
    assert np.linalg.eigvalsh(precision).min() > 0.0


def test_map_of_the_keloid_twin(shared_data):
    """Homogeneous twin: no cell departs from the mean (Bonferroni, two-sided). Twin with
    a stiffer material (ratio 3.5) inside the outline: the map's one linearised step
    takes the cost down to within 10 % of the homogeneous twin's (the noise's)."""
    from experiments.realskin.cellmap import estimate_map, significant_cells
    from experiments.realskin.setup import RealSkinSettings, build
    from experiments.realskin.stages import fit_stage
    from experiments.realskin.twin import base_parameters, make_twin, truth_model
    from solvers.inverse.space import SkinParameterSpace

    settings = RealSkinSettings()
    real = build("keloid", settings)
    space = SkinParameterSpace.build(real.base_names, real.start, settings.bounds)
    maps = {}
    for ratio in (1.0, 3.5):
        truth = truth_model(real, ratio, settings)
        params = base_parameters(real, truth, settings)
        x = np.array([params["alpha_u"], params["alpha_w"], ratio])
        noisy, _ = make_twin(real, truth, x, 0, real.noise_mm)
        fit = fit_stage(real.model, noisy.cases, space, "linear", log=lambda *_: None)
        maps[ratio] = estimate_map(
            real.model, noisy.cases, fit.names, fit.x, settings.bounds, real.grid
        )
    cells = significant_cells(maps[1.0])
    assert cells["stiffer_bonferroni"] == 0 and cells["softer_bonferroni"] == 0
    assert maps[1.0].cost_after <= maps[1.0].cost_before
    assert maps[3.5].cost_before > 2.0 * maps[1.0].cost_before
    assert maps[3.5].cost_after < 1.1 * maps[1.0].cost_before
    assert 1.0 < maps[3.5].effective_dof < real.grid.n_cells - 1
