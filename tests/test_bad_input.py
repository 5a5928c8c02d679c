"""Regression tests of the hostile inputs measured by the bad-input campaign.

Each example of the campaign's table gives exit 2 (or 3 for a computation that failed)
and one line on stderr, never a traceback; and valid data with a non-square marker grid
fits and diagnoses with the defaults.
"""

from __future__ import annotations

import io
import json
import os
import zipfile

import numpy as np
import pytest
from conftest import exit_code_and_stderr
from fuzzing import forged_header, time_limit

from experiments.command.cli import main
from experiments.data import archive
from experiments.data.dataset import DatasetError, load_dataset, save_dataset, to_arrays
from experiments.phantom.forehead import PhantomSettings
from experiments.phantom.simulate import simulate


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bad")
    path = folder / "phantom.npz"
    save_dataset(path, simulate())
    return path


def _written(folder, name: str, change) -> str:
    arrays = to_arrays(load_dataset(folder))
    change(arrays)
    path = folder.parent / name
    np.savez(path, **arrays)
    return str(path)


def _one_line_exit(argv, capsys, expected: int = 2, fragment: str = "") -> str:
    with time_limit(120):
        code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == expected, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert fragment in err, err
    return err


# ----------------------------------------------------------------- file system
def test_a_300_character_file_name(tmp_path, capsys):
    name = str(tmp_path / ("a" * 300 + ".npz"))
    _one_line_exit(["fit", name, "--out", str(tmp_path / "o")], capsys, fragment="too long")


