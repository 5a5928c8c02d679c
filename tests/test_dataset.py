"""Dataset format v1: round trip, atomic writes and a corpus of malformed files."""

from __future__ import annotations

import json
import os
from collections.abc import Callable

import numpy as np
import pytest

from experiments.data.dataset import (
    SCHEMA,
    Dataset,
    DatasetError,
    from_arrays,
    load_dataset,
    save_dataset,
    to_arrays,
    validate,
)
from experiments.output import atomic

CURVATURE_RADIUS_MM = 100.0
THICKNESS_MM = 5.0


def dome_grid(size: int = 9, width_mm: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Gently curved outer grid z = -(x^2 + y^2) / 2R and its unit upward normals."""
    axis = np.linspace(-width_mm / 2, width_mm / 2, size)
    x, y = np.meshgrid(axis, axis, indexing="ij")
    z = -(x**2 + y**2) / (2 * CURVATURE_RADIUS_MM)
    normal = np.stack([x / CURVATURE_RADIUS_MM, y / CURVATURE_RADIUS_MM, np.ones_like(x)], -1)
    return np.stack([x, y, z], -1), normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def bump(outer: np.ndarray, centre: np.ndarray, depth_mm: float = 1.5) -> np.ndarray:
    """Smooth downward Gaussian indentation of the grid around ``centre``."""
    squared = np.sum((outer[..., :2] - centre[:2]) ** 2, axis=-1)
    shift = np.zeros_like(outer)
    shift[..., 2] = -depth_mm * np.exp(-squared / (2 * 6.0**2))
    return outer + shift


def make_dataset(with_optional: bool = False) -> Dataset:
    """Two load cases of (0, 0, -0.25) N, at the centre marker and off centre."""
    outer, normal = dome_grid()
    inner = outer - THICKNESS_MM * normal
    contacts = np.stack([outer[4, 4], outer[2, 6]])
    forces = np.array([[0.0, 0.0, -0.25], [0.0, 0.0, -0.25]])
    loaded = np.stack([bump(outer, contact) for contact in contacts])
    loaded[0, 0, 0] = np.nan  # occluded markers
    loaded[1, 8, 3] = np.nan
    dataset = Dataset(outer, inner, forces, contacts, loaded)
    if with_optional:
        times = np.linspace(0.0, 0.5, 4)
        ramp = 1.0 - np.exp(-times / 0.1)
        displacement = loaded - outer
        series = outer + ramp[None, :, None, None, None] * displacement[:, None]
        dataset.noise_mm = 0.05
        dataset.probe_radius = np.array([0.0, 2.5])
        dataset.times, dataset.outer_series = times, series
        dataset.extra = {"camera_ids": np.array(["left", "right"]), "seed": np.array(7)}
    return dataset


@pytest.fixture
def valid() -> Dataset:
    return make_dataset(with_optional=True)


def assert_bit_identical(first: np.ndarray, second: np.ndarray) -> None:
    assert first.dtype == second.dtype and first.shape == second.shape
    assert first.tobytes() == second.tobytes()


# --------------------------------------------------------------------------- round trip


def test_valid_dataset_passes_and_has_expected_properties(valid):
    validate(valid)
    assert valid.n_loads == 2
    assert valid.marker_shape == (9, 9)
    assert valid.observed_mask.shape == (2, 9, 9)
    assert np.count_nonzero(~valid.observed_mask) == 2


def test_round_trip_is_bit_identical(tmp_path, valid):
    path = tmp_path / "phantom.npz"
    save_dataset(path, valid)
    loaded = load_dataset(path)
    for key in ("outer_rest", "inner_rest", "forces", "contacts", "outer_loaded"):
        assert_bit_identical(getattr(valid, key), getattr(loaded, key))
    for key in ("probe_radius", "times", "outer_series"):
        assert_bit_identical(getattr(valid, key), getattr(loaded, key))
    assert loaded.noise_mm == valid.noise_mm
    assert np.array_equal(loaded.observed_mask, valid.observed_mask)
    assert set(loaded.extra) == set(valid.extra)
    for key, value in valid.extra.items():
        assert_bit_identical(value, loaded.extra[key])


def test_schema_is_a_zero_d_string_and_optional_keys_are_omitted(tmp_path):
    path = tmp_path / "minimal.npz"
    save_dataset(path, make_dataset())
    with np.load(path, allow_pickle=False) as archive:
        assert archive["schema"].shape == () and archive["schema"].item() == SCHEMA
        assert set(archive.files) == {
            "schema",
            "outer_rest",
            "inner_rest",
            "forces",
            "contacts",
            "outer_loaded",
        }
    loaded = load_dataset(path)
    assert loaded.noise_mm is None and loaded.times is None and loaded.extra == {}


def test_integer_arrays_are_accepted_and_loaded_as_float(tmp_path):
    arrays = to_arrays(make_dataset())
    arrays["forces"] = np.array([[0, 0, -1], [0, 0, -2]])
    np.savez(tmp_path / "ints.npz", **arrays)
    assert load_dataset(tmp_path / "ints.npz").forces.dtype == np.float64


# ----------------------------------------------------------------------------- atomic


def test_failed_save_leaves_no_file(tmp_path, valid, monkeypatch):
    def fail_mid_write(handle, **arrays):
        handle.write(b"PK\x03\x04 half an archive")
        raise RuntimeError("disk pulled out")

    monkeypatch.setattr(np, "savez", fail_mid_write)
    with pytest.raises(RuntimeError, match="disk pulled out"):
        save_dataset(tmp_path / "phantom.npz", valid)
    assert os.listdir(tmp_path) == []


def test_failed_save_keeps_the_previous_file(tmp_path, valid, monkeypatch):
    path = tmp_path / "phantom.npz"
    save_dataset(path, valid)
    before = path.read_bytes()

    def fail_at_sync(descriptor):
        raise OSError("fsync failed")

    monkeypatch.setattr(os, "fsync", fail_at_sync)
    with pytest.raises(OSError, match="fsync failed"):
        save_dataset(path, make_dataset())
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["phantom.npz"]


def test_invalid_dataset_is_not_saved(tmp_path, valid):
    valid.forces = np.zeros((2, 3))
    with pytest.raises(DatasetError, match="forces"):
        save_dataset(tmp_path / "bad.npz", valid)
    assert os.listdir(tmp_path) == []


def test_atomic_json_writes_strict_json_with_nulls(tmp_path):
    path = tmp_path / "result.json"
    atomic.atomic_write_json(
        path, {"rms_mm": np.float64(0.1), "steps": np.array([1.0, np.nan]), "inf": np.inf}
    )
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"rms_mm": 0.1, "steps": [1.0, None], "inf": None}


def test_atomic_savefig_takes_format_from_suffix(tmp_path):
    import matplotlib.figure

    figure = matplotlib.figure.Figure()
    figure.add_subplot().plot([0, 1], [1, 0])
    atomic.atomic_savefig(figure, tmp_path / "plot.png")
    atomic.atomic_savefig(figure, tmp_path / "plot.svg")
    assert (tmp_path / "plot.png").read_bytes().startswith(b"\x89PNG")
    assert b"<svg" in (tmp_path / "plot.svg").read_bytes()
    assert (tmp_path / "plot.pdf").read_bytes().startswith(b"%PDF")  # the PNG's vector twin
    assert sorted(os.listdir(tmp_path)) == ["plot.pdf", "plot.png", "plot.svg"]


# ------------------------------------------------------------------ malformed corpus


def _mutated(valid: dict[str, np.ndarray], **changes) -> dict[str, np.ndarray]:
    """Copy of ``valid`` with keys replaced (value None = key removed)."""
    arrays = {key: np.array(value, copy=True) for key, value in valid.items()}
    for key, value in changes.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    return arrays


def _edited(array: np.ndarray, edit: Callable[[np.ndarray], None]) -> np.ndarray:
    """Copy of ``array`` changed in place by ``edit``."""
    copy = np.array(array, dtype=float, copy=True)
    edit(copy)
    return copy


def _set(index, value) -> Callable[[np.ndarray], None]:
    return lambda array: array.__setitem__(index, value)


def malformed_corpus(valid: Dataset) -> dict[str, dict[str, np.ndarray]]:
    """Broken variants of ``valid``, named ``"<offending key>:<problem>"``."""
    good = to_arrays(valid)
    outer, inner = good["outer_rest"], good["inner_rest"]
    flipped = inner.copy()
    flipped[5:] = outer[5:] + (outer[5:] - inner[5:])
    half_seen = good["outer_loaded"].copy()
    half_seen[0, 3, 3, 1] = np.nan
    cases = {
        "schema:missing": dict(schema=None),
        "schema:wrong_version": dict(schema=np.array("dvs-dataset/2")),
        "schema:not_a_string": dict(schema=np.array(1.0)),
        "outer_rest:missing": dict(outer_rest=None),
        "outer_loaded:missing": dict(outer_loaded=None),
        "outer_rest:flat_list_of_markers": dict(outer_rest=outer.reshape(-1, 3)),
        "outer_rest:two_coordinates": dict(outer_rest=outer[..., :2]),
        "outer_rest:non_finite": dict(outer_rest=_edited(outer, _set((2, 2, 0), np.nan))),
        "outer_rest:all_markers_coincide": dict(outer_rest=np.zeros_like(outer)),
        "outer_rest:text_dtype": dict(outer_rest=outer.astype(str)),
        "inner_rest:u_mismatch": dict(inner_rest=inner[:8]),
        "inner_rest:non_finite": dict(inner_rest=_edited(inner, _set((0, 0, 2), np.inf))),
        "inner_rest:zero_thickness": dict(inner_rest=_edited(inner, _set((3, 3), outer[3, 3]))),
        "inner_rest:crosses_outer": dict(inner_rest=flipped),
        "forces:missing": dict(forces=None),
        "forces:k_by_2": dict(forces=good["forces"][:, :2]),
        "forces:non_finite": dict(forces=_edited(good["forces"], _set((1, 2), np.nan))),
        "forces:zero": dict(forces=_edited(good["forces"], _set(1, 0.0))),
        "forces:below_1e-9_N": dict(forces=_edited(good["forces"], _set((0, 2), -1e-12))),
        "forces:complex_dtype": dict(forces=good["forces"].astype(complex)),
        "forces:boolean_dtype": dict(forces=np.ones((2, 3), dtype=bool)),
        "contacts:k_mismatch": dict(contacts=good["contacts"][:1]),
        "contacts:non_finite": dict(contacts=_edited(good["contacts"], _set((0, 0), np.nan))),
        "contacts:far_from_surface": dict(
            contacts=_edited(good["contacts"], _set((1, 2), outer[2, 6, 2] + 30.0))
        ),
        "outer_loaded:v_mismatch": dict(outer_loaded=good["outer_loaded"][:, :, :7]),
        "outer_loaded:k_mismatch": dict(outer_loaded=good["outer_loaded"][:1]),
        "outer_loaded:no_marker_seen": dict(
            outer_loaded=_edited(good["outer_loaded"], _set(1, np.nan))
        ),
        "outer_loaded:infinite": dict(
            outer_loaded=_edited(good["outer_loaded"], _set((0, 1, 1, 2), -np.inf))
        ),
        "outer_loaded:partly_nan_marker": dict(outer_loaded=half_seen),
        "outer_loaded:pickled_objects": dict(outer_loaded=good["outer_loaded"].astype(object)),
        "noise_mm:negative": dict(noise_mm=np.array(-0.1)),
        "noise_mm:not_scalar": dict(noise_mm=np.array([0.1, 0.2])),
        "noise_mm:nan": dict(noise_mm=np.array(np.nan)),
        "probe_radius:wrong_length": dict(probe_radius=np.array([1.0, 1.0, 1.0])),
        "probe_radius:negative": dict(probe_radius=np.array([0.0, -2.0])),
        "times:not_increasing": dict(times=good["times"][::-1].copy()),
        "times:repeated_sample": dict(times=np.array([0.0, 0.1, 0.1, 0.3])),
        "times:missing_with_series": dict(times=None),
        "outer_series:missing_with_times": dict(outer_series=None),
        "outer_series:t_mismatch": dict(outer_series=good["outer_series"][:, :3]),
        "outer_series:infinite": dict(
            outer_series=_edited(good["outer_series"], _set((0, 2, 4, 4, 2), np.inf))
        ),
        "camera_ids:extra_key_pickled": dict(camera_ids=np.array([{"left": 1}], dtype=object)),
    }
    return {name: _mutated(good, **changes) for name, changes in cases.items()}


CORPUS = malformed_corpus(make_dataset(with_optional=True))


def test_corpus_is_large_and_valid_baseline_loads(tmp_path, valid):
    assert len(CORPUS) >= 12
    np.savez(tmp_path / "good.npz", **to_arrays(valid))
    load_dataset(tmp_path / "good.npz")


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_malformed_file_is_rejected_naming_its_key(tmp_path, name):
    key = name.split(":")[0]
    path = tmp_path / "broken.npz"
    np.savez(path, **CORPUS[name])
    with pytest.raises(DatasetError) as caught:
        load_dataset(path)
    message = str(caught.value)
    assert caught.value.key == key
    assert f"{key}:" in message and str(path) in message
    assert "\n" not in message


@pytest.mark.parametrize("name", sorted(n for n in CORPUS if not n.startswith("schema")))
def test_from_arrays_rejects_the_same_corpus(name):
    with pytest.raises(DatasetError) as caught:
        from_arrays(CORPUS[name])
    assert caught.value.key == name.split(":")[0]


def _write_npy(path):
    with open(path, "wb") as handle:
        np.save(handle, np.zeros(3))


def _write_text(path):
    path.write_text("outer_rest = [[1, 2, 3]]\n")


def _write_truncated(path):
    save_dataset(path, make_dataset())
    path.write_bytes(path.read_bytes()[:200])


@pytest.mark.parametrize(
    "make_file, problem",
    [
        (lambda path: None, "not found"),
        (lambda path: path.mkdir(), "directory"),
        (_write_npy, "single .npy array"),
        (_write_text, "not a readable .npz"),
        (_write_truncated, "not a readable .npz"),
    ],
    ids=["missing", "directory", "npy", "text", "truncated"],
)
def test_unreadable_file_gives_one_line_error(tmp_path, make_file, problem):
    path = tmp_path / "data.npz"
    make_file(path)
    with pytest.raises(DatasetError, match=problem) as caught:
        load_dataset(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)
    assert caught.value.key is None


def test_formats_doc_example_runs(tmp_path, monkeypatch):
    from experiments.data.paths import PROJECT_ROOT

    text = (PROJECT_ROOT / "docs" / "formats.md").read_text()
    example = text.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(tmp_path)
    exec(compile(example, "docs/formats.md", "exec"), {})
    assert load_dataset(tmp_path / "phantom.npz").observed_mask.sum() == 80
