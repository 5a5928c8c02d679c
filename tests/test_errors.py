"""Bad input to every public constructor gives a ValueError that names the problem."""

import numpy as np
import pytest

from experiments.phantom.forehead import PhantomSettings, forehead_model, segmented_surfaces
from solvers.forward.equilibrium import EquilibriumSolver, NewtonSettings
from symbolic.basis import BSplineBasis, VolumeBasis
from symbolic.constraints import BoundaryConditions
from symbolic.loads import PointForce, PrescribedDisplacement, ProbeForce
from symbolic.model import TissueModel
from symbolic.volume import VolumeSpline

GOOD = segmented_surfaces()


def nan_points():
    bad = GOOD.copy()
    bad[3, 4, 1, 2] = np.nan
    return bad


CASES = [
    (lambda: BSplineBasis(-1, 4), "degree"),
    (lambda: BSplineBasis(3, 3), "n_control"),
    (lambda: BSplineBasis(3, 5).evaluate([0.5, 1.5]), r"\[0, 1\]"),
    (lambda: VolumeBasis((4, 4), (3, 3, 1)), "three entries"),
    (lambda: VolumeBasis((4, 4, 2), (3, 3, 1), weights=-np.ones((4, 4, 2))), "positive"),
    (lambda: VolumeBasis((4, 4, 2), (3, 3, 1), weights=np.ones((4, 4, 3))), "weights"),
    (lambda: VolumeBasis((4, 4, 2), (1, 1, 1)).collocation(np.zeros((3, 2))), r"\(n, 3\)"),
    (lambda: VolumeSpline(VolumeBasis((4, 4, 2), (3, 3, 1)), np.zeros((5, 3))), "control_points"),
    (lambda: VolumeSpline.fit(GOOD[..., :2]), r"\(U, V, K, 3\)"),
    (lambda: VolumeSpline.fit(nan_points()), "NaN"),
    (lambda: VolumeSpline.fit(GOOD[:5, :5], (9, 9, 2)), "cannot determine"),
    (lambda: VolumeSpline.fit(GOOD[:, :8], (9, 9, 2)), "rank deficient in v"),
    (lambda: VolumeSpline.fit(GOOD, (9, 9, 2), parameterization="foo"), "parameterization"),
    (lambda: PointForce([0, 0], uv=[0.5, 0.5]), "force"),
    (lambda: PointForce([0, 0, np.nan], uv=[0.5, 0.5]), "force"),
    (lambda: ProbeForce([0, 0, -1], radius=0.0, uv=[0.5, 0.5]), "radius"),
    (lambda: PrescribedDisplacement(np.array([[0.5, 1.5]])), r"\[0, 1\]"),
    (lambda: PrescribedDisplacement(np.zeros((0, 2))), "shape"),
    (lambda: TissueModel(forehead_model().volume, {"alpha_x": 1.0}), "unknown parameters"),
    (lambda: TissueModel(forehead_model().volume, {"alpha_u": -1.0}), "alpha_u"),
    (lambda: TissueModel(forehead_model().volume, {"mu": np.inf}), "mu"),
    (lambda: TissueModel("not a volume"), "VolumeSpline"),
    (
        lambda: TissueModel(
            VolumeSpline.fit(GOOD, (2, 2, 2), (1, 1, 1))[0], boundary=BoundaryConditions(True, True)
        ),
        "every control point is fixed",
    ),
    (lambda: PhantomSettings(thickness=-5.0), "thickness"),
    (lambda: PhantomSettings(width=500.0), "width"),
    (lambda: NewtonSettings(tolerance=0.0), "tolerance"),
    (lambda: NewtonSettings(max_iterations=0), "max_iterations"),
    (lambda: EquilibriumSolver(forehead_model(), ("alpha_u", "alpha_u")), "distinct"),
]


@pytest.mark.parametrize("build,message", CASES, ids=[c[1] for c in CASES])
def test_bad_input_raises_value_error_naming_the_problem(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_point_force_contact_given_twice_is_rejected():
    model = forehead_model()
    load = PointForce([0, 0, -0.25], uv=[0.5, 0.5], point=[0, 0, 0])
    with pytest.raises(ValueError, match="not both"):
        load.generalized(model.volume)


def test_solver_rejects_wrong_number_of_parameter_values():
    model = forehead_model()
    solver = EquilibriumSolver(model, ("alpha_u",))
    with pytest.raises(ValueError, match="expected 1 values"):
        solver.solve(np.zeros((model.n_free, 3)), [1.0, 2.0])
