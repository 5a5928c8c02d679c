"""Issue 40, point 6, "the same defaults everywhere": with no model option ``dvs fit``,
``dvs diagnose``, ``dvs image`` and ``dvs design`` run step 0 on the same data at the same
level, print its choice in the same one line, record the same ``base_choice`` and use the
chosen model; the paper's model stays one option away (``--energy dnurbs``).

The FE data are a small patch of ``experiments.phantom.tissue`` (18 x 12 mm marked by
5 x 4 markers, clamped 4 mm beyond them, 8 loads of a 3 mm disc whose radius is not
declared), so that step 0 takes seconds. Step 0 is deterministic; the four commands
share one run of it (``choose_base`` memoised on the dataset's arrays and the level,
each call recorded): the test proves the calls agree and that each command uses and
records the outcome. ``test_each_command_runs_its_own_step_0`` (slow) runs the four
unshared.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from fepatch import patch_dataset

from experiments.command.cli import main as dvs
from experiments.data.dataset import save_dataset, to_arrays


def _fingerprint(dataset) -> str:
    digest = hashlib.sha1()
    for name, value in to_arrays(dataset).items():
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    return digest.hexdigest()


@pytest.fixture(scope="module")
def tissue(tmp_path_factory):
    path = tmp_path_factory.mktemp("same") / "patch.npz"
    save_dataset(path, patch_dataset((18.0, 12.0), (5, 4), 3.0))
    return path


@pytest.fixture(scope="module")
def shared_step0():
    """``choose_base`` memoised for the module; the (dataset, level) of every call."""
    import experiments.basemodel as basemodel

    real, cache, calls = basemodel.choose_base, {}, []

    def memoised(dataset, log=None, level=0.01):
        key = (_fingerprint(dataset), float(level))
        calls.append(key)
        if key not in cache:
            cache[key] = real(dataset, log, level)
        return cache[key]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(basemodel, "choose_base", memoised)
        yield calls


def _run(argv, capsys) -> tuple[int, str]:
    code = dvs(argv)
    out = capsys.readouterr()
    assert code == 0, out.err
    return code, out.out


@pytest.fixture(scope="module")
def outputs(tissue, shared_step0, tmp_path_factory):
    """The four commands with their defaults (non-model options only to keep it fast):
    the JSON each writes and the lines each prints."""
    root = tmp_path_factory.mktemp("outs")
    runs = {
        "fit": (["fit", str(tissue)], "result.json"),
        "diagnose": (["diagnose", str(tissue), "--max-effects", "0"], "diagnosis.json"),
        "image": (["image", str(tissue), "--field", "3x3", "--weight", "100"], "image.json"),
        "design": (["design", str(tissue), "--budget", "2", "--contacts", "2"], "design.json"),
    }
    import contextlib
    import io

    documents, printed = {}, {}
    for name, (argv, filename) in runs.items():
        stream = io.StringIO()
        with contextlib.redirect_stdout(stream):
            code = dvs([*argv, "--out", str(root / name)])
        assert code == 0, stream.getvalue()
        documents[name] = json.loads((root / name / filename).read_text())
        printed[name] = stream.getvalue()
    return documents, printed, list(shared_step0)


def _choices(record: dict) -> dict:
    """A base_choice without its timings, and without what the loop of dvs diagnose adds
    to it afterwards (``revisits``: the surroundings re-estimated after an effect)."""
    record = json.loads(json.dumps(record))
    record.pop("seconds")
    record.pop("revisits", None)
    for trial in [record["paper"], record["continuum"], *record["trials"]]:
        if trial is not None:
            trial.pop("seconds")
    for check in record["resolution"]:
        check.pop("seconds", None)
    return record


def _difference(a, b, path=""):
    """The first path where two JSON documents differ, with both values."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                return _difference(a.get(key), b.get(key), f"{path}.{key}")
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for k, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return _difference(x, y, f"{path}[{k}]")
    return path, a, b


def test_the_four_commands_record_and_print_the_same_choice(outputs):
    documents, printed, calls = outputs
    assert len(calls) == 4 and len(set(calls)) == 1  # one dataset, one level, four runs
    records = {name: _choices(document["base_choice"]) for name, document in documents.items()}
    for name, record in records.items():
        assert record == records["fit"], (name, _difference(record, records["fit"]))
    choice = records["fit"]
    assert choice["chosen"] == "linear-elastic"  # FE tissue: the continuum wins
    lines = {
        name: [ln.strip() for ln in text.splitlines() if "base model: " in ln][0]
        for name, text in printed.items()
    }
    assert len(set(lines.values())) == 1, lines
    continuum, surroundings = choice["continuum"], choice["surroundings"]
    grid = "x".join(map(str, continuum["grid"]))
    assert lines["fit"].startswith(f"base model: linear-elastic, grid {grid}, degrees 2x2x2")
    assert f"probe r {surroundings['probe_radius_mm']:.2f} mm" in lines["fit"]


