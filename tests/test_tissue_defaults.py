"""Issue 40's acceptance: default ``dvs diagnose`` on tissue the model was not tuned on.

The data are FE patches from the generator the model was not tuned on
(``experiments.phantom.tissue``): the tissue goes on beyond the markers by an amount
the dataset does not declare and is held there in ways it does not declare, the probe's
radius is not in the file, the marker grid is not square. The rows are those of the
table in docs/continuum.md ("Tissue the model was not tuned on").

They are the strong form the issue asks for: the named effect (or only physics the data
have), never a stand-in at any step, and explained at <= 1.1x the noise level. Written
before the fix as strict expected failures; step 0 (``experiments.basemodel``) and the
layering effect made rows A, D, G and the slab pass. Row E (curved, 8 mm, 10 mm free)
still fails: the resolution check stops at its budget before the predicted markers
converge, and the loop then adds layering for the discretisation's share.
"""

from __future__ import annotations

import pytest

from experiments.diagnosis.diagnose import diagnose_dataset

PHYSICAL = frozenset(
    {"contact_patch", "surrounding_tissue", "volumetric_coupling", "shear_coupling"}
)
"""Terms every such patch has: a probe of finite size, tissue beyond the markers, the
continuum's volume and shear coupling. Anything else added without an injected effect
is a stand-in (rigid motion, a per-capture scale, a stiffening, a pre-tension, ...)."""

UNCONVERGED = (
    "issue 40: on row E the resolution check's next volume (70x59x8) is over its budget, "
    "the adopted one moves the markers by chi2 92 against 6.6, and layering stands in"
)

ROWS = {  # name: (TissuePatch fields, design, markers, probe, radius [mm])
    "A": (
        dict(marked=(40.0, 30.0), extent_mm=5.0, thickness=5.0, poisson=0.45, support="clamped"),
        "diagnosis",
        (11, 8),
        "disc",
        2.5,
    ),
    "D": (
        dict(
            marked=(40.0, 30.0),
            extent_mm=5.0,
            thickness=7.0,
            poisson=0.47,
            support="elastic",
            curvature_radii=(60.0, 90.0),
        ),
        "corners",
        (11, 8),
        "disc",
        3.0,
    ),
    "E": (
        dict(
            marked=(40.0, 30.0),
            extent_mm=10.0,
            thickness=8.0,
            poisson=0.45,
            support="free",
            curvature_radii=(80.0, 80.0),
        ),
        "diagnosis",
        (11, 8),
        "disc",
        2.0,
    ),
}
"""Rows A, D and E of the baseline table (no effect injected)."""

BILAYER = (
    dict(
        marked=(40.0, 30.0),
        extent_mm=5.0,
        thickness=6.0,
        poisson=0.45,
        support="clamped",
        skin_mm=1.5,
        skin_ratio=5.0,
    ),
    "diagnosis",
    (11, 8),
    "disc",
    2.5,
)
"""Row G: a 1.5 mm skin 5x stiffer than the fat below."""


def _diagnosed(row, seed: int) -> dict:
    pytest.importorskip("skfem")
    from experiments.phantom.simulate import SimulationSettings
    from experiments.phantom.tissue import TissuePatch, tissue_cases, tissue_dataset

    fields, design, markers, probe, radius = row
    patch = TissuePatch(layers=4, **fields)
    forces, contacts = tissue_cases(design, patch)
    measurement = SimulationSettings(noise_mm=0.02, seed=seed)
    data = tissue_dataset(patch, forces, contacts, radius, markers, probe, measurement=measurement)
    assert data.probe_radius is None  # the radius is not declared
    return diagnose_dataset(data).document()


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        pytest.param(
            name,
            marks=[pytest.mark.xfail(strict=True, raises=AssertionError, reason=UNCONVERGED)]
            if name == "E"
            else [],
        )
        for name in sorted(ROWS)
    ],
)
def test_without_an_effect_the_defaults_explain_tissue_with_physics_only(name):
    """No effect injected: explained at <= 1.1x the noise, only physical terms added."""
    document = _diagnosed(ROWS[name], seed=sorted(ROWS).index(name))
    assert set(document["selected"]) <= PHYSICAL, document["selected"]
    assert document["unexplained"] is False
    assert document["rms_after_mm"] <= 1.1 * document["noise_rms_mm"]


@pytest.mark.slow
def test_a_bilayer_is_named_as_layering_or_left_unexplained_without_stand_ins():
    """A bilayer is named (a layering effect) or left unexplained; never heterogeneity
    or base_compliance, and no stand-in at any step."""
    document = _diagnosed(BILAYER, seed=6)
    selected = set(document["selected"])
    assert not selected & {"heterogeneity", "base_compliance"}
    assert selected <= PHYSICAL | {"layering"}, document["selected"]
    assert "layering" in selected or document["unexplained"]


def test_out_of_library_data_get_no_stand_in_at_any_step():
    """The strong form of test_diagnosis's out-of-library check (FE slab, stiff skin on
    soft fat, point probe, the paper's design): only physics the slab has may be added
    (its skin layer included), explained or not. Before step 0 measurement_scale was
    added first and the verdict was unexplained, which the weak check accepted."""
    from experiments.diagnosis.outoflibrary import simulate_slab

    document = diagnose_dataset(simulate_slab(seed=0)).document()
    assert document["base_choice"]["chosen"] == "linear-elastic"
    assert set(document["selected"]) <= PHYSICAL | {"layering"}, document["selected"]
