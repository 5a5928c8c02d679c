"""``dvs image`` end to end on scikit-fem data (another code and mesh than the model)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from experiments.data.dataset import save_dataset
from experiments.imaging.command import main
from experiments.phantom.fe import ReferenceSlab, design_cases, reference_dataset
from experiments.phantom.simulate import SimulationSettings


@pytest.fixture(scope="module")
def fe_dataset(tmp_path_factory):
    """A slab with a stiff disc (E x 2, 10 mm) on the 10-load design, 0.02 mm noise."""
    folder = tmp_path_factory.mktemp("image")
    slab = ReferenceSlab(elements=(12, 12, 2), inclusion=(6.0, -5.0, 10.0, 2.0))
    forces, contacts = design_cases("diagnosis", slab)
    data = reference_dataset(
        slab, forces, contacts, 4.0, (7, 7), SimulationSettings(noise_mm=0.02, seed=3)
    )
    path = folder / "slab.npz"
    save_dataset(path, data)
    unlabelled = folder / "no_noise.npz"
    save_dataset(unlabelled, replace(data, noise_mm=None))
    return path, unlabelled


def test_image_writes_the_map_its_uncertainty_and_a_consistent_record(fe_dataset, tmp_path, capsys):
    import json

    import meshio

    path, _ = fe_dataset
    out = tmp_path / "image"
    argv = [str(path), "--out", str(out), "--energy", "linear-elastic", "--grid", "7x7x2"]
    argv += ["--field", "4x4", "--weight", "100"]
    assert main(argv) == 0, capsys.readouterr().err
    written = {p.name for p in out.iterdir()}
    assert {"image.json", "map.png", "std.png", "map.vtu"} <= written, written
    record = json.loads((out / "image.json").read_text())
    assert record["schema"] == "dvs-image/1"
    # --energy linear-elastic: the volume of the options, no step 0
    assert record["model"]["source"] == "options" and "base_choice" not in record
    assert (record["model"]["grid"], record["model"]["degrees"]) == ([7, 7, 2], [3, 3, 1])
    field = record["field"]
    s = np.array(field["coefficients"])
    reference = record["model"]["E_ref_kPa"]
    homogeneous = record["model"]["homogeneous_fit"]  # the field is about the homogeneous fit
    assert (reference, record["model"]["nu"]) == (homogeneous["E"], homogeneous["nu"])
    np.testing.assert_allclose(field["E_kPa"], reference * np.exp(s), rtol=1e-12)
    assert record["weight"] == {**record["weight"], "rule": "given", "beta_mm2": 100.0}
    assert 1.0 <= record["effective_dof"] <= len(s)
    assert all(v > 0 for v in field["std_log_E"])
    residual = record["residual"]
    assert residual["chi2_over_n"] == pytest.approx(residual["chi2"] / residual["n"])
    mesh = meshio.read(out / "map.vtu")
    np.testing.assert_allclose(
        mesh.point_data["E_kPa"], reference * np.exp(mesh.point_data["log_E_ratio"])
    )
    # the nodal values of a degree-1 field are the map's values at the nodes
    assert np.nanmin(mesh.point_data["E_kPa"]) >= min(field["E_kPa"]) * (1 - 1e-9)
    assert "strongest departure" in capsys.readouterr().out
    # image.json keys (docs/formats.md): the peak lies over the markers and is the map's
    # largest E there
    from experiments.data.dataset import load_dataset

    markers = load_dataset(path).outer_rest.reshape(-1, 3)
    low, high = markers[:, :2].min(axis=0), markers[:, :2].max(axis=0)
    assert np.all(record["peak_mm"] >= low) and np.all(record["peak_mm"] <= high)
    assert 1.0 <= record["contrast"] <= max(field["E_kPa"]) / min(field["E_kPa"])
    assert record["rms_mm"] == pytest.approx(residual["rms_um"] * 1e-3)
    assert 0.0 < record["noise_rms_mm"] < 3 * 0.02


def test_image_without_a_noise_level_is_a_usage_error(fe_dataset, tmp_path, capsys):
    _, unlabelled = fe_dataset
    out = tmp_path / "none"
    assert main([str(unlabelled), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--noise" in err and err.count("\n") == 1
    assert not out.exists()


def test_every_key_of_image_json_is_documented(fe_dataset, tmp_path):
    import json
    from pathlib import Path

    path, _ = fe_dataset
    out = tmp_path / "keys"
    argv = [str(path), "--out", str(out), "--energy", "linear-elastic", "--grid", "7x7x2"]
    assert main([*argv, "--field", "3x3", "--weight", "10"]) == 0
    record = json.loads((out / "image.json").read_text())
    formats = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = formats.split("## image.json", 1)[1].split("\n## ", 1)[0]

    def keys(document):
        if isinstance(document, dict):
            return set(document) | set().union(*map(keys, document.values()))
        return set()

    assert sorted(k for k in keys(record) if f"`{k}`" not in section) == []


@pytest.mark.parametrize("text", ["morozov", "gcv", "lcurve", "250"])
def test_every_weight_rule_is_accepted(text):
    from experiments.imaging.options import parse_weight

    assert parse_weight(text) == (float(text) if text[0].isdigit() else text)


def test_the_map_finds_the_known_inclusion(fe_dataset, tmp_path):
    """FE data of a 10 mm disc twice as stiff at (6, -5) mm (another code and mesh): the
    GCV map's peak lies within 3 mm of the disc's centre, its contrast is above 1.3, and
    the truth log(E_true / E_ref) lies inside the map's 2-std band at 90 % of the field's
    nodes over the markers. Measured: 2.2 mm, 2.57, 15 of 16 nodes."""
    import json

    path, _ = fe_dataset
    out = tmp_path / "found"
    argv = [str(path), "--out", str(out), "--energy", "linear-elastic", "--grid", "15x15x3"]
    argv += ["--margin", "10", "--field", "8x8", "--weight", "gcv"]
    assert main(argv) == 0
    record = json.loads((out / "image.json").read_text())
    centre, radius, young = np.array([6.0, -5.0]), 5.0, 20.0  # the fixture's disc and slab
    assert np.linalg.norm(np.array(record["peak_mm"]) - centre) <= 3.0
    assert record["contrast"] >= 1.3
    field = record["field"]
    nodes = np.array(field["nodes_xyz_mm"])[:, :2]
    inside = np.linalg.norm(nodes - centre, axis=1) <= radius
    truth = np.log(np.where(inside, 2.0 * young, young) / record["model"]["E_ref_kPa"])
    z = np.abs(np.array(field["coefficients"]) - truth) / np.array(field["std_log_E"])
    over = np.all(np.abs(nodes) <= 20.1, axis=1)  # the 7 x 7 markers span 40 mm
    assert over.sum() >= 9 and np.mean(z[over] <= 2.0) >= 0.9
