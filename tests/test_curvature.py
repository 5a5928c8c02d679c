"""The force curvature of the hyperelastic energies and the simultaneous NLP's derivatives
built from it (symbolic/curvature.py, solvers/inverse/lagrangian.py).

- d2(w . f)/dDelta2 assembled in numpy equals CasADi's AD Hessian of the force of
  eq. (C8), for the neo-Hookean, exponential and fibre stresses;
- for a neo-Hookean (and an exponential, supported, pad-held) inverse problem, the
  simultaneous NLP's Hessian of the Lagrangian and constraint Jacobian equal AD's.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from conftest import nlp_derivatives
from volumes import curved_volume

from symbolic.continuum import PhysicalGradient, box_volume, lame
from symbolic.curvature import ForceCurvature
from symbolic.hyperelastic import NeoHookeanForce, NeoHookeanTangent

MU, LAM = lame(20.0, 0.4)
COEFFICIENTS = {
    "neo-hookean": (MU, LAM),
    "exponential": (MU, LAM, 5e-3, 20.0),
    "fibres": (MU, LAM, 5e-3, 20.0, 8e-3, 10.0, 0.5),
}


@pytest.mark.parametrize("energy", list(COEFFICIENTS))
def test_force_curvature_matches_automatic_differentiation(energy):
    """On every control point of a curved slab at a 20 % random state."""
    volume = curved_volume()
    exponential, fibres = energy != "neo-hookean", energy == "fibres"
    gradient = PhysicalGradient.of(volume)
    n = volume.basis.size
    force = NeoHookeanForce(gradient.operators, gradient.volume, exponential, fibres)
    tangent = NeoHookeanTangent(
        volume.collocation(gradient.points), gradient.operators, gradient.volume, np.arange(n)
    )
    state, weight = ca.MX.sym("s", 3 * n), ca.MX.sym("w", 3 * n)
    work = ca.dot(weight, ca.vec(force(ca.reshape(state, n, 3), *COEFFICIENTS[energy])))
    hessian = ca.Function("H", [state, weight], [ca.hessian(work, state)[0]])
    rng = np.random.default_rng(2)
    delta, multipliers = 0.2 * rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    automatic = hessian(delta.T.ravel(), multipliers.T.ravel()).full()
    curvature = ForceCurvature(tangent, exponential, fibres)
    numeric = curvature(delta, multipliers, *COEFFICIENTS[energy]).toarray()
    assert np.abs(automatic).max() > 0
    assert np.abs(numeric - automatic).max() < 1e-10 * np.abs(automatic).max()


def slab_problem(energy: str):
    """Two probe loads on a 20 x 16 x 3 mm slab with random markers; ``exponential``
    adds a foundation and two held pads (prescribed rows)."""
    from solvers.inverse.problem import InverseProblem, observation_case
    from solvers.inverse.space import ParameterSpace
    from symbolic.continuum_model import ENERGIES
    from symbolic.loads import PrescribedDisplacement, ProbeForce

    volume = box_volume((20.0, 16.0, 3.0), (6, 5, 3), (3, 3, 2))
    values = {"E": 20.0, "nu": 0.4, "k1": 5.0, "k2": 2.0}
    if energy == "neo-hookean":
        model, names = ENERGIES[energy](volume, {"E": 20.0, "nu": 0.4}), ("E", "nu")
        prescribed = None
    else:
        pads = PrescribedDisplacement(np.array([[0.1, 0.5], [0.9, 0.5]]))
        model = ENERGIES[energy](volume, values, prescribed=pads, support=1e-3)
        names, prescribed = ("E", "nu", "k1", "k2"), np.zeros((2, 3))
    rng = np.random.default_rng(4)
    uv = rng.uniform(0.1, 0.9, size=(12, 2))
    rest = volume.collocation(volume.outer_params(uv)) @ model.rest
    cases = [
        observation_case(
            model,
            ProbeForce(np.array([0.0, 0.0, -f]), 3.0, uv=np.array([0.5, 0.5])),
            rest + rng.normal(0.0, 0.05, rest.shape),
            uv,
            prescribed=prescribed,
        )
        for f in (0.05, 0.1)
    ]
    space = ParameterSpace.create(names, start={k: values[k] for k in names})
    return InverseProblem(model, cases, space, 0.02)


@pytest.mark.parametrize("energy", ["neo-hookean", "exponential"])
def test_simultaneous_derivatives_equal_automatic_differentiation(energy):
    """The NLP's structured d2L/dv2 and dg/dv against CasADi's AD of the same NLP."""
    from solvers.inverse.simultaneous import SimultaneousSolver

    problem = slab_problem(energy)
    solver = SimultaneousSolver(problem)
    v, expected, structured, reference = nlp_derivatives(solver, 0.05, 0.1)
    assert np.abs(structured - expected).max() < 1e-10 * np.abs(expected).max()
    difference = solver.jacobian(v, [])[1].sparse() - reference
    assert abs(difference).max() < 1e-12 * abs(reference).max()