def test_the_four_commands_use_the_chosen_model(outputs):
    """Each command's own record of the volume it used is step 0's continuum."""
    documents, _, _ = outputs
    choice = documents["fit"]["base_choice"]
    continuum, surroundings = choice["continuum"], choice["surroundings"]
    expected = {
        "energy": "linear-elastic",
        "grid": continuum["grid"],
        "degrees": continuum["degrees"],
        "margin_mm": surroundings["margin_mm"],
        "support": surroundings["support"],
    }
    fit = documents["fit"]["model"]
    assert fit["energy"] == "linear-elastic" and fit["grid"] == continuum["grid"]
    assert fit["degrees"] == continuum["degrees"] and fit["margin_mm"] == continuum["margin_mm"]
    assert fit["boundary_conditions"]["fix_lateral"] == (surroundings["support"] == "clamped")
    for name in ("image", "design"):
        model = documents[name]["model"]
        assert {k: model[k] for k in expected} == expected, name
        assert model["probe_radius_mm"] == pytest.approx(surroundings["probe_radius_mm"])
    image = documents["image"]["model"]
    assert image["source"] == "step 0" and image["note"] == ""
    assert image["resolution"] == documents["image"]["base_choice"]["resolution"]
    # the map's reference is the continuum's homogeneous fit: fit's E and nu
    fitted = documents["fit"]["parameters"]
    assert image["E_ref_kPa"] == pytest.approx(fitted["E"]["value"], rel=1e-3)
    assert image["nu"] == pytest.approx(fitted["nu"]["value"], rel=1e-3)
    assert documents["diagnose"]["refinement"]["verdict"] == "not checked"


def test_the_new_keys_of_image_and_design_json_are_documented(outputs):
    """image.json's and design.json's ``model`` and ``base_choice`` in docs/formats.md
    (base_choice's own keys in its diagnosis.json row; parameter names are data)."""
    from pathlib import Path

    documents, _, _ = outputs
    formats = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()

    def section(title: str) -> str:
        return formats.split(f"## {title}", 1)[1].split("\n## ", 1)[0]

    def keys(document) -> set:
        if isinstance(document, dict):
            return set(document) | set().union(*map(keys, document.values()))
        if isinstance(document, list):
            return set().union(set(), *map(keys, document))
        return set()

    from symbolic.model import PARAMETERS

    data = set(PARAMETERS)  # parameter names are data, not keys of the format
    for name, title in (("image", "image.json"), ("design", "design.json")):
        text = section(title)
        document = documents[name]
        assert "`base_choice`" in text and "`model`" in text
        missing = keys(document["model"]) - data - {k for k in keys(document) if f"`{k}`" in text}
        assert not missing, (name, sorted(missing))
    row = section("diagnosis.json")
    inner = keys(documents["image"]["base_choice"]) - data
    assert sorted(k for k in inner if f"`{k}`" not in row) == []


def test_when_step_0_keeps_the_papers_energy_the_map_says_whose_continuum(tissue, shared_step0):
    """The fallback's words and model (step 0 run on the patch, then read as if the
    paper's energy had been kept): the map is of the best continuum tried, with its
    probe radius and volume, and the line says why."""
    from dataclasses import replace

    import experiments.basemodel as basemodel
    from experiments.data.dataset import load_dataset
    from experiments.imaging.continuum import SOURCES, ImagingModel, fallback_note

    dataset = load_dataset(tissue)
    choice = basemodel.choose_base(dataset)  # the module's shared run
    kept = replace(choice, chosen=choice.paper)
    note = fallback_note(kept, SOURCES[1])
    assert "keeps the paper's energy (BIC" in note and "best continuum" in note
    model = ImagingModel(kept.record(), choice.continuum, SOURCES[1], [], note)
    grid = "x".join(map(str, choice.continuum.settings.grid))
    assert model.line().startswith(f"imaging on linear-elastic, grid {grid}, degrees 2x2x2")
    assert model.line().endswith(f"({note})") and model.base_choice["chosen"] == "dnurbs"
    radius = choice.continuum.surroundings.radius_mm
    assert np.allclose(model.dataset(dataset).probe_radius, radius)
    settings = model.settings()
    assert settings.names == ("E", "nu") and settings.grid == choice.continuum.settings.grid
    assert model.problem().space.names == ("E", "nu")
    assert "did not try" in fallback_note(kept, SOURCES[2])
    assert fallback_note(choice, SOURCES[0]) == ""


