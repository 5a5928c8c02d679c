"""The dvs command: exit codes, one-line errors, no partial output, result.json."""

import json

import numpy as np
import pytest
from conftest import exit_code_and_stderr
from test_dataset import make_dataset, malformed_corpus

from experiments.cli import main


@pytest.fixture(scope="module")
def dataset_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "phantom.npz"
    assert main(["simulate", "--noise", "0.02", "--seed", "1", "--out", str(path)]) == 0
    return path


def test_fit_writes_result_json_with_identifiability_flags(dataset_file, tmp_path, capsys):
    out = tmp_path / "fit"
    assert main(["fit", str(dataset_file), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.count("not identifiable from static data") == 2  # mu and gamma
    document = json.loads((out / "result.json").read_text())
    assert document["schema"] == "dvs-result/1"
    params = document["parameters"]
    for name in ("mu", "gamma"):
        assert params[name]["identifiable"] is False and params[name]["std"] is None
    for name in ("alpha_u", "alpha_v", "alpha_w"):
        assert params[name]["identifiable"] and params[name]["std"] > 0
        assert params[name]["unit"] == "N/mm"
    assert set(document["per_load_rms_mm"]) == {"0.17 N", "0.25 N"}
    assert document["rms_mm"] < 0.1 and document["solver"]["forward_solves"] >= 1
    assert document["model"]["grid"] == [9, 9, 2]
    assert (out / "residual_map.png").stat().st_size > 0


def test_fit_methods_agree_through_the_cli(dataset_file, tmp_path):
    values = {}
    for method in ("simultaneous", "nested"):
        out = tmp_path / method
        args = [
            "fit",
            str(dataset_file),
            "--method",
            method,
            "--params",
            "alpha_u,alpha_v,alpha_w",
            "--out",
            str(out),
        ]
        assert main(args) == 0
        doc = json.loads((out / "result.json").read_text())
        values[method] = np.array([doc["parameters"][n]["value"] for n in doc["parameters"]])
    assert np.allclose(values["simultaneous"], values["nested"], rtol=1e-6)


def test_every_malformed_dataset_exits_2_with_one_line_and_no_output(tmp_path, capsys):
    corpus = malformed_corpus(make_dataset(with_optional=True))
    assert len(corpus) >= 10
    for kind, arrays in corpus.items():
        path = tmp_path / f"{kind.replace(':', '_')}.npz"
        np.savez(path, **arrays)
        out = tmp_path / f"out-{kind.replace(':', '_')}"
        code = main(["fit", str(path), "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 2, kind
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, kind
        assert kind.split(":")[0] in err, kind
        assert not out.exists(), kind


@pytest.mark.parametrize(
    "args,fragment",
    [
        (["fit", "missing.npz", "--out", "x"], "missing.npz"),
        (["fit", "{data}", "--grid", "9x9", "--out", "x"], "--grid"),
        (["fit", "{data}", "--params", "alpha_q", "--out", "x"], "alpha_q"),
        (["simulate", "--noise", "-1", "--out", "a.npz"], "--noise"),
        (["simulate", "--out", "a.txt"], ".npz"),
        (["fit"], "required"),
        (["nonsense"], "invalid choice"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    args, fragment, dataset_file, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{data}", str(dataset_file)) for a in args]
    code, err = exit_code_and_stderr(main, args, capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and fragment in err
    assert not (tmp_path / "x").exists()
