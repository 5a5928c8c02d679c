"""Research scripts are importable and run headless; each test checks one key number."""

import numpy as np
import pytest

from experiments.inverse import compare, paper
from experiments.phantom import forward
from experiments.phantom.simulate import simulate
from experiments.problem.fitting import FitSettings, build_problem


def test_forward_script_reports_the_probe_displacement(tmp_path):
    summary = forward.run(tmp_path, force=0.25, log=lambda *_: None)
    assert -0.6 < summary["probe_displacement_mm"][2] < -0.3
    assert summary["relative_residual"] < 1e-10
    assert (tmp_path / "forward.png").exists()


def test_paper_script_flags_mu_and_recovers_alpha(tmp_path):
    result = paper.run(tmp_path, log=lambda *_: None)
    joint = result["rows"][-1]["parameters"]
    assert joint["mu"]["note"] == "not identifiable from static data"
    for name, truth in (("alpha_u", 2.6), ("alpha_v", 0.18), ("alpha_w", 1.7)):
        assert abs(joint[name]["value"] - truth) < 3 * joint[name]["std"]
    assert (tmp_path / "table1.md").read_text().count("|") > 20


def test_compare_finds_the_same_optimum_with_both_fast_methods():
    problem = build_problem(simulate(), FitSettings(names=compare.ALPHAS))
    rows = compare.compare(
        problem, starts=4, methods=("simultaneous", "nested"), log=lambda *_: None
    )
    estimates = [np.array(list(rows[m]["estimate"].values())) for m in ("simultaneous", "nested")]
    assert np.allclose(*estimates, rtol=1e-6)
    assert rows["simultaneous"]["success_rate"] == 1.0
    assert "success rate" in compare.table(rows)


def test_benchmark_measures_in_a_fresh_process_and_judges_the_targets(capsys):
    """bench: a power law's exponent is recovered; one isolated 9x9x2 measurement
    carries timings, iterations and peak memory; the targets block names each target."""
    from experiments.inverse.bench import _inverse_job, isolated
    from experiments.inverse.benchtables import print_targets, scaling_exponent

    assert scaling_exponent([1e2, 1e3, 1e4], [3e-2, 3e0, 3e2]) == pytest.approx(2.0)
    row = isolated(_inverse_job, (9, 9, 2), "simultaneous")
    assert row["build"] > 0 and row["solve"] > 0 and row["iterations"] > 0
    assert row["total"] >= row["build"] + row["solve"] - 1e-9
    assert row["peak_mb"] > 50 and row["dofs"] == 243
    paper = {**row, "total": 100.0 * row["total"]}
    print_targets([], {(9, 9, 2): {"simultaneous": row, "paper": paper}})
    out = capsys.readouterr().out
    assert "[met] 9x9x2 paper-faithful / simultaneous (build incl.): 100x" in out
    assert "median of 5 repeats" in out
