"""Which weight rule sees the acceptance inclusion (docs/imaging.md, "Which weight").

The linearised Monte Carlo of ``experiments.imaging.weightstudy`` on the acceptance's
first draw (FE disc signal, 23x23x4 model): the fast test checks the study's closed
forms on a small made-up linear problem; the slow one (about 4 min) re-measures the
rates the docs quote, with bounds four binomial standard deviations wide at 200 draws.
"""

import numpy as np
import pytest

from experiments.imaging.weightstudy import LinearStudy, monte_carlo


def toy_parts(rng, n=300, size=9):
    """A 3 x 3 node field on a 30 mm square, J random, d = J times a bump, nu's column."""
    xy = np.array([(x, y) for y in (-10.0, 0.0, 10.0) for x in (-10.0, 0.0, 10.0)])
    difference = np.zeros((12, size))
    pairs = [(i, i + 1) for i in range(size) if i % 3 != 2] + [(i, i + 3) for i in range(6)]
    for row, (a, b) in enumerate(pairs):
        difference[row, a], difference[row, b] = 1.0, -1.0
    jacobian = rng.standard_normal((n, size))
    truth = np.where(np.linalg.norm(xy, axis=1) < 1.0, np.log(2.0), 0.0)
    return {
        "J": jacobian,
        "nu": rng.standard_normal(n),
        "d": -(jacobian @ truth),
        "L": difference.T @ difference,
        "D": difference,
        "xy": xy,
    }


def test_the_study_estimate_is_the_regularised_least_squares_solution():
    rng = np.random.default_rng(1)
    study = LinearStudy(toy_parts(rng), (0.0, 0.0), betas=np.array([0.1, 10.0, 1e3]))
    y = study.d + study.project(rng.standard_normal(study.n))
    maps, chi2, _, _, _ = study.path(y)
    for beta, c, chi in zip(study.betas, maps, chi2):
        stacked = np.vstack(
            [study.J, np.sqrt(beta) * np.linalg.cholesky(study.L + 1e-12 * np.eye(9)).T]
        )
        direct = np.linalg.lstsq(stacked, np.concatenate([-y, np.zeros(9)]), rcond=None)[0]
        assert np.allclose(c, direct, atol=1e-6)
        assert chi == pytest.approx(np.sum((y + study.J @ c) ** 2))
    # nu's column is profiled: the projected J is orthogonal to it
    assert np.abs(study.J.T @ toy_parts(np.random.default_rng(1))["nu"]).max() < 1e-8
    # the effective dof falls from near N to near the null space of L (the constant)
    assert study.dof[0] > study.dof[1] > study.dof[2] > 1.0 - 1e-6


def test_every_rule_finds_a_strong_bump_and_none_on_pure_noise():
    study = LinearStudy(toy_parts(np.random.default_rng(2)), (0.0, 0.0), np.logspace(-2, 4, 25))
    result = monte_carlo(study, draws=20)
    for rule in ("gcv", "upre", "marginal likelihood"):
        assert result["rules"][rule]["peak_ok"] == 1.0
        assert result["rules"][rule]["null_node_beyond_2_std"] <= 0.1


class Differences:
    """R(c) = sum_e sqrt((D c)_e^2 + eps^2) - its minimum: a total variation over the
    toy's edges, with the interface of ``solvers.imaging.regularization.TotalVariation``."""

    def __init__(self, difference, epsilon=0.01):
        self.D, self.epsilon = difference, epsilon

    def value(self, c):
        return float(np.sum(np.sqrt((self.D @ c) ** 2 + self.epsilon**2)))

    def gradient(self, c):
        return self.D.T @ ((self.D @ c) / np.sqrt((self.D @ c) ** 2 + self.epsilon**2))

    def hessian(self, c):
        import scipy.sparse as sp

        weight = 1.0 / np.sqrt((self.D @ c) ** 2 + self.epsilon**2)
        return sp.csr_matrix(self.D.T @ (weight[:, None] * self.D))


