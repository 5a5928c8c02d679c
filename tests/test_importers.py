"""``dvs import``: the measured experiments as datasets (docs/formats.md, "Measured
experiments"), their round trip, the rules of the keys they add, and bad input."""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import pytest
from conftest import exit_code_and_stderr

from experiments.command.cli import main
from experiments.data.compression import compression_dataset, disc_grid, read_recipe
from experiments.data.dataset import (
    DatasetError,
    from_arrays,
    load_dataset,
    save_dataset,
    to_arrays,
)
from experiments.data.truthcube import cube_from_dataset, read_truth_cube, truth_cube_dataset
from experiments.realskin.data import load_case, read_case
from experiments.realskin.skindataset import SKIN_THICKNESS_MM, case_from_dataset, skin_dataset


def _one_line(argv, capsys, expected=2) -> str:
    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == expected, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.fixture(scope="module")
def cube_file(shared_data):
    return shared_data / "truth-cube" / "uniaxial_positions.csv"


@pytest.fixture(scope="module")
def recipe_folder(shared_data):
    return shared_data / "phantom-compression" / "data" / "EF10_0T"


# ------------------------------------------------------------------ Truth Cube
def test_the_truth_cube_round_trips_and_keeps_every_bead(cube_file, tmp_path, capsys):
    out = tmp_path / "cube.npz"
    assert main(["import", "truth-cube", str(cube_file), "--out", str(out)]) == 0
    data = load_dataset(out)
    cube = read_truth_cube(cube_file)
    assert data.kind == "plate" and data.n_loads == 3
    np.testing.assert_array_equal(data.markers_rest, cube.rest)
    np.testing.assert_array_equal(data.markers_loaded, cube.loaded)
    assert np.isnan(data.forces).all() and np.isnan(data.outer_loaded).all()
    # the plate moves towards the base (+z in the file's frame) by 5, 12.5, 18.25 % of 80 mm
    np.testing.assert_allclose(data.plate_motion[:, 2], [4.0, 10.0, 14.6])
    # every bead lies between the plate's face and the base, about 1 cm inside
    top, base = data.outer_rest[..., 2].mean(), data.inner_rest[..., 2].mean()
    assert top < cube.rest[:, 2].min() - 5.0 and base > cube.rest[:, 2].max() + 5.0
    again = from_arrays(to_arrays(data))
    np.testing.assert_array_equal(again.markers_loaded, data.markers_loaded)


def test_a_bead_file_with_a_short_line_is_one_line_exit_2(cube_file, tmp_path, capsys):
    lines = cube_file.read_text().splitlines()
    lines[9] = ",".join(lines[9].split(",")[:8])
    bad = tmp_path / "short.csv"
    bad.write_text("\n".join(lines))
    out = tmp_path / "cube.npz"
    err = _one_line(["import", "truth-cube", str(bad), "--out", str(out)], capsys)
    assert "line 10" in err and not out.exists()


def test_a_repeated_bead_index_is_refused(cube_file, tmp_path, capsys):
    lines = cube_file.read_text().splitlines()
    lines[8] = lines[7]
    bad = tmp_path / "repeated.csv"
    bad.write_text("\n".join(lines))
    err = _one_line(["import", "truth-cube", str(bad), "--out", str(tmp_path / "o.npz")], capsys)
    assert "repeated" in err


# -------------------------------------------------------------------- phantoms
def test_a_recipe_round_trips_with_its_curves(recipe_folder, tmp_path):
    out = tmp_path / "ef.npz"
    assert main(["import", "compression", str(recipe_folder), "--out", str(out)]) == 0
    data = load_dataset(out)
    recipe, tests = read_recipe(recipe_folder)
    assert data.kind == "plate" and data.n_loads == 15 * len(tests) == 150
    assert list(data.extra["specimen_names"]) == [t.name for t in tests]
    # each specimen's curve: the plate moves down, the force grows with it
    for number in range(len(tests)):
        rows = data.specimen == number
        assert np.all(np.diff(-data.plate_motion[rows, 2]) > 0)
        assert np.all(np.diff(-data.forces[rows, 2]) > 0)
    # a sampled force is the test's own record at that compression
    first = tests[0]
    c = -data.plate_motion[0, 2]
    nearest = np.argmin(np.abs(first.compression_mm - c))
    assert abs(-data.forces[0, 2] - first.load_n[nearest]) < 0.05 * first.load_n[nearest] + 0.05
    assert 0.0 < data.force_noise_n < 0.5


