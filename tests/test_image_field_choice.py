"""``dvs image`` chooses its field from the data when ``--field`` is not given.

The rule (``experiments.imaging.fieldchoice``): nodes half a marker spacing apart over the
volume imaged on, at most ``AUTO_MAX_SIZE`` coefficients. The fast tests check the rule's
properties on made-up geometries; the slow ones run the default ``dvs image`` (step 0's
continuum, GCV's weight, the chosen field) on the project's scikit-fem disc data
(docs/imaging.md, "The field's size") and check that the map's peak (image.json's
``peak_mm``, the stiffest point over the markers) lies within 3 mm of the disc.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from experiments.imaging.fieldchoice import (
    AUTO_MAX_SIZE,
    SPACING_OF_MARKERS,
    choose_field,
    describe,
    layout_shape,
)

GEOMETRIES = [
    (5.0, (60.0, 60.0, 5.0)),  # 9 x 9 markers over 40 mm and a 10 mm band
    (5.0, (20.0, 10.0, 5.0)),  # a small patch
    (3.0, (26.0, 20.0, 4.0)),  # 5 x 4 markers 3 mm apart and a 4 mm band
    (1.0, (100.0, 50.0, 5.0)),  # dense markers over a long strip
    (12.0, (90.0, 70.0, 8.0)),  # sparse markers
]


@pytest.mark.parametrize("over", ["surface", "layers", "volume"])
@pytest.mark.parametrize("spacing, lengths", GEOMETRIES)
def test_the_rule_takes_the_finest_field_up_to_half_a_marker_spacing_that_fits(
    spacing, lengths, over
):
    choice = choose_field(spacing, lengths, over)
    shape = tuple(choice["shape"])
    assert choice["rule"] == "auto" and len(shape) == (2 if over == "surface" else 3)
    assert math.prod(shape) <= AUTO_MAX_SIZE and min(shape[:2]) >= 2
    target = SPACING_OF_MARKERS * spacing
    assert choice["target_spacing_mm"] == pytest.approx(target)
    nodes = choice["spacing_mm"][:2]
    if not choice["capped"]:
        # one node's hat (2 h) no wider than the marker spacing, along u and v
        assert max(nodes) <= target * (1 + 1e-9)
    else:
        # the finest that fits: no equal spacing from the target up to the chosen one does
        assert max(nodes) > target
        for finer in np.linspace(target, max(nodes) * (1 - 1e-6), 101):  # past the rule's 1e-9
            assert math.prod(layout_shape(lengths, finer, over)) > AUTO_MAX_SIZE
    # no finer than that: one node fewer along u or v would leave a gap over it
    for axis in (0, 1):
        assert shape[axis] == 2 or lengths[axis] / (shape[axis] - 2) > max(target, max(nodes))


def test_denser_markers_and_a_larger_volume_never_give_a_coarser_field():
    lengths = (60.0, 50.0, 5.0)
    sizes = [math.prod(choose_field(s, lengths)["shape"]) for s in (20.0, 12.0, 8.0, 5.0, 2.0)]
    assert sizes == sorted(sizes) and sizes[0] < sizes[-1] == max(sizes)
    spacing = [choose_field(12.0, (L, L, 5.0))["shape"][0] for L in (20.0, 40.0, 80.0)]
    assert spacing == sorted(spacing) and spacing[0] < spacing[-1]


def test_the_layouts_keep_their_least_counts_through_the_thickness():
    thin = (40.0, 40.0, 0.5)
    assert layout_shape(thin, 5.0, "layers")[2] == 2  # one layer would be the surface field
    assert layout_shape(thin, 5.0, "volume")[2] == 2
    assert layout_shape((40.0, 40.0, 10.0), 2.5, "layers")[2] == 4


def test_a_larger_size_allows_a_finer_field_and_the_record_says_why():
    small = choose_field(5.0, (60.0, 60.0, 5.0), max_size=64)
    large = choose_field(5.0, (60.0, 60.0, 5.0), max_size=10_000)
    assert small["capped"] and not large["capped"]
    assert max(large["spacing_mm"]) <= 2.5 + 1e-9 < max(small["spacing_mm"])
    assert "64 coefficients" in small["reason"] and "coefficients" not in large["reason"]
    line = describe(small)
    assert "x".join(map(str, small["shape"])) in line and "auto" in line
    with pytest.raises(ValueError):
        choose_field(0.0, (60.0, 60.0, 5.0))


def test_the_command_defaults_to_the_rule_and_keeps_an_explicit_field():
    from experiments.imaging.command import build_parser, image_settings

    def settings(*options):
        return image_settings(build_parser().parse_args(["d.npz", "--out", "o", *options]))[0]

    assert settings().shape == "auto"
    assert settings("--over", "layers").shape == "auto"
    assert tuple(settings("--field", "8x6").shape) == (8, 6)


# --- the default dvs image on the project's FE disc data (slow: step 0 and the map) ---

SEEDS = (101, 202, 303)
"""Disc places drawn by ``inclusion_datasets``, chosen before the runs and not used to
design the rule (its one parameter, half a marker spacing, is not fitted to any place).
Measured (docs/imaging.md, "The field's size"): 2.4, 0.5 and 1.8 mm."""


def _default_image(dataset, folder) -> dict:
    """``dvs image FILE --out DIR`` with no option but the output; image.json."""
    from experiments.command.cli import main as dvs
    from experiments.data.dataset import save_dataset

    path = folder / "disc.npz"
    save_dataset(path, dataset)
    out = folder / "image"
    assert dvs(["image", str(path), "--out", str(out)]) == 0
    return json.loads((out / "image.json").read_text())


def _check_peak(record: dict, centre) -> float:
    """Distance [mm] of the map's peak from ``centre``; infinite for a flat map (the
    weight found no field: its stiffest point is rounding, and locates nothing)."""
    choice = record["field_choice"]
    assert choice["rule"] == "auto" and record["field"]["shape"] == choice["shape"]
    assert math.prod(choice["shape"]) <= AUTO_MAX_SIZE
    if record["weight"]["note"] == "the data need no field":
        return math.inf
    return float(np.linalg.norm(np.array(record["peak_mm"]) - np.asarray(centre)))


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_the_default_map_finds_the_disc_at_a_random_place(seed, tmp_path, capsys):
    """The acceptance disc (E x 2, 8 mm, 10-load design, 0.02 mm noise) at a place drawn
    from ``seed``: the default map's peak within 3 mm of its centre. About 30 s a seed
    where step 0 keeps a 23x23x5 volume (202, 303); about 2 min where it refines to
    38x38x6 (101)."""
    from experiments.imaging.weightstudy import inclusion_datasets

    disc, _, centre = inclusion_datasets(seed)
    record = _default_image(disc, tmp_path)
    assert "field auto" in capsys.readouterr().out
    assert _check_peak(record, centre) <= 3.0


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="information, not the field: at the edge the 10-load design barely sees the "
    "disc, and GCV keeps 4 effective dof (E 20.5-21.6 kPa, contrast 1.03), peak 5.7 mm "
    "from it (Morozov: 76 dof, E 5-84 kPa, 33.8 mm; docs/imaging.md, 'Which weight')",
)
def test_the_default_map_finds_a_disc_near_the_edge_of_the_markers(tmp_path):
    """The same disc 3 mm inside the markers' edge (x = 17 mm; the 9 x 9 markers span
    +-20 mm), built as ``inclusion_datasets`` builds its places (about 1 min)."""
    from experiments.imaging.weightstudy import DIAMETER_MM, RATIO, study_cases
    from experiments.phantom.fe import ReferenceSlab, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    centre = (17.0, -6.0)
    slab = ReferenceSlab(elements=(24, 24, 4), inclusion=(*centre, DIAMETER_MM, RATIO))
    forces, contacts = study_cases(slab)
    measurement = SimulationSettings(noise_mm=0.02, seed=404)
    disc = reference_dataset(slab, forces, contacts, 4.0, (9, 9), measurement)
    assert _check_peak(_default_image(disc, tmp_path), centre) <= 3.0
