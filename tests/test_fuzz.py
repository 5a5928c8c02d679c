"""Property-based fuzzing of the input surface: the loader and the dvs contract.

A fast run is part of ``make test`` (derandomised, so CI sees the same cases); the long
campaign runs with ``-m slow`` and prints its case count per class of mutation.
"""

from __future__ import annotations

import collections
import io
import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from fuzzing import (
    PATH_KINDS,
    any_command_argv,
    array_mutation,
    byte_mutation,
    check_contract,
    experiment_mutation,
    hostile_path,
    option_argv,
    time_limit,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_dataset import make_dataset

from experiments.data.dataset import DatasetError, load_dataset, save_dataset, to_arrays, validate
from experiments.phantom.simulate import simulate

FAST = settings(
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    database=None,
)
CAMPAIGN = settings(FAST, derandomize=False)
VALID = to_arrays(make_dataset(with_optional=True))
VALID["marker_std_mm"] = np.full((3, 9, 9), 0.01)
VALID["load_ramp_s"] = np.array(0.05)
_COUNTER = itertools.count()


def _write_bytes(folder, data: bytes):
    path = folder / f"case{next(_COUNTER)}.npz"
    path.write_bytes(data)
    return path


def _saved(arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _loads_or_refuses(path) -> str:
    """The loader's property: a valid Dataset or one DatasetError line, within 20 s."""
    with time_limit(20):
        try:
            dataset = load_dataset(path)
        except DatasetError as error:
            assert "\n" not in str(error)
            return "refused"
    validate(dataset)  # what was accepted is valid, and finite where the format says so
    for key in ("outer_rest", "inner_rest", "forces", "contacts"):
        assert np.all(np.isfinite(getattr(dataset, key))), key
    return "accepted"


def _mutated_loads_or_refuses(arrays, folder) -> str:
    """``_loads_or_refuses`` on mutated arrays saved in ``folder``; "unwritable" when numpy
    cannot write them (nothing to load)."""
    try:
        data = _saved(arrays)
    except (ValueError, TypeError):
        return "unwritable"
    return _loads_or_refuses(_write_bytes(folder, data))


def _dataset_case(command: str, arrays, folder, seconds: int = 60) -> int | None:
    """``dvs command`` on mutated arrays saved in ``folder``, under the contract; its exit
    code, or None when numpy cannot write them (nothing to run)."""
    try:
        path = _write_bytes(folder, _saved(arrays))
    except (ValueError, TypeError):
        return None
    out = folder / f"out{next(_COUNTER)}"
    return check_contract([command, str(path), "--out", str(out)], out, seconds)


def _option_case(data, folder, seconds: int = 60) -> tuple[str, int]:
    """A command line with odd option values drawn from ``data``, on the phantom's dataset
    (saved in ``folder`` once), under the contract; its command and exit code."""
    path = folder / "phantom.npz"
    if not path.exists():
        save_dataset(path, simulate())
    out = folder / f"out{next(_COUNTER)}"
    argv = data.draw(option_argv(str(path), str(out)))
    target = out.with_suffix(".npz") if argv[0] == "simulate" else out
    return argv[0], check_contract(argv, target, seconds)


@settings(FAST, max_examples=300)
@given(mutation=array_mutation(VALID))
def test_loader_accepts_or_refuses_every_mutated_dataset(mutation, tmp_path):
    _, arrays = mutation
    _mutated_loads_or_refuses(arrays, tmp_path)


@settings(FAST, max_examples=150)
@given(mutation=byte_mutation(_saved(VALID)))
def test_loader_accepts_or_refuses_every_damaged_file(mutation, tmp_path):
    _, data = mutation
    _loads_or_refuses(_write_bytes(tmp_path, data))


@pytest.fixture(scope="module")
def phantom_arrays():
    """The phantom's dataset (the CLI fits it in about a second)."""
    return to_arrays(simulate())


@settings(FAST, max_examples=12)
@given(data=st.data())
def test_dvs_fit_keeps_the_contract_on_mutated_datasets(data, phantom_arrays, tmp_path):
    _, arrays = data.draw(array_mutation(phantom_arrays))
    _dataset_case("fit", arrays, tmp_path)


@settings(FAST, max_examples=12)
@given(data=st.data())
def test_options_keep_the_contract(data, phantom_arrays, tmp_path):
    _option_case(data, tmp_path)


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    """A dataset file, a rendered experiment and an unwritable place for outputs."""
    import os

    from experiments.stereo.render import write_synthetic_experiment
    from experiments.stereo.rig import RigSettings

    folder = tmp_path_factory.mktemp("places")
    data = folder / "phantom.npz"
    save_dataset(data, simulate())
    experiment = folder / "run"
    write_synthetic_experiment(experiment, rig=RigSettings(scale=0.5), n_boards=8)
    locked = Path("/sys") if os.geteuid() == 0 else folder / "locked"
    if locked != Path("/sys"):
        locked.mkdir()
        locked.chmod(0o555)
    return folder, data, experiment, locked


def _commands(data, experiment, locked) -> dict:
    """Every command with its positional arguments, and the unwritable output it gets."""
    from experiments.command.cli import COMMANDS

    files = {"simulate": ".npz", "reconstruct": ".npz", "study outoflibrary": ".npz"}
    positional = {"fit": [str(data)], "diagnose": [str(data)], "reconstruct": [str(experiment)]}
    table = {}
    for name in COMMANDS:
        if name == "study render":
            out = str(locked / "run")
        elif name == "realskin strain":
            out = f"--figure {locked / 'x.png'}"
        elif name == "realskin data":
            out = ""
        else:
            out = f"--out {locked / ('x' + files.get(name, ''))}"
        table[name] = (positional.get(name, []), out)
    return table


@pytest.mark.parametrize("kind", PATH_KINDS)
@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_hostile_input_paths_keep_the_contract(command, kind, places, tmp_path):
    _, data, _, _ = places
    path = hostile_path(kind, tmp_path, data)
    out = tmp_path / "out"
    assert check_contract([command, str(path), "--out", str(out)], out, seconds=30) == 2


@settings(FAST, max_examples=40)
@given(data=st.data())
def test_every_command_keeps_the_contract_on_odd_options(data, places):
    folder, dataset, experiment, locked = places
    table = _commands(dataset, experiment, locked)
    name = data.draw(st.sampled_from(sorted(table)))
    positional, out = table[name]
    argv = data.draw(any_command_argv({name: positional}, out))
    check_contract(argv, folder / "never-written", seconds=60)


# ------------------------------------------------------------------ the campaign
@pytest.mark.slow
def test_campaign(tmp_path, phantom_arrays, places, capsys):
    """Hundreds of cases over every class; prints the count per class and outcome."""
    counts: collections.Counter = collections.Counter()

    @settings(CAMPAIGN, max_examples=600)
    @given(mutation=array_mutation(VALID))
    def loader_arrays(mutation):
        label, arrays = mutation
        counts[("loader", label.split(":")[0], _mutated_loads_or_refuses(arrays, tmp_path))] += 1

    @settings(CAMPAIGN, max_examples=300)
    @given(mutation=byte_mutation(_saved(VALID)))
    def loader_bytes(mutation):
        label, data = mutation
        counts[("bytes", label, _loads_or_refuses(_write_bytes(tmp_path, data)))] += 1

    def dataset_cases(command: str, examples: int, seconds: int):
        """A campaign of ``dvs command`` on mutated phantom datasets."""

        @settings(CAMPAIGN, max_examples=examples)
        @given(data=st.data())
        def cases(data):
            label, arrays = data.draw(array_mutation(phantom_arrays))
            code = _dataset_case(command, arrays, tmp_path, seconds)
            if code is not None:
                counts[(command, label.split(":")[0], f"exit {code}")] += 1

        return cases

    fit_cases, diagnose_cases = dataset_cases("fit", 120, 120), dataset_cases("diagnose", 60, 300)

    @settings(CAMPAIGN, max_examples=120)
    @given(data=st.data())
    def option_cases(data):
        command, code = _option_case(data, tmp_path, 120)
        counts[("options", command, f"exit {code}")] += 1

    folder, dataset, experiment, locked = places
    table = _commands(dataset, experiment, locked)
    spec = json.loads((experiment / "experiment.json").read_text())

    @settings(CAMPAIGN, max_examples=200)
    @given(data=st.data())
    def command_cases(data):
        name = data.draw(st.sampled_from(sorted(table)))
        argv = data.draw(any_command_argv({name: table[name][0]}, table[name][1]))
        code = check_contract(argv, folder / "never-written", seconds=120)
        counts[("command", name, f"exit {code}")] += 1

    def path_cases():
        for command in ("fit", "diagnose", "compare", "reconstruct"):
            for kind in PATH_KINDS:
                path = hostile_path(kind, tmp_path, dataset)
                out = tmp_path / f"out{next(_COUNTER)}"
                suffix = ["--out", str(out) + (".npz" if command == "reconstruct" else "")]
                code = check_contract([command, str(path), *suffix], out, seconds=60)
                counts[("path", command, f"exit {code}")] += 1

    @settings(CAMPAIGN, max_examples=40)
    @given(mutation=experiment_mutation(spec))
    def experiment_cases(mutation):
        import cv2

        label, changed, image = mutation
        target = tmp_path / f"exp{next(_COUNTER)}"
        shutil.copytree(experiment, target)
        (target / "experiment.json").write_text(json.dumps(changed))
        picture = target / "cam1_load0.png"
        if image == "white" or image == "noise":
            shape = cv2.imread(str(picture), cv2.IMREAD_GRAYSCALE).shape
            fill = (
                np.full(shape, 255, np.uint8)
                if image == "white"
                else np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
            )
            cv2.imwrite(str(picture), fill)
        elif image == "truncated":
            picture.write_bytes(picture.read_bytes()[:100])
        elif image == "missing":
            picture.unlink()
        out = tmp_path / f"rec{next(_COUNTER)}.npz"
        code = check_contract(["reconstruct", str(target), "--out", str(out)], out, 300)
        counts[("experiment", label.split("/")[0], f"exit {code}")] += 1

    runs = (loader_arrays, loader_bytes, fit_cases, diagnose_cases, option_cases)
    for run in (*runs, command_cases, path_cases, experiment_cases):
        run()
    with capsys.disabled():
        print(f"\nfuzz campaign: {sum(counts.values())} cases")
        for (surface, kind, outcome), n in sorted(counts.items()):
            print(f"  {surface:9} {kind:9} {outcome:9} {n}")
