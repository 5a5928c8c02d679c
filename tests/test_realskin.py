"""The real-skin extensometer study (``experiments/realskin``) on the shared loop.

Without data: the slab's closed-form Jacobians equal CasADi's AD, the DIC observation uses
x and y only, the slab's tensions, the overlap of a rectangle with the keloid's outline,
and the stiffer region the loop's family score test chose, read back in mm. With data
(``shared_data``), behind the slow marker: the whole study through
``solvers.diagnosis`` names strain stiffening on healthy skin and no region as a cause,
and on the keloid names a stiffer region on the outline or says why it cannot.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

from experiments.realskin.geometry import Rect
from experiments.realskin.skinfit import overlap, region_record, region_verdict
from experiments.realskin.slab import Pads, slab_volume, surface_uv
from solvers.inverse.problem import LoadCase, PlanarProblem
from solvers.inverse.space import ParameterSpace
from symbolic.constraints import BoundaryConditions
from symbolic.skin_slab import POISSON, SkinSlabModel
from symbolic.stiffening import exponential_stiffening

REGION = Rect(0.0, -5.0, 100.0, 45.0)
MOVING, FIXED = Rect(26.0, 16.0, 34.0, 24.0), Rect(66.0, 16.0, 74.0, 24.0)
STRIP = np.array([[30.0, 16.0], [70.0, 16.0], [70.0, 24.0], [30.0, 24.0]])


def small_model(boundary: BoundaryConditions, **options) -> tuple[SkinSlabModel, Pads]:
    """A 9 x 5 x 2 slab over the 100 x 50 mm region, pads of the healthy .geo."""
    pads = Pads.build(REGION, MOVING, FIXED, per_side=3)
    model = SkinSlabModel(
        slab_volume(REGION, 2.0, (9, 5)),
        {"alpha_u": 0.01, "alpha_w": 0.05, "k0": 0.3},
        boundary,
        prescribed=pads.prescribed,
        isotropic=True,
        **options,
    )
    return model, pads


@pytest.mark.parametrize(
    "boundary", [BoundaryConditions(True, False), BoundaryConditions(False, True)]
)
@pytest.mark.parametrize("names", [("alpha_u",), ("alpha_u", "k0"), ("alpha_u", "k0", POISSON)])
def test_closed_form_jacobian_equals_automatic_differentiation(boundary, names):
    model, pads = small_model(boundary, stiffening=exponential_stiffening)
    residual = model._residual(names)
    s, x, force, d = residual.mx_in()
    automatic = ca.Function("ad", [s, x, force, d], [ca.jacobian(residual(s, x, force, d), s)])
    rng = np.random.default_rng(1)
    state = rng.normal(scale=0.5, size=residual.size1_in(0))
    values = np.array([0.012, 0.4, 0.5])[: len(names)]
    args = (state, values, np.zeros((model.n_free, 3)), pads.displacement([-2.0, 0.1]))
    closed, d_x = model.jacobian_function(names)(*args)
    assert np.allclose(closed.full(), automatic(*args).full(), atol=1e-12)
    g_x = ca.Function("gx", [s, x, force, d], [ca.jacobian(residual(s, x, force, d), x)])
    assert np.allclose(d_x.full(), g_x(*args).full(), atol=1e-12)


def test_isotropic_tension():
    """T_x = alpha_u L_x / L_y and T_y = alpha_v L_y / L_x with alpha_v tied: equal."""
    model, _ = small_model(BoundaryConditions(True, False))
    tension_x, tension_y = model.membrane_tension(model.values({"alpha_u": 0.01}))
    assert tension_x == pytest.approx(0.02) and tension_y == pytest.approx(0.02)


def test_planar_problem_sees_x_and_y_but_not_z():
    model, pads = small_model(BoundaryConditions(True, False))
    points = np.array([[45.0, 18.0], [55.0, 22.0]])
    rows = model.volume.collocation(model.volume.outer_params(surface_uv(REGION, points)))
    case = LoadCase(
        force=np.zeros((model.n_free, 3)),
        rows=rows[:, model.free].tocsr(),
        offset=np.array([[0.1, -0.2, 5.0], [0.3, 0.0, -7.0]]),
        weights=np.ones(len(points)),
        prescribed=pads.displacement([-1.0, 0.0]),
        rest_points=rows @ model.rest,
        force_rows=sp.csr_matrix(model.point_force_rows(pads.moving_index)[:1]),
        force_target=np.array([-0.05]),
        force_weight=10.0,
    )
    problem = PlanarProblem(model, [case], ParameterSpace.create(("alpha_u",)))
    jacobian = problem.case_residual_jacobian(case)
    assert jacobian.shape == (2 * 2 + 1, problem.n_state)
    n = model.n_free
    assert abs(jacobian[:, 2 * n : 3 * n]).sum() == 0  # z of the control points is not seen
    assert np.allclose(problem.case_offset(case), [0.1, 0.3, -0.2, 0.0, 0.5])


def test_overlap_of_a_rectangle_with_a_polygon():
    """IoU, inside fraction and recall on the grid: a rectangle inside the strip, and
    one half over it (80 of its 160 mm^2 inside; the strip is 320 mm^2)."""
    inside = overlap((40.0, 50.0, 18.0, 22.0), STRIP)
    assert inside["inside_fraction"] == pytest.approx(1.0, abs=0.01)
    assert inside["recall"] == pytest.approx(40.0 / 320.0, abs=0.01)
    half = overlap((20.0, 40.0, 16.0, 24.0), STRIP)
    assert half["inside_fraction"] == pytest.approx(0.5, abs=0.01)
    assert half["iou"] == pytest.approx(80.0 / 400.0, abs=0.01)


def test_the_region_record_reads_the_rectangle_the_family_test_chose():
    """The rectangle (u, v) of the family score test of the round that named the region
    (or its best test when it was not named), in mm on the slab, its overlap with the
    outline and the verdict's reason."""
    from types import SimpleNamespace as NS

    geometry = NS(region=REGION, keloid=STRIP)
    setup = NS(case=NS(geometry=geometry))

    def test(statistic, rect):
        detail = {"rect_uv": rect}
        return {"effect": "stiffer_region", "statistic": statistic, "detail": detail}

    steps = [
        {"effect": None, "score_tests": [test(50.0, [0.3, 0.7, 0.42, 0.58])]},
        {"effect": "stiffer_region", "score_tests": [test(9.0, [0.0, 0.1, 0.0, 0.1])]},
    ]
    named = region_record(setup, {"steps": steps, "stand_ins": []})
    assert named["named"] and named["rect_mm"] == pytest.approx([30.0, 70.0, 16.0, 24.0])
    assert named["iou"] == pytest.approx(1.0, abs=0.02)
    assert "located" in region_verdict(named)
    stood = [{"effect": "stiffer_region", "reason": "ends at its bound (s_region)"}]
    record = region_record(setup, {"steps": steps[:1], "stand_ins": stood})
    assert not record["named"] and record["reason"] == stood[0]["reason"]
    assert "no stiffer region is named" in region_verdict(record)
    assert region_record(setup, {"steps": [{"effect": None, "score_tests": []}]}) is None
    healthy = NS(case=NS(geometry=NS(region=REGION, keloid=None)))  # no outline: the reason
    record = region_record(healthy, {"steps": steps[:1], "stand_ins": stood})
    assert "iou" not in record and region_verdict(record).endswith(stood[0]["reason"])


