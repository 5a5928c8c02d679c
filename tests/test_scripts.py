"""Research scripts are importable and run headless; each test checks one key number."""

import numpy as np

from experiments import compare, forward, paper
from experiments.fitting import FitSettings, build_problem
from experiments.simulate import simulate


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
