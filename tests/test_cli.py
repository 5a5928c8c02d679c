"""The dvs command: exit codes, one-line errors, no partial output, result.json."""

import json

import numpy as np
import pytest
from conftest import exit_code_and_stderr
from test_dataset import make_dataset, malformed_corpus

from experiments.command.cli import main


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


# ------------------------------------------------------------------------ the verdict
def _variant(dataset_file, tmp_path, name, change) -> str:
    arrays = dict(np.load(dataset_file))
    change(arrays)
    path = tmp_path / f"{name}.npz"
    np.savez(path, **arrays)
    return str(path)


def test_fit_of_clean_data_says_it_explains_them(dataset_file, tmp_path, capsys):
    assert main(["fit", str(dataset_file), "--out", str(tmp_path / "fit")]) == 0
    captured = capsys.readouterr()
    assert "verdict: the fit explains the data" in captured.out
    assert "warning" not in captured.err
    verdict = json.loads((tmp_path / "fit" / "result.json").read_text())["verdict"]
    assert verdict["explains_data"] is True and verdict["p_value"] >= verdict["level"]
    assert 0.5 < verdict["chi2"] / verdict["dof"] < 1.5


def test_fit_with_swapped_surfaces_exits_0_but_says_it_does_not_explain_the_data(
    dataset_file, tmp_path, capsys
):
    """The swapped dataset fits (Solve_Succeeded) at ~100x the noise: the verdict says
    so, and the forces, seen from the swapped surfaces, pull the skin outward.

    The paper's energy (``--energy dnurbs``): the verdict and the warnings are about the
    data, not the base model's choice, and step 0 on data nothing explains refines the
    continuum to its largest grid (minutes); test_basemodel tests step 0."""

    def swap(arrays):
        arrays["outer_rest"], arrays["inner_rest"] = arrays["inner_rest"], arrays["outer_rest"]

    path = _variant(dataset_file, tmp_path, "swapped", swap)
    assert main(["fit", path, "--energy", "dnurbs", "--out", str(tmp_path / "fit")]) == 0
    captured = capsys.readouterr()
    assert "does NOT explain the data" in captured.out
    assert "pulls the skin outward" in captured.err and "Traceback" not in captured.err
    document = json.loads((tmp_path / "fit" / "result.json").read_text())
    assert document["success"] is True
    assert document["verdict"]["explains_data"] is False
    assert document["verdict"]["rms_mm"] > 30 * document["verdict"]["noise_rms_mm"]
    assert any("outward" in w for w in document["warnings"])
    assert any("noise alone" in w for w in document["warnings"])


def test_absurd_forces_are_refused_before_any_work(dataset_file, tmp_path, capsys):
    def huge(arrays):
        arrays["forces"] = arrays["forces"] * 1e30

    path = _variant(dataset_file, tmp_path, "huge", huge)
    code, err = exit_code_and_stderr(main, ["fit", path, "--out", str(tmp_path / "fit")], capsys)
    assert code == 2 and "forces" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "fit").exists()


def test_fit_that_does_not_converge_exits_3_with_success_false(
    dataset_file, tmp_path, capsys, monkeypatch
):
    """A solver that stops without converging: result.json says so and the exit is 3."""
    from dataclasses import replace

    from solvers.inverse.simultaneous import SimultaneousSolver

    solve = SimultaneousSolver.solve

    def failing(self, *args, **kwargs):
        return replace(solve(self, *args, **kwargs), success=False, status="Maximum_Iterations")

    monkeypatch.setattr(SimultaneousSolver, "solve", failing)
    argv = ["fit", str(dataset_file), "--method", "simultaneous", "--out", str(tmp_path / "fit")]
    code, err = exit_code_and_stderr(main, argv, capsys)
    assert code == 3
    assert err.strip().splitlines()[-1].startswith("dvs fit: error: the solver did not converge")
    assert json.loads((tmp_path / "fit" / "result.json").read_text())["success"] is False


def test_the_verdict_statistic_is_the_diagnosis_residual_test(dataset_file):
    """Two code paths, one statistic: at the same parameters, the verdict's chi^2 equals
    the diagnosis's residual test (the same whitening of the rest-marker noise)."""
    from experiments.data.dataset import load_dataset
    from experiments.diagnosis.diagnose import BASE_NAMES
    from experiments.problem.fitting import FitSettings, build_problem, dataset_loads
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit
    from solvers.diagnosis.stats import residual_test
    from solvers.diagnosis.verdict import fit_verdict

    dataset = load_dataset(dataset_file)
    base = build_problem(dataset, FitSettings(names=BASE_NAMES))
    problem = ExtendedProblem(base, dataset_loads(dataset, base.model.volume), [])
    current = fit(problem)
    _, _, states = problem.evaluate(current.p)
    verdict = fit_verdict(base, states, problem.rms(current.residual)[0])
    expected = residual_test(current, dataset.noise_mm)
    assert verdict.statistic == pytest.approx(expected.statistic, rel=1e-9)
    assert verdict.dof == expected.dof and verdict.explains


def test_simulated_stiffening_on_the_diagnosis_design_is_diagnosed(tmp_path, capsys):
    """dvs simulate --design diagnosis --effect nonlinear_stiffening, then dvs diagnose:
    stiffening is selected, and the report notes what this design cannot separate."""
    data = tmp_path / "stiff.npz"
    argv = ["simulate", "--design", "diagnosis", "--effect", "nonlinear_stiffening"]
    assert main([*argv, "--out", str(data)]) == 0
    assert main(["diagnose", str(data), "--out", str(tmp_path / "diag")]) == 0
    document = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert document["selected"][:1] == ["nonlinear_stiffening"]
    assert document["design"]["contacts"] == 5 and document["design"]["tilted_loads"] == 5
    assert document["design"]["cannot_separate"] == ["base_compliance"]
    assert "base_compliance" in (tmp_path / "diag" / "report.md").read_text()
    assert "note:" in capsys.readouterr().out


def test_the_papers_design_is_noted_as_unable_to_separate_four_effects(dataset_file):
    from experiments.data.dataset import load_dataset
    from experiments.diagnosis.design import design_note

    note = design_note(load_dataset(dataset_file))
    assert (note["loads"], note["contacts"], note["tilted_loads"]) == (2, 1, 0)
    assert set(note["cannot_separate"]) == {
        "heterogeneity",
        "bending",
        "pre_tension",
        "base_compliance",
    }
