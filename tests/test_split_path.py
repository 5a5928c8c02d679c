"""The split path (``solvers.diagnosis.splitpath``) against the cases' CasADi Functions.

For a base linear in the state with nonlinear_stiffening, Newton's g, dg/ds, the
implicit-function Jacobian's dg/dp and the observation are assembled in numbers: K(p)
from the unit terms, the stiffening force from ``NumericStiffening``. These tests hold
every piece against the CasADi Functions of ``CaseFunctions`` (which stay the reference
and the path of every other effect set), on the paper's energy and on the real skin's
slab with its prescribed pads.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp
from effectchecks import simulated_setting
from test_extensometer_problem import synthetic_setting

from solvers.diagnosis import splitpath
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import fit
from symbolic.effects.base import Effect
from symbolic.effects.declaration import Parameter
from symbolic.effects.nonlinearity import _stiffening

PAPER_SETS = (
    ("nonlinear_stiffening",),
    ("nonlinear_stiffening", "heterogeneity"),
    ("base_compliance", "nonlinear_stiffening"),
    ("rigid_motion", "nonlinear_stiffening", "force_direction"),
    ("contact_patch", "nonlinear_stiffening", "measurement_scale"),
)
"""The stiffening with a field, extra state, per-case observation and load effects."""


@pytest.fixture(scope="module")
def paper():
    """A simulated dataset on the paper's energy (k0 = 0), its base fit, the library."""
    return simulated_setting()


@pytest.fixture(scope="module")
def slab():
    """The synthetic two-pad extensometer of ``test_extensometer_problem``."""
    return synthetic_setting(
        ("nonlinear_stiffening", "volumetric_coupling", "anisotropy", "stiffer_region")
    )


def _dense(value) -> np.ndarray:
    return value.toarray() if sp.issparse(value) else np.asarray(value)