def test_the_total_variation_study_estimate_is_stationary_and_its_dof_falls():
    rng = np.random.default_rng(3)
    parts = toy_parts(rng)
    tv = Differences(parts["D"])
    study = LinearStudy(parts, (0.0, 0.0), np.array([0.1, 10.0, 1e3]), regularizer=tv)
    y = study.d + study.project(rng.standard_normal(study.n))
    maps, chi2, penalty, dof, std = study.path(y)
    for beta, c, chi, value in zip(study.betas, maps, chi2, penalty):
        # the gradient of |y + J c|^2 / 2 + beta R(c) vanishes at the estimate
        stationarity = study.J.T @ (y + study.J @ c) + beta * tv.gradient(c)
        assert np.abs(stationarity).max() < 1e-4 * np.abs(study.J.T @ y).max()
        assert chi == pytest.approx(np.sum((y + study.J @ c) ** 2))
        assert value == pytest.approx(2 * beta * tv.value(c))
    assert dof[0] > dof[1] > dof[2] > 1.0 - 1e-6
    assert all(np.all(s > 0) for s in std)
    assert "marginal likelihood" not in study.choose(chi2, penalty, dof)


@pytest.mark.slow
def test_gcv_sees_the_acceptance_disc_where_morozov_smooths_it_away():
    from experiments.imaging.weightstudy import inclusion_datasets, linearise

    disc, none, centre = inclusion_datasets(7)
    study = LinearStudy(linearise(disc, none, (23, 23, 4)), centre)
    rules = monte_carlo(study, draws=200)["rules"]
    assert rules["gcv"]["all_ok"] >= 0.78  # measured 0.875
    assert rules["gcv"]["null_node_beyond_2_std"] <= 0.05  # measured 0.01
    assert rules["morozov"]["all_ok"] <= 0.50  # measured 0.37


def test_the_oracle_press_adds_one_normal_press_at_the_disc_to_the_study_design():
    from experiments.imaging.weightstudy import ORACLE_FORCE_N, study_cases
    from experiments.phantom.fe import ReferenceSlab, design_cases

    slab = ReferenceSlab(elements=(4, 4, 1))
    forces, contacts = study_cases(slab)
    plain_forces, plain_contacts = design_cases("diagnosis", slab)
    assert np.array_equal(forces, plain_forces) and np.array_equal(contacts, plain_contacts)
    more_forces, more_contacts = study_cases(slab, (-5.19, 14.62))
    assert more_forces.shape == (len(forces) + 1, 3)
    assert np.array_equal(more_forces[:-1], forces)
    assert np.array_equal(more_contacts[:-1], contacts)
    assert np.allclose(more_forces[-1], [0.0, 0.0, -ORACLE_FORCE_N])
    assert np.allclose(more_contacts[-1], [-5.19, 14.62])


def test_the_places_table_reads_each_place_from_its_own_study():
    from experiments.imaging.weightstudy import (
        nearest_press_mm,
        oracle_contact,
        place_row,
        places_table,
    )

    # the diagnosis design presses at the centre and at (+-8, +-8) mm
    assert nearest_press_mm((8.0, 8.0)) == pytest.approx(0.0, abs=1e-9)
    assert nearest_press_mm((-11.0, 0.0)) == pytest.approx(np.hypot(3.0, 8.0))
    assert nearest_press_mm((-11.0, 0.0), oracle_mm=0.0) == pytest.approx(0.0, abs=1e-9)
    # 5 mm towards the centre from (-11, 0): (-6, 0), nearer than the design's presses
    assert nearest_press_mm((-11.0, 0.0), oracle_mm=5.0) == pytest.approx(5.0)
    assert np.allclose(oracle_contact((3.0, 4.0), 5.0), 0.0)
    assert np.allclose(oracle_contact((3.0, 4.0), 2.5), (1.5, 2.0))
    study = LinearStudy(toy_parts(np.random.default_rng(2)), (0.0, 0.0), np.logspace(-2, 4, 25))
    result = monte_carlo(study, draws=10)
    row = place_row(3, (1.234, -5.0), result)
    best = max(r["all_ok"] for r in result["fixed_beta"])
    assert row["best_fixed"]["all_ok"] == best
    assert row["all_ok"]["gcv"] == result["rules"]["gcv"]["all_ok"]
    assert row["signal_chi2"] == pytest.approx(result["signal_chi2"], abs=0.05)
    table = places_table([row, row]).splitlines()
    assert len(table) == 4 and table[2].startswith("| 3 | (1.23, -5.00) |")