def test_on_phantom_data_design_keeps_the_papers_energy(tmp_path, capsys):
    """Step 0 keeps dnurbs (it fits at the noise) and the design is the one of
    ``--energy dnurbs``, press for press."""
    from experiments.design.predictions import NOISE_MM, phantom_dataset

    data = tmp_path / "phantom.npz"
    save_dataset(data, phantom_dataset({}, 1, "diagnosis", NOISE_MM))
    options = ["--budget", "2", "--contacts", "2"]
    documents = {}
    for name, energy in (("auto", []), ("dnurbs", ["--energy", "dnurbs"])):
        _, out = _run(
            ["design", str(data), *options, *energy, "--out", str(tmp_path / name)], capsys
        )
        documents[name] = json.loads((tmp_path / name / "design.json").read_text())
        assert ("base model: dnurbs, grid auto, degrees 3x3x1" in out) == (name == "auto")
    auto, paper = documents["auto"], documents["dnurbs"]
    assert auto["base_choice"]["chosen"] == "dnurbs" and auto["base_choice"]["continuum"] is None
    assert "base_choice" not in paper
    assert auto["model"] == paper["model"] and auto["model"]["energy"] == "dnurbs"
    for key in ("contact_mm", "force_N"):  # step 0 fits on one BLAS thread: equal to rounding
        np.testing.assert_allclose(
            [p[key] for p in auto["presses"]], [p[key] for p in paper["presses"]], atol=1e-9
        )
    errors = [d["predicted"]["standard_errors"] for d in (auto, paper)]
    assert errors[0] == pytest.approx(errors[1], rel=1e-6)


@pytest.mark.parametrize(
    "command, options",
    [
        ("image", ["--grid", "7x7x2"]),
        ("image", ["--degrees", "3x3x2", "--margin", "10"]),
        ("design", ["--margin", "5"]),
        ("design", ["--grid", "9x9x2", "--degrees", "3x3x1"]),
    ],
)
def test_model_options_without_an_energy_exit_2(tmp_path, capsys, command, options):
    """As fit and diagnose: --grid, --degrees and --margin set the volume of a chosen
    --energy; without one, exit 2 with one line and nothing written."""
    data = tmp_path / "d.npz"
    data.write_bytes(b"")
    out = tmp_path / "out"
    assert dvs([command, str(data), *options, "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and "step 0 chooses the volume" in error and options[0] in error
    assert not out.exists()


@pytest.mark.slow
def test_each_command_runs_its_own_step_0(tissue, tmp_path, capsys):
    """Unshared: four processes' worth of step 0 (in one process) choose alike."""
    runs = {
        "fit": (["fit", str(tissue)], "result.json"),
        "diagnose": (["diagnose", str(tissue), "--max-effects", "0"], "diagnosis.json"),
        "image": (["image", str(tissue), "--field", "3x3", "--weight", "100"], "image.json"),
        "design": (["design", str(tissue), "--budget", "2", "--contacts", "2"], "design.json"),
    }
    records = []
    for name, (argv, filename) in runs.items():
        _run([*argv, "--out", str(tmp_path / name)], capsys)
        document = json.loads((tmp_path / name / filename).read_text())
        records.append(_choices(document["base_choice"]))
    assert all(record == records[0] for record in records)


@pytest.mark.slow
def test_image_on_phantom_data_searches_the_continuum(tmp_path, capsys):
    """Step 0 keeps the paper's energy without trying the continuum: dvs image says so,
    searches the continuum's surroundings itself and records where its model came from."""
    data = tmp_path / "phantom.npz"
    assert dvs(["simulate", "--out", str(data)]) == 0
    _, out = _run(
        ["image", str(data), "--field", "3x3", "--weight", "100", "--out", str(tmp_path / "image")],
        capsys,
    )
    assert "base model: dnurbs" in out and "did not try the continuum" in out
    record = json.loads((tmp_path / "image" / "image.json").read_text())
    assert record["base_choice"]["chosen"] == "dnurbs"
    assert record["model"]["source"] == "continuum search"
    assert record["model"]["energy"] == "linear-elastic" and record["model"]["resolution"]
