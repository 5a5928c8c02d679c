"""Verification of the fibre family (docs/continuum.md, eq. C13-C14).

- the force with the fibre stress (C14) is the gradient of the stored energy (C6) +
  (C10) + (C13), the latter evaluated independently in numpy;
- its numpy tangent equals CasADi's AD Jacobian of the force, and vanishes at rest;
- closed form: a homogeneous stretch along the fibres gives P_f = 2 W1 lambda a0 a0^T,
  and neither a compression along them nor a stretch across them gives any;
- at kf1 = 0 the model is the exponential one; models without fibres refuse kf1.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from test_hyperelastic import exponential_operators
from volumes import curved_volume

from symbolic.continuum import box_volume, lame
from symbolic.hyperelastic import (
    exponential_energy_density,
    fibre_energy_density,
    neo_hookean_energy_density,
    piola_stress,
)

MU, LAM = lame(20.0, 0.4)
K1, K2 = 5e-3, 20.0
"""k1 [N/mm^2] and k2 [1] of the isotropic exponential term."""
KF1, KF2, PHI = 2e-2, 5.0, 0.6
"""kf1 [N/mm^2] (20 kPa), kf2 [1] and the fibre angle phi [rad] of the checks."""


def fibre_operators(volume):
    """Force with stress (C7) + (C11) + (C14) and its tangent, on every control point."""
    return exponential_operators(volume, fibres=True)


def random_state(volume, size: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return size * rng.normal(size=volume.control_points.shape)


def test_fibre_force_is_the_gradient_of_its_energy():
    """Eq. (C14) against central differences of the numpy energy; at 30 % random
    displacements some fibres are stretched and some are not."""
    volume = curved_volume()
    gradient, force, _ = fibre_operators(volume)
    delta = ca.MX.sym("delta", volume.basis.size, 3)
    function = ca.Function("f", [delta], [force(delta, MU, LAM, K1, K2, KF1, KF2, PHI)])
    state, direction = random_state(volume, 0.3), random_state(volume, 1.0, seed=1)

    def gradients(d):
        return np.stack(
            [np.stack([p @ d[:, i] for p in gradient.operators], -1) for i in range(3)], 1
        )

    def total(d):
        h = gradients(d)
        density = (
            neo_hookean_energy_density(h, MU, LAM)
            + exponential_energy_density(h, K1, K2)
            + fibre_energy_density(h, KF1, KF2, PHI)
        )
        return float(gradient.volume @ density)

    stretched = fibre_energy_density(gradients(state), 1.0, 0.0, PHI) > 0
    assert 0.1 < stretched.mean() < 0.9
    step = 1e-5
    numeric = (total(state + step * direction) - total(state - step * direction)) / (2 * step)
    assert float(np.sum(function(state).full() * direction)) == pytest.approx(numeric, rel=1e-7)


def test_fibre_tangent_matches_ad_and_vanishes_at_rest():
    """The numpy tangent (C14) equals CasADi's AD Jacobian of the force; the fibres add
    a large part of it away from rest and nothing at rest."""
    volume = curved_volume()
    _, force, tangent = fibre_operators(volume)
    n = volume.basis.size
    state = ca.MX.sym("s", 3 * n)
    expression = ca.vec(force(ca.reshape(state, n, 3), MU, LAM, K1, K2, KF1, KF2, PHI))
    jacobian = ca.Function("K", [state], [ca.jacobian(expression, state)])
    deformed = random_state(volume, 0.3)
    automatic = jacobian(deformed.T.ravel()).full()
    numeric = tangent(deformed, MU, LAM, K1, K2, KF1, KF2, PHI).toarray()
    assert np.abs(numeric - automatic).max() < 1e-12 * np.abs(automatic).max()
    added = numeric - tangent(deformed, MU, LAM, K1, K2).toarray()
    assert np.abs(added).max() > 0.1 * np.abs(numeric).max()
    rest = np.zeros_like(deformed)
    assert np.array_equal(
        tangent(rest, MU, LAM, K1, K2, KF1, KF2, PHI).toarray(),
        tangent(rest, MU, LAM, K1, K2).toarray(),
    )


@pytest.mark.parametrize("stretch", [1.2, 0.85])
def test_homogeneous_stretch_along_and_across_the_fibres(stretch):
    """F = I + (lambda - 1) b b^T: along the fibres (b = a0) the fibre stress is
    2 W1 lambda a0 a0^T with e = lambda^2 - 1 in tension and zero in compression; across
    them (b perpendicular to a0 in the plane) it is zero."""
    with_fibres, without = piola_stress(True, True), piola_stress(True)
    a0 = np.array([np.cos(PHI), np.sin(PHI), 0.0])
    across = np.array([-np.sin(PHI), np.cos(PHI), 0.0])
    for direction, along in ((a0, True), (across, False)):
        h = (stretch - 1.0) * np.outer(direction, direction)
        fibre = (
            with_fibres(h.ravel(), MU, LAM, K1, K2, KF1, KF2, PHI).full()
            - without(h.ravel(), MU, LAM, K1, K2).full()
        ).reshape(3, 3)
        e = max(stretch**2 - 1.0, 0.0) if along else 0.0
        w1 = KF1 * e * np.exp(KF2 * e**2)
        expected = 2.0 * w1 * stretch * np.outer(a0, a0)
        assert np.abs(fibre - expected).max() < 1e-14 + 1e-12 * np.abs(expected).max()
        assert (np.abs(fibre).max() > 0) == (along and stretch > 1)


def test_fibre_model_without_fibres_is_the_exponential_model():
    """At kf1 = 0 the fibre model's equilibrium under a probe is the exponential
    model's, bit for bit; the models without the family refuse kf1 with one line."""
    from solvers.forward.equilibrium import EquilibriumSolver
    from symbolic.continuum_model import ExponentialModel, FibreModel, NeoHookeanModel
    from symbolic.loads import ProbeForce

    volume = box_volume((20.0, 20.0, 4.0), (7, 7, 3), (3, 3, 2))
    load = ProbeForce(np.array([0.2, 0.0, -0.3]), 3.0, uv=np.array([0.5, 0.5]))
    values = {"E": 20.0, "nu": 0.4, "k1": 20.0, "k2": 10.0}
    states = []
    for model in (
        ExponentialModel(volume, values),
        FibreModel(volume, {**values, "kf2": 7.0, "fibre_angle": 30.0}),
    ):
        states.append(EquilibriumSolver(model).solve(model.generalized_force(load)).positions)
    assert np.array_equal(states[0], states[1])
    stiffer = FibreModel(volume, {**values, "kf1": 50.0, "fibre_angle": 0.0})
    pulled = EquilibriumSolver(stiffer).solve(stiffer.generalized_force(load)).positions
    assert np.abs(pulled - stiffer.rest)[:, 0].max() < np.abs(states[0] - stiffer.rest)[:, 0].max()
    for model_class in (NeoHookeanModel, ExponentialModel):
        with pytest.raises(ValueError, match="no fibre family kf1"):
            model_class(volume, {"kf1": 1.0})