def test_the_disc_grid_covers_the_disc():
    grid = disc_grid(25.0, 30.0)
    radius = np.linalg.norm(grid[..., :2], axis=-1)
    assert radius.max() == pytest.approx(25.0) and radius.min() == 0.0
    # the edge of the square maps onto the circle
    np.testing.assert_allclose(radius[0, :], 25.0)


def test_a_folder_without_tests_and_a_strain_beyond_the_record_exit_2(
    recipe_folder, tmp_path, capsys
):
    out = tmp_path / "x.npz"
    err = _one_line(["import", "compression", str(tmp_path), "--out", str(out)], capsys)
    assert "no" in err and "test files" in err and not out.exists()
    err = _one_line(
        ["import", "compression", str(recipe_folder), "--strain", "0.9", "--out", "x.npz"], capsys
    )
    assert "lower --strain" in err


# ---------------------------------------------------------------- the new rules
@pytest.fixture(scope="module")
def cube_arrays(cube_file):
    return to_arrays(truth_cube_dataset(read_truth_cube(cube_file)))


def _refusal(arrays: dict, change) -> DatasetError:
    """The error ``from_arrays`` raises on a copy of ``arrays`` that ``change`` broke."""
    broken = {k: np.array(v, copy=True) for k, v in arrays.items()}
    change(broken)
    with pytest.raises(DatasetError) as raised:
        from_arrays(broken)
    return raised.value


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda a: a.pop("markers_loaded"), "markers_loaded"),
        (lambda a: a.update(markers_rest=a["markers_rest"] + 500.0), "markers_rest"),
        (lambda a: a.update(plate_motion=a["plate_motion"] * 10.0), "plate_motion"),
        (lambda a: a.update(forces=np.where([[1, 0, 0]], 0.1, a["forces"])), "forces"),
        (lambda a: a.update(specimen=np.array([0.0, 1.5, 2.0])), "specimen"),
        (lambda a: a.update(force_noise_n=np.array(-1.0)), "force_noise_n"),
        (lambda a: a.pop("plate_motion"), "forces"),  # NaN forces without a plate
    ],
)
def test_each_rule_of_the_experiment_keys_names_its_key(cube_arrays, change, key):
    error = _refusal(cube_arrays, change)
    assert error.key == key, str(error)


def test_a_load_case_that_observes_nothing_is_refused(cube_arrays):
    def unobserved(arrays):
        arrays["markers_loaded"][1] = np.nan

    assert "nothing observed in load 1" in str(_refusal(cube_arrays, unobserved))


def test_indentation_commands_refuse_a_plate_dataset(cube_file, recipe_folder, tmp_path, capsys):
    """fit and image model a probe: they refuse the cube; diagnose runs the phantoms'
    own set-up and refuses model options for it, one line, nothing written."""
    path = tmp_path / "cube.npz"
    save_dataset(path, truth_cube_dataset(read_truth_cube(cube_file)))
    for command in ("fit", "image"):
        err = _one_line([command, str(path), "--out", str(tmp_path / command)], capsys)
        assert "plate load" in err and not (tmp_path / command).exists()
    recipe, tests = read_recipe(recipe_folder)
    curves = tmp_path / "curves.npz"
    save_dataset(curves, compression_dataset(recipe, tests))
    argv = ["diagnose", str(curves), "--energy", "neo-hookean", "--out", str(tmp_path / "d")]
    err = _one_line(argv, capsys)
    assert "give only --out" in err and not (tmp_path / "d").exists()


def test_a_cube_dataset_gives_back_its_beads(cube_file):
    cube = read_truth_cube(cube_file)
    again = cube_from_dataset(from_arrays(to_arrays(truth_cube_dataset(cube))))
    np.testing.assert_array_equal(again.index, cube.index)
    np.testing.assert_array_equal(again.loaded, cube.loaded)
    np.testing.assert_allclose(again.plate_travel_mm(), cube.plate_travel_mm())


def test_the_phantom_curves_fit_the_load_limit(recipe_folder):
    recipe, tests = read_recipe(recipe_folder)
    with pytest.raises(DatasetError, match="at most 200 load cases"):
        compression_dataset(recipe, tests, samples=25)


# ------------------------------------------------------------ skin extensometer
SKIN_CASES = ("healthy", "keloid")


