"""The sequential loop (issue 21, part 3): its questions (eq. D6), the lab it presses on,
and ``dvs design --sequential``.

The questions are checked on a linear model with known columns, where every value has
a direct least-squares form; the separation rule (D6') by simulating the loop's chi^2
drops. The closed loop on FE continuum data is a slow study (``-m slow``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from experiments.command.cli import main as dvs
from solvers.design.discrimination import (
    DETECT,
    SEPARATE,
    Discrimination,
    Question,
    lack_of_fit,
    needed_separation,
    questions,
    standings,
)
from solvers.design.pool import Layout, Totals

SIGMA = 0.02


def _effect(name: str, dim: int):
    return SimpleNamespace(name=name, dim=dim, scales=(1.0,) * dim, lower=(0.0,) * dim)


def _linear(rows: int = 120, seed: int = 0):
    """Columns [x (2) | theta_a (1), s_a | theta_b (2), s_b | theta_c (1), s_c] of a
    linear model, columns of very different size (units), and their Layout."""
    rng = np.random.default_rng(seed)
    effects = ((_effect("a", 1), 1.0), (_effect("b", 2), 1.0), (_effect("c", 1), 1.0))
    blocks, columns, start = [], [rng.normal(size=(rows, 2)) * [1e3, 1e-2]], 2
    for effect, _ in effects:
        theta = rng.normal(size=(rows, effect.dim)) * 0.05
        signal = theta @ rng.normal(size=effect.dim) + 0.3 * theta.std() * rng.normal(size=rows)
        columns += [theta, signal[:, None]]
        blocks.append((np.arange(start, start + effect.dim), start + effect.dim))
        start += effect.dim + 1
    matrix = np.hstack(columns)
    layout = Layout(("x1", "x2"), np.ones(2), effects, tuple(blocks))
    return matrix, layout


def _residual(matrix, columns, target):
    """target - its least-squares fit on the columns."""
    basis = matrix[:, columns]
    coefficients = np.linalg.lstsq(basis, target, rcond=None)[0]
    return target - basis @ coefficients


def test_lack_of_fit_is_the_least_squares_residual():
    matrix, layout = _linear()
    gram = matrix.T @ matrix
    nuisance = [0, 1, 4, 5]
    direct = _residual(matrix, nuisance, matrix[:, 3])
    assert lack_of_fit(gram, nuisance, 3) == pytest.approx(direct @ direct, rel=1e-9)
    assert lack_of_fit(gram, [], 3) == pytest.approx(matrix[:, 3] @ matrix[:, 3])


def test_question_values_refit_the_models_effects_and_the_rival():
    """separate a from b: s_a's residual on [x, theta_c (named too), theta_b];
    detect b with a and c named: |P_A s_b|^2, A = theta_b with x, theta_a, theta_c
    projected out (the score test on the named model)."""
    matrix, layout = _linear()
    gram = matrix.T @ matrix
    separate = Question(SEPARATE, 0, 1, (0, 2), 1.0)
    expected = _residual(matrix, [0, 1, 7, 4, 5], matrix[:, 3])
    assert separate.value(gram, layout, SIGMA) == pytest.approx(
        expected @ expected / SIGMA**2, rel=1e-8
    )
    detect = Question(DETECT, 1, None, (0, 2), 1.0)
    nuisance = [0, 1, 2, 7]
    a = np.column_stack([_residual(matrix, nuisance, matrix[:, k]) for k in (4, 5)])
    signal = matrix[:, 6]
    projected = a @ np.linalg.lstsq(a, signal, rcond=None)[0]
    assert detect.value(gram, layout, SIGMA) == pytest.approx(
        projected @ projected / SIGMA**2, rel=1e-8
    )
    assert separate.label(layout) == "separate a from b" and detect.label(layout) == "detect b"


def test_questions_separate_the_named_and_detect_the_rest():
    _, layout = _linear()
    asked = questions(layout, [0], 0.01 / 12, 0.9, 3.84)
    kinds = sorted((q.kind, q.effect, q.rival) for q in asked)
    assert kinds == [(DETECT, 1, None), (DETECT, 2, None), (SEPARATE, 0, 1), (SEPARATE, 0, 2)]
    assert all(q.given == (0,) for q in asked)
    assert needed_separation(3.84, 0.9) == pytest.approx(13.65, abs=0.01)


def test_the_separation_rule_holds_for_simulated_drops():
    """At T_ab = the need of eq. (D6'), the loop's chi^2 drop of the true effect a beats
    the rival b's by more than the margin in at least the goal's share of draws (the
    bound on the variance is an upper bound: somewhat more, never fewer)."""
    rng = np.random.default_rng(3)
    rows, margin, goal = 80, 3.84, 0.9
    x = rng.normal(size=(rows, 2))
    a = rng.normal(size=rows)
    b = 0.8 * a + 0.6 * rng.normal(size=rows)  # a rival close to a
    columns = np.column_stack([x, a, b])
    gram = columns.T @ columns
    unit = lack_of_fit(gram, [0, 1, 3], 2)  # T_ab of a unit theta_a, sigma = 1
    truth = a * np.sqrt(needed_separation(margin, goal) / unit)
    draws = truth + rng.normal(size=(20000, rows))

    def drop(column):
        before = _residual(x, [0, 1], draws.T)
        after = _residual(np.column_stack([x, column]), [0, 1, 2], draws.T)
        return (before**2).sum(axis=0) - (after**2).sum(axis=0)

    separated = np.mean(drop(a) - drop(b) > margin)
    assert goal - 0.01 <= separated <= goal + 0.06


def test_standings_answer_reach_or_give_up():
    """A question already answered, one a single press answers, and one no budget
    reaches; the criterion sums the log of each value / need, capped at 1 (eq. D7)."""
    matrix, layout = _linear()
    pool = SimpleNamespace(layout=layout, blocks=[])
    made = _totals(matrix[:40])
    for part in (matrix[40:80], matrix[80:]):
        pool.blocks.append(_totals(part))
    detect = Question(DETECT, 1, None, (), 1.0)
    value = detect.value(made.matrix(), layout, SIGMA)
    gain = detect.value((made + pool.blocks[1]).matrix(), layout, SIGMA) - value
    asked = [
        Question(DETECT, 1, None, (), 0.5 * value),
        Question(DETECT, 1, None, (), value + 0.5 * gain),
        Question(DETECT, 1, None, (), value + 10 * gain),
    ]
    found = standings(pool, asked, made, [0, 1], SIGMA, remaining=2)
    assert [s.answered for s in found] == [True, False, False]
    assert [s.reachable for s in found] == [True, True, False]
    criterion = Discrimination(tuple(asked), layout, SIGMA)  # eq. (D7): the answered adds 0
    expected = np.log(value / asked[1].needed) + np.log(value / asked[2].needed)
    assert criterion.score(made.matrix()) == pytest.approx(expected)


def _totals(block: np.ndarray) -> Totals:
    """Totals of rows that share no rest marker (no shared noise)."""
    return Totals(block.T @ block, np.zeros((1, block.shape[1])), np.zeros(1))


def test_the_lab_keeps_each_capture_as_it_was_filmed():
    """A press adds a capture and leaves the earlier ones, and the rest, as they were."""
    from experiments.design.lab import ContinuumLab
    from experiments.diagnosis.continuumstudy import ContinuumStudy
    from experiments.phantom.fe import ReferenceSlab

    lab = ContinuumLab("compliant_base", ContinuumStudy(slab=ReferenceSlab(elements=(8, 8, 2))))
    first = lab.start("paper")
    second = lab.press([5.0, -5.0, 5.0], [0.0, 0.0, -0.25])
    assert first.n_loads == 2 and second.n_loads == 3
    assert np.array_equal(first.outer_rest, second.outer_rest)
    assert np.array_equal(first.outer_loaded, second.outer_loaded[:2], equal_nan=True)
    assert np.allclose(second.contacts[2], [5.0, -5.0, 5.0])
    moved = np.nanmax(np.linalg.norm(second.outer_loaded[2] - second.outer_rest, axis=-1))
    assert moved > 10 * lab.study.noise_mm  # the press deforms the skin
    assert lab.hidden == "base_compliance"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--sequential", "no_such"], "unknown scenario"),
        (["--sequential", "compliant_base", "--budget", "2"], "at least 3"),
        (["data.npz", "--sequential", "compliant_base"], "no DATASET"),
        ([], "DATASET"),
    ],
)
def test_sequential_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    code = dvs(["design", *argv, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0]
    assert not out.exists()


@pytest.mark.slow
def test_the_sequential_loop_names_nothing_when_nothing_is_hidden(tmp_path):
    """``dvs design --sequential none`` on FE continuum data, from the paper's two loads:
    "explained" with nothing named within 3 presses, and the path written (about 4
    minutes). The three hidden-effect scenarios are a study (docs/results/sequential-loop.md),
    not a test: they do not yet meet the issue's acceptance at the 15x15x3 loop grid."""
    import json

    out = tmp_path / "seq"
    assert dvs(["design", "--sequential", "none", "--budget", "3", "--out", str(out)]) == 0
    document = json.loads((out / "sequential.json").read_text())
    assert document["verdict"] == "explained" and document["named"] == []
    assert document["presses"] <= 3 and document["path"][0]["presses"] == 2
    assert (out / "path.png").stat().st_size > 0 and "| presses |" in (
        out / "report.md"
    ).read_text()