@pytest.mark.parametrize(
    "argv",
    [["--candidates", "gravity", "--out", "x"], ["--case", "scar", "--out", "x"], ["--nope"]],
)
def test_bad_study_command_line_is_one_line_and_exit_2(argv, capsys):
    from conftest import exit_code_and_stderr

    from experiments.realskin.skinfit import main

    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err


# ------------------------------------------------------------------------ the full study
@pytest.fixture(scope="module")
def study(shared_data, tmp_path_factory):
    from experiments.realskin.setup import RealSkinSettings
    from experiments.realskin.skinfit import run

    out = tmp_path_factory.mktemp("realskin")
    return run(out, RealSkinSettings(), log=lambda *_: None), out


def _document(out, name: str) -> dict:
    import json

    return json.loads((out / name / "diagnosis.json").read_text())


@pytest.mark.slow
@pytest.mark.realdata
def test_healthy_skin_names_stiffening_and_no_region_as_a_cause(study):
    """Healthy skin: strain stiffening is named first; no region is named (a stiffer
    rectangle, if found, is a stand-in); every added step predicts the left-out frames
    better (its left-out RMS before and after); the model error is stated against the
    DIC noise."""
    summary, out = study
    document = _document(out, "healthy")
    assert document["selected"][:1] == ["nonlinear_stiffening"], document["selected"]
    assert "stiffer_region" not in document["selected"] and document["region_iou"] is None
    for step in document["steps"][1:]:
        prediction = step["prediction"]
        assert prediction["rms_after_mm"] < prediction["rms_before_mm"]
    assert document["model_error"]["times_noise"] == pytest.approx(
        document["model_error_mm"] / document["noise_rms_mm"]
    )
    assert document["steps"][-1]["force_rms_N"] < 0.5 * document["steps"][0]["force_rms_N"]
    assert (out / "healthy" / "report.md").exists() and (out / "healthy" / "force.png").exists()


@pytest.mark.slow
@pytest.mark.realdata
def test_keloid_names_a_region_on_the_outline_or_says_why_not(study):
    """The keloid: a stiffer region is named with IoU >= 0.5 against the outline of
    geometry.geo, or the verdict gives the reason the loop could not locate it."""
    summary, out = study
    document = _document(out, "keloid")
    region = document["region"]
    assert region is not None and "iou" in region
    if document["region_iou"] is not None:
        assert document["region_iou"] >= 0.5, document["region_verdict"]
    else:
        assert region["reason"] or "not significant" in document["region_verdict"]
        assert document["region_verdict"].startswith("no stiffer region is named")


@pytest.mark.slow
@pytest.mark.realdata
def test_every_realskin_key_is_in_the_format_reference(study):
    """Both cases' diagnosis.json and summary.json: every key is named in docs/formats.md
    (the labels of fitted parameters, in the steps and the stand-ins, and the case names
    are data, not keys)."""
    import json

    from formatkeys import FORMATS, json_keys, undocumented

    summary, out = study
    text = FORMATS.read_text()
    for name in ("healthy", "keloid"):
        document = _document(out, name)
        fitted = [*document["steps"], *document["stand_ins"]]  # parameter names are data
        labels = {label for record in fitted for label in record.get("parameters") or {}}
        assert not undocumented(json_keys(document), text, labels), name
    written = json.loads((out / "summary.json").read_text())
    assert not undocumented(json_keys(written), text, {"healthy", "keloid"})