@pytest.fixture(scope="module")
def skin_folders(shared_data):
    return {name: shared_data / "skin-extensometer" / name for name in SKIN_CASES}


def _same_case(again, case) -> None:
    """Two ``SkinCase``s equal field for field, array for array (NaN equal to NaN)."""
    for field in dataclasses.fields(case):
        mine, theirs = getattr(again, field.name), getattr(case, field.name)
        if isinstance(theirs, np.ndarray):
            assert mine.dtype == theirs.dtype and mine.shape == theirs.shape, field.name
            np.testing.assert_array_equal(mine, theirs, err_msg=field.name)
        elif field.name == "geometry":
            for part in ("region", "pad_moving", "pad_fixed", "variables"):
                assert getattr(mine, part) == getattr(theirs, part), part
            if theirs.keloid is None:
                assert mine.keloid is None
            else:
                np.testing.assert_array_equal(mine.keloid, theirs.keloid)
        else:
            assert mine == theirs, field.name


@pytest.mark.parametrize("name", SKIN_CASES)
def test_an_extensometer_case_round_trips_to_its_skin_case(name, skin_folders, tmp_path):
    """Import, load, rebuild: the case equals ``load_case`` array for array."""
    out = tmp_path / f"{name}.npz"
    assert main(["import", "extensometer", str(skin_folders[name]), "--out", str(out)]) == 0
    data = load_dataset(out)
    case = load_case(name)
    assert data.kind == "extensometer" and data.n_loads == case.n_frames
    np.testing.assert_array_equal(data.markers_axes, [1.0, 1.0, 0.0])
    assert np.isnan(data.markers_loaded[..., 2]).all()
    np.testing.assert_array_equal(data.markers_loaded[..., :2], case.dic_positions_mm)
    # the moving pad's travel and its measured x force; NaN beyond the force record
    np.testing.assert_array_equal(data.plate_motion[:, :2], case.pad_displacement_mm)
    np.testing.assert_array_equal(data.forces[:, 0], case.force_at_frame_n)
    assert np.isnan(data.forces[~case.force_valid]).all()
    _same_case(case_from_dataset(data), case)


def test_the_skin_slab_is_the_studys_thickness():
    from experiments.realskin.setup import RealSkinSettings

    assert SKIN_THICKNESS_MM == RealSkinSettings().thickness_mm


def _linked_case(source, target):
    """A writable copy of a case folder: its files linked, so one can be replaced."""
    for path in sorted(source.rglob("*")):
        if path.is_file():
            (target / path.relative_to(source)).parent.mkdir(parents=True, exist_ok=True)
            (target / path.relative_to(source)).symlink_to(path)
    return target


def _replace(folder, member: str, text: str) -> None:
    (folder / member).unlink()
    (folder / member).write_text(text)


def test_a_folder_without_the_case_files_exits_2(skin_folders, tmp_path, capsys):
    out = tmp_path / "x.npz"
    err = _one_line(["import", "extensometer", str(tmp_path), "--out", str(out)], capsys)
    assert "missing" in err and "xt_pad_mov.out" in err and not out.exists()
    err = _one_line(["import", "extensometer", str(tmp_path / "nope"), "--out", str(out)], capsys)
    assert "not a folder" in err and not out.exists()
    err = _one_line(
        ["import", "extensometer", str(skin_folders["healthy"]), "--out", "x.txt"], capsys
    )
    assert ".npz" in err


@pytest.mark.parametrize(
    "member, text, fragment",
    [
        ("reactionforce/fx_pad_mov.out", "-0.1\nabc\n", "not a table of numbers"),
        ("reactionforce/ux_pad_mov.out", "", "0 rows"),
        ("displacement/xt_dic_0003.out", "1 2 3\n4 5 6\n", "rows of 3 numbers"),
        ("displacement/xt_pad_fix.out", "36.5 0.0\n", "do not match the frames"),
        ("geometry.geo", "Point(1) = {0, 0, 0};\n", "geometry.geo"),
    ],
)
def test_a_malformed_case_file_exits_2_naming_it(
    member, text, fragment, skin_folders, tmp_path, capsys
):
    folder = _linked_case(skin_folders["healthy"], tmp_path / "healthy")
    _replace(folder, member, text)
    out = tmp_path / "x.npz"
    err = _one_line(["import", "extensometer", str(folder), "--out", str(out)], capsys)
    assert fragment in err and not out.exists(), err