def _relative(a, b) -> float:
    a, b = _dense(a), _dense(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def _agrees(problem: ExtendedProblem, base_p: np.ndarray, k0: float) -> None:
    """Every piece of the split path of each case equals its CasADi Function's at a
    state off equilibrium, to rounding."""
    assert problem.extended.split_part() is not None and not problem.linear_state
    theta = problem.scale[base_p.size :] / 3.0
    p = np.clip(np.concatenate([base_p, theta]), problem.lower, problem.upper)
    p[problem.slice_of("nonlinear_stiffening")] = k0
    rng = np.random.default_rng(4)
    for position in range(len(problem.positions)):
        state = rng.normal(0.0, 0.2, problem.extended.n_state)
        residual, jacobian = splitpath.equations(problem, position, p)
        g, tangent = problem.numeric(position, "newton")(state, p)
        assert _relative(residual(state), g.ravel()) < 1e-13
        mine = jacobian(state)
        assert _relative(mine, tangent) < 1e-13
        assert mine.format == "csc" and mine.has_sorted_indices
        expected = problem.numeric(position, "sensitivity")(state, p)
        for piece, reference in zip(splitpath.sensitivity(problem, position, state, p), expected):
            assert _relative(piece, reference) < 1e-12
        r = problem.numeric(position, "residual")(state, p)[0]
        assert _relative(splitpath.residual(problem, position, state, p), r.ravel()) < 1e-14


@pytest.mark.parametrize("names", PAPER_SETS, ids="+".join)
def test_split_path_equals_the_case_functions(paper, names):
    """g, dg/ds, dg/dp, r, dr/ds and dr/dp on the paper's energy."""
    problem, base_fit, library = paper
    _agrees(problem.with_effects([library[n] for n in names]), base_fit.p, 80.0)


@pytest.mark.parametrize(
    "names",
    [("nonlinear_stiffening",), ("nonlinear_stiffening", "anisotropy", "volumetric_coupling")],
    ids="+".join,
)
def test_split_path_with_the_pads_multipliers(slab, names):
    """The same on the extensometer's slab, whose state ends in the pads' multipliers."""
    problem, base_fit, library = slab
    _agrees(problem.with_effects([library[n] for n in names]), base_fit.p, 0.5)


def test_split_path_with_a_stiffer_region(slab):
    """The stiffening beside a region effect, both active (a rectangle chosen)."""
    problem, base_fit, library = slab
    region = library["stiffer_region"]
    region.choose((0.25, 0.6, 0.2, 0.8))
    _agrees(problem.with_effects([library["nonlinear_stiffening"], region]), base_fit.p, 0.5)


def test_the_split_paths_fit_is_newtons_on_the_case_functions(slab, monkeypatch):
    """A fit with the stiffening lands where the same fit on the cases' CasADi Functions
    lands (the split part switched off), and so do its states and Jacobian."""
    problem, base_fit, library = slab
    effects = [library["nonlinear_stiffening"]]
    start = np.r_[base_fit.p, 0.3]
    split = fit(problem.with_effects(effects), start)
    reference = problem.with_effects(effects)
    reference.forget_solves()
    monkeypatch.setattr(type(reference.extended), "split_part", lambda self: None)
    whole = fit(reference, start)
    assert _relative(split.p, whole.p) < 1e-8
    assert _relative(split.jacobian, whole.jacobian) < 1e-7
    for mine, theirs in zip(split.states, whole.states):
        assert _relative(mine, theirs) < 1e-8


def test_numeric_stiffening_is_the_casadi_stiffening(paper):
    """``NumericStiffening``'s F, dF/dDelta and dF/d(c, k, kb) against the CasADi force,
    its tangent and its custom Jacobian, at a model k0 that is not zero."""
    problem, _, library = paper
    model = problem.model
    effect = library["nonlinear_stiffening"]
    _, numeric = effect.numeric_force(model, model.values(), ca.MX.sym("k0", 1))
    force, tangent = _stiffening(model)
    rng = np.random.default_rng(1)
    delta = rng.normal(0.0, 0.2, (model.n_free, 3))
    c = np.r_[2.6, 0.18, 1.7, rng.uniform(0.0, 0.3, len(model.terms) - 3)]
    q = np.r_[c, 80.0, 5.0]
    args = (delta, c, 80.0, 5.0)
    assert _relative(numeric.force(delta, q), np.array(force(*args)).T.ravel()) < 1e-14
    assert _relative(numeric.tangent(delta, q), tangent(*args).sparse()) < 1e-14
    jacobian = force.jacobian()(*args, force(*args))
    columns = np.column_stack([np.array(jacobian[1]), np.array(jacobian[2]), np.array(jacobian[3])])
    assert _relative(numeric.slope(delta, q), columns) < 1e-14


class _CubicSpring(Effect):
    """An internal force without a numeric form (the test's own)."""

    name = "cubic_spring"
    parameters = (Parameter("t", "1", 1.0, -1.0, 1.0),)

    def internal_force(self, model, symbols, theta):
        return theta[0] * symbols.delta**3


def test_a_force_without_numbers_keeps_the_case_functions(paper):
    """An effect whose force has no ``numeric_force`` keeps the CasADi path, and so does a
    set of unit terms alone (the linear path's)."""
    problem, _, library = paper
    assert problem.with_effects([_CubicSpring()]).extended.split_part() is None
    assert problem.with_effects([library["heterogeneity"]]).extended.split_part() is None
    mixed = problem.with_effects([library["nonlinear_stiffening"], _CubicSpring()])
    assert mixed.extended.split_part() is None


def test_pattern_sum_is_the_sum_on_the_union_of_patterns():
    """``PatternSum`` equals scipy's sum for CSR + CSC, keeps sums of one pair of
    patterns on one union, and starts again when a pattern changes."""
    rng = np.random.default_rng(0)
    a = sp.random(40, 40, 0.1, "csr", random_state=rng)
    b = sp.random(40, 40, 0.1, "csc", random_state=rng)
    adder = splitpath.PatternSum()
    total = adder(a, b)
    assert total.format == "csc" and _relative(total, a + b) == 0.0
    again = adder(2.0 * a, b)
    assert np.array_equal(again.indices, total.indices)
    assert _relative(again, 2.0 * a + b) == 0.0
    c = sp.random(40, 40, 0.2, "csr", random_state=rng)
    assert _relative(adder(c, b), c + b) == 0.0