@pytest.mark.skipif(os.geteuid() == 0, reason="root enters every folder")
def test_a_dataset_in_a_folder_that_cannot_be_entered(phantom, tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    (locked / "data.npz").write_bytes(phantom.read_bytes())
    locked.chmod(0o000)
    try:
        _one_line_exit(["fit", str(locked / "data.npz"), "--out", str(tmp_path / "o")], capsys)
    finally:
        locked.chmod(0o700)


def test_a_pipe_named_like_a_dataset_does_not_block(tmp_path, capsys):
    fifo = tmp_path / "f.npz"
    os.mkfifo(fifo)
    _one_line_exit(["fit", str(fifo), "--out", str(tmp_path / "o")], capsys, fragment="regular")


# ------------------------------------------------------------------ lying archives
def test_a_header_claiming_a_trillion_elements_is_refused_without_allocating(phantom, tmp_path):
    forged = tmp_path / "forged.npz"
    forged.write_bytes(forged_header(phantom.read_bytes(), "outer_rest"))
    with pytest.raises(DatasetError, match="header claims") as caught:
        load_dataset(forged)
    assert caught.value.key == "outer_rest"


def test_a_member_that_inflates_beyond_the_limit_is_refused(phantom, tmp_path, monkeypatch):
    """A zip bomb in miniature: the limit is lowered, the member is deflated zeros."""
    monkeypatch.setattr(archive, "MAX_MEMBER_BYTES", 10_000)
    arrays = to_arrays(load_dataset(phantom))
    arrays["padding"] = np.zeros(100_000)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    path = tmp_path / "bomb.npz"
    path.write_bytes(buffer.getvalue())
    assert path.stat().st_size < 50_000  # small on disk, 800 kB inflated
    with pytest.raises(DatasetError, match="inflates to") as caught:
        load_dataset(path)
    assert caught.value.key == "padding"


def test_a_zip_with_a_non_array_member_is_refused(phantom, tmp_path):
    path = tmp_path / "odd.npz"
    path.write_bytes(phantom.read_bytes())
    with zipfile.ZipFile(path, "a") as handle:
        handle.writestr("notes.txt", "hello")
    with pytest.raises(DatasetError, match="not a .npy member"):
        load_dataset(path)


# ------------------------------------------------------------------- absurd numbers
@pytest.mark.parametrize(
    "name, change, key",
    [
        ("radius", lambda a: a.__setitem__("probe_radius", np.full(2, 1e308)), "probe_radius"),
        ("forces", lambda a: a.__setitem__("forces", a["forces"] * 1e308), "forces"),
        ("noise", lambda a: a.__setitem__("noise_mm", np.array(100.0)), "noise_mm"),
        ("tiny", lambda a: a.__setitem__("noise_mm", np.array(1e-300)), "noise_mm"),
        ("far", lambda a: a.__setitem__("outer_loaded", a["outer_loaded"] + 1000.0), "loaded"),
        ("thick", lambda a: a.__setitem__("inner_rest", a["inner_rest"] * 100.0), "inner_rest"),
        ("ramp", lambda a: a.__setitem__("load_ramp_s", np.array(-1.0)), "load_ramp_s"),
        ("std", lambda a: a.__setitem__("marker_std_mm", np.ones((2, 9, 9))), "marker_std_mm"),
    ],
)
def test_absurd_values_are_refused_naming_the_key(phantom, capsys, name, change, key):
    path = _written(phantom, f"{name}.npz", change)
    _one_line_exit(["fit", path, "--out", str(phantom.parent / "o")], capsys, fragment=key)
    assert not (phantom.parent / "o").exists()


def test_a_vanishing_probe_radius_is_a_point_force(phantom, tmp_path, capsys):
    """Found by the campaign: probe_radius 1e-308 mm made the Gaussian patch empty."""
    path = _written(
        phantom, "tiny.npz", lambda a: a.__setitem__("probe_radius", np.full(2, 1e-308))
    )
    assert main(["fit", path, "--out", str(tmp_path / "fit")]) == 0
    point = _written(phantom, "point.npz", lambda a: a.__setitem__("probe_radius", np.zeros(2)))
    assert main(["fit", point, "--out", str(tmp_path / "point")]) == 0
    values = [
        json.loads((tmp_path / name / "result.json").read_text())["parameters"]["alpha_u"]["value"]
        for name in ("fit", "point")
    ]
    assert values[0] == pytest.approx(values[1], rel=1e-9)


def test_geometry_scaled_by_1e150_is_refused_by_diagnose(phantom, capsys):
    def scale(arrays):
        for key in ("outer_rest", "inner_rest", "contacts", "outer_loaded"):
            arrays[key] = arrays[key] * 1e150

    path = _written(phantom, "huge.npz", scale)
    argv = ["diagnose", path, "--out", str(phantom.parent / "d")]
    _one_line_exit(argv, capsys, fragment="outer_rest")


def test_an_unknown_candidate_effect_is_refused_by_diagnose(phantom, capsys):
    argv = [
        "diagnose",
        str(phantom),
        "--out",
        str(phantom.parent / "c"),
        "--candidates",
        "x,gravity",
    ]
    _one_line_exit(argv, capsys, fragment="--candidates: unknown x, gravity")
    assert not (phantom.parent / "c").exists()


# ----------------------------------------------------- valid data, default settings
@pytest.mark.parametrize("markers", [(11, 8), (9, 4)])
def test_a_non_square_marker_grid_fits_and_diagnoses_with_the_defaults(markers, tmp_path, capsys):
    path = tmp_path / "data.npz"
    save_dataset(path, simulate(PhantomSettings(markers=markers)))
    assert main(["fit", str(path), "--out", str(tmp_path / "fit")]) == 0
    printed = capsys.readouterr().out
    grid = (min(9, markers[0]), min(9, markers[1]), 2)
    assert f"control grid {'x'.join(map(str, grid))}" in printed
    document = json.loads((tmp_path / "fit" / "result.json").read_text())
    assert document["model"]["grid"] == list(grid) and document["verdict"]["explains_data"]
    assert main(["diagnose", str(path), "--out", str(tmp_path / "diag")]) == 0
    assert json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["success"]


def test_a_grid_finer_than_the_markers_refines_the_fitted_geometry(tmp_path, capsys):
    path = tmp_path / "data.npz"
    save_dataset(path, simulate(PhantomSettings(markers=(11, 8))))
    argv = ["fit", str(path), "--energy", "dnurbs", "--grid", "9x9x2", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    document = json.loads((tmp_path / "o" / "result.json").read_text())
    assert document["model"]["grid"] == [9, 9, 2] and document["verdict"]["explains_data"]


# ------------------------------------------------------------------- experiments
@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    from experiments.stereo.render import write_synthetic_experiment
    from experiments.stereo.rig import RigSettings

    folder = tmp_path_factory.mktemp("render") / "run"
    write_synthetic_experiment(folder, rig=RigSettings(scale=0.5), n_boards=8)
    return folder


def _copy(folder, tmp_path, name):
    import shutil

    target = tmp_path / name
    shutil.copytree(folder, target)
    return target


def test_a_billion_cameras_are_refused_before_anything_is_allocated(experiment, tmp_path, capsys):
    folder = _copy(experiment, tmp_path, "many")
    spec = json.loads((folder / "experiment.json").read_text())
    spec["cameras"] = 10**9
    (folder / "experiment.json").write_text(json.dumps(spec))
    argv = ["reconstruct", str(folder), "--out", str(tmp_path / "x.npz")]
    _one_line_exit(argv, capsys, fragment="cameras")


def test_an_all_white_loaded_image_is_reconstructed_from_the_other_cameras(
    experiment, tmp_path, capsys
):
    import cv2

    folder = _copy(experiment, tmp_path, "white")
    image = cv2.imread(str(folder / "cam0_load1.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(folder / "cam0_load1.png"), np.full_like(image, 255))
    out = tmp_path / "white.npz"
    with time_limit(120):
        code, err = exit_code_and_stderr(
            main, ["reconstruct", str(folder), "--out", str(out)], capsys
        )
    assert code == 0 and "Traceback" not in err
    seen = np.isfinite(load_dataset(out).outer_loaded[1, ..., 0]).sum()
    assert seen > 40  # two cameras still see most markers under the second load
