"""Issue 40's acceptance: default ``dvs diagnose`` on tissue the model was not tuned on.

The data are FE patches from the generator the model was not tuned on
(``experiments.phantom.tissue``): the tissue goes on beyond the markers by an amount
the dataset does not declare and is held there in ways it does not declare, the probe's
radius is not in the file, the marker grid is not square. The rows are those of the
tables in docs/results/tissue-defaults.md (docs/stepzero.md, "Tissue the model was not
tuned on", describes the data).

They are the strong form the issue asks for: the named effect (or only physics the data
have), never a stand-in at any step, and explained at <= 1.1x the noise level. Written
before the fix as strict expected failures; step 0 (``experiments.basemodel``) and the
layering effect made rows A, D, G and the slab pass, and the probe's shape (step 0's
``checked_shape``) row E: with the model's Gaussian patch the loop added layering
there for what was the FE probe's disc.
"""

from __future__ import annotations

import pytest

from experiments.diagnosis.diagnose import diagnose_dataset
from experiments.diagnosis.tissuedefaults import ROWS as ROWS_ALL
from experiments.diagnosis.tissuedefaults import injected_scenarios, row_dataset

PHYSICAL = frozenset(
    {"contact_patch", "surrounding_tissue", "volumetric_coupling", "shear_coupling"}
)
"""Terms every such patch has: a probe of finite size, tissue beyond the markers, the
continuum's volume and shear coupling. Anything else added without an injected effect
is a stand-in (rigid motion, a per-capture scale, a stiffening, a pre-tension, ...)."""

ROWS = {name: ROWS_ALL[name] for name in ("A", "D", "E")}
"""Rows A, D and E of the table (no effect injected)."""


def _diagnosed(name: str) -> dict:
    data = row_dataset(name)
    assert data.probe_radius is None  # the radius is not declared
    return diagnose_dataset(data).document()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ROWS))
def test_without_an_effect_the_defaults_explain_tissue_with_physics_only(name):
    """No effect injected: explained at <= 1.1x the noise, only physical terms added."""
    document = _diagnosed(name)
    assert set(document["selected"]) <= PHYSICAL, document["selected"]
    assert document["unexplained"] is False
    assert document["rms_after_mm"] <= 1.1 * document["noise_rms_mm"]


@pytest.mark.slow
def test_a_bilayer_is_named_as_layering_or_left_unexplained_without_stand_ins():
    """A bilayer is named (a layering effect) or left unexplained; never heterogeneity
    or base_compliance, and no stand-in at any step."""
    document = _diagnosed("G")
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


NOT_NAMED: dict[str, str] = {}
"""Injected rows that fail the strong form, with the measured reason. tilted_force was
one until the probe's shape was estimated (``experiments.basemodel.choice.checked_shape``):
with the model's Gaussian patch, chi^2 stayed 2785/2531 after force_direction and layering
stood in; with the disc step 0 now keeps, force_direction alone ends at 2686/2531.
stiffness_gradient was one at a557cd9 (the fits kept stable): step 0 kept the Gaussian
(the disc better by chi^2 5, below 6.6), the revisit compared shapes only while the
residual was significant, and layering stood in for the disc after heterogeneity; the
revisit now always compares them (the disc by 54 with heterogeneity in)."""


@pytest.mark.slow
@pytest.mark.parametrize(
    "injected",
    [
        pytest.param(
            name,
            marks=[pytest.mark.xfail(strict=True, raises=AssertionError, reason=NOT_NAMED[name])]
            if name in NOT_NAMED
            else [],
        )
        for name in sorted(injected_scenarios())
    ],
)
def test_one_injected_effect_is_named_first_and_nothing_stands_in(injected):
    """Row A's patch with one departure, 10 loads: the effect that names it is the first
    selected, nothing but physics follows it at any step, and the RMS ends at <= 1.1x
    the noise (the surroundings re-estimated with it in, ``experiments.basemodel.revisit``).
    The verdict may stay "unexplained": the issue asks for the name, not for noise."""
    effect = injected_scenarios()[injected][2]
    document = diagnose_dataset(row_dataset("A", injected)).document()
    assert document["selected"][:1] == [effect], document["selected"]
    assert set(document["selected"][1:]) <= PHYSICAL, document["selected"]
    assert document["rms_after_mm"] <= 1.1 * document["noise_rms_mm"]


PAPER_DESIGN_FAST = ("compliant_base", "contact_offset", "larger_probe_patch", "stiffness_gradient")
"""Row C's departures on which step 0 keeps the paper's energy (seconds each)."""


def _named_or_not_ruled_out(injected: str) -> None:
    effect = injected_scenarios()[injected][2]
    document = diagnose_dataset(row_dataset("C", injected)).document()
    listed = {spot["effect"] for spot in document["blind_spots"]}
    rivals = {name for names in document["rivals"].values() for name in names}
    named = effect in set(document["selected"]) | rivals
    assert named or (not document["unexplained"] and effect in listed), (
        document["selected"],
        sorted(listed),
    )


@pytest.mark.parametrize("injected", PAPER_DESIGN_FAST)
def test_on_the_papers_two_loads_each_effect_is_named_or_not_ruled_out(injected):
    """Issue 40, point 5 on the paper's 2-load design (row C): the injected effect is
    selected, a rival of the selected one, or listed by the explained verdict as not
    ruled out (this design's power against it below 0.8, ``solvers.diagnosis.blind``).
    Before the blind spots, four of six ended "explained" with nothing said of them."""
    _named_or_not_ruled_out(injected)


@pytest.mark.slow
@pytest.mark.parametrize("injected", ("rigid_motion", "tilted_force"))
def test_on_the_papers_two_loads_the_measurable_effects_are_named(injected):
    """The two departures row C's design can see are named (the continuum, 35-222 s)."""
    _named_or_not_ruled_out(injected)