@pytest.fixture(scope="module")
def skin_arrays(skin_folders):
    return to_arrays(skin_dataset(read_case(skin_folders["keloid"])))


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda a: a.update(markers_axes=np.array([1.0, 1.0, 2.0])), "markers_axes"),
        (lambda a: a.update(markers_axes=np.zeros(3)), "markers_axes"),
        (lambda a: [a.pop("markers_rest"), a.pop("markers_loaded")], "markers_axes"),
        (lambda a: a["markers_loaded"][..., 2].fill(0.0), "markers_loaded"),
        (lambda a: a.pop("markers_axes"), "markers_loaded"),  # z NaN, x and y seen
        (lambda a: a.update(fixed_plate=a["fixed_plate"] + 500.0), "fixed_plate"),
        (lambda a: a.update(fixed_plate=a["fixed_plate"][:2]), "fixed_plate"),
        (lambda a: a.update(plate_motion=a["plate_motion"] * 10.0), "plate_motion"),
        (lambda a: a.update(plate_force_curve=a["plate_force_curve"][:, :1]), "plate_force_curve"),
        (lambda a: a["plate_force_curve"].__setitem__((3, 1), np.nan), "plate_force_curve"),
    ],
)
def test_the_extensometer_rule_names_its_key(skin_arrays, change, key):
    """Rule 23 (docs/formats-validation.md): each broken extensometer key is named."""
    error = _refusal(skin_arrays, change)
    assert error.key == key, str(error)


def test_a_fixed_plate_needs_a_moving_one(skin_arrays):
    def without_moving_plate(arrays):
        arrays.pop("plate_motion")
        arrays.pop("plate_force_curve")
        arrays["forces"] = np.nan_to_num(arrays["forces"], nan=0.1)

    error = _refusal(skin_arrays, without_moving_plate)
    assert error.key == "fixed_plate", str(error)


def test_the_extensometer_travels_beyond_the_skins_thickness(skin_arrays):
    """The keloid's pad travels 5 mm along the skin, more than the 2 mm slab: the bound
    is the pads' distance (rule 23), not the thickness (rule 20)."""
    data = from_arrays(skin_arrays)
    assert np.linalg.norm(data.plate_motion, axis=1).max() > SKIN_THICKNESS_MM


def test_probe_commands_refuse_an_extensometer_and_diagnose_takes_only_out(
    skin_folders, tmp_path, capsys
):
    path = tmp_path / "skin.npz"
    save_dataset(path, skin_dataset(read_case(skin_folders["healthy"])))
    for argv in (["fit"], ["image"], ["design"], ["next", "--budget", "2"]):
        out = tmp_path / argv[0]
        err = _one_line([argv[0], str(path), *argv[1:], "--out", str(out)], capsys)
        assert "two pads" in err and not out.exists(), err
    out = tmp_path / "d"
    err = _one_line(["diagnose", str(path), "--energy", "dnurbs", "--out", str(out)], capsys)
    assert "give only --out" in err and not out.exists()


def test_a_dataset_that_is_no_extensometer_is_not_a_skin_case(cube_arrays):
    with pytest.raises(DatasetError, match="dvs import extensometer"):
        case_from_dataset(from_arrays(cube_arrays))


@pytest.mark.slow
def test_import_and_diagnose_an_extensometer_case_end_to_end(skin_folders, tmp_path):
    """``dvs import extensometer`` then the default ``dvs diagnose``: the real-skin
    study's diagnosis.json, report and figures in --out (prints the times)."""
    path, out = tmp_path / "healthy.npz", tmp_path / "d"
    begin = time.perf_counter()
    assert main(["import", "extensometer", str(skin_folders["healthy"]), "--out", str(path)]) == 0
    imported = time.perf_counter() - begin
    assert main(["diagnose", str(path), "--out", str(out)]) == 0
    print(f"import {imported:.1f} s, diagnose {time.perf_counter() - begin - imported:.1f} s")
    document = json.loads((out / "diagnosis.json").read_text())
    assert document["schema"] == "dvs-diagnosis/1" and document["success"]
    assert document["steps"][0]["effect"] is None
    observed = document["observations"]
    assert sum(label.startswith("frame ") for label in observed["frames"]) == 6
    assert 0.005 < observed["dic_noise_mm"] < 0.05  # docs/realskin-data.md: 0.0118 mm
    assert "region_verdict" in document and document["model_error_mm"] > 0.0
    assert (out / "report.md").is_file() and (out / "force.png").is_file()
