"""``dvs next``: the next press of an experiment from its data, and appending captures.

The proposal is one step of the sequential loop (``experiments.design.sequential``) on
the data given; these tests check the command around it: the merge of a session's
captures, the files it writes, that the proposal is a press ``dvs simulate --design``
can make, that it promises more than the naive next press (the centre again: a press
the dataset made there, repeated, judged by the same code on the same information), that
the same data give the same proposal, and the bad-input contract.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from experiments.command.cli import main as dvs
from experiments.data.captures import merge_captures
from experiments.data.dataset import load_dataset, save_dataset
from experiments.data.validation import DatasetError


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """FE continuum data (scikit-fem) of the paper's two presses on a stiffness
    gradient, one file per press and both together."""
    from experiments.design.lab import ContinuumLab

    folder = tmp_path_factory.mktemp("next")
    lab = ContinuumLab("stiffness_gradient")
    both = lab.start("paper")
    save_dataset(folder / "both.npz", both)
    for k, capture in enumerate(lab.captures):
        save_dataset(folder / f"press{k}.npz", capture)
    return folder, both, list(lab.captures)


def _central(dataset) -> list[int]:
    """The dataset's presses at its central contact (the one nearest the markers' centre):
    pressing there again is the naive next press the proposal must beat."""
    centre = dataset.outer_rest.reshape(-1, 3)[:, :2].mean(axis=0)
    contacts = dataset.contacts[:, :2]
    nearest = contacts[np.argmin(np.linalg.norm(contacts - centre, axis=1))]
    return [k for k, c in enumerate(contacts) if np.allclose(c, nearest, atol=1e-6)]


def _recorded(monkeypatch, module, name: str) -> dict:
    """Wrap ``module.name`` to keep its arguments and result; the dict also holds the
    function itself (``original``)."""
    recorded = {"original": getattr(module, name)}

    def wrapper(*args, **kwargs):
        result = recorded["original"](*args, **kwargs)
        recorded.update(args=args, kwargs=kwargs, result=result)
        return result

    monkeypatch.setattr(module, name, wrapper)
    return recorded


def _split(dataset, k):
    """The dataset's load ``k`` alone, with its rest capture."""
    return replace(
        dataset,
        forces=dataset.forces[k : k + 1],
        contacts=dataset.contacts[k : k + 1],
        outer_loaded=dataset.outer_loaded[k : k + 1],
        probe_radius=dataset.probe_radius[k : k + 1],
    )


def test_merging_the_presses_of_a_dataset_gives_it_back():
    from experiments.phantom.simulate import SimulationSettings, simulate

    dataset = simulate(measurement=SimulationSettings(seed=3))
    parts = [_split(dataset, k) for k in range(dataset.n_loads)]
    merged = merge_captures(parts)
    for key in ("outer_rest", "inner_rest", "forces", "contacts", "probe_radius"):
        assert np.array_equal(getattr(merged, key), getattr(dataset, key)), key
    assert np.array_equal(merged.outer_loaded, dataset.outer_loaded, equal_nan=True)
    assert merged.noise_mm == dataset.noise_mm


def test_a_merge_refuses_captures_it_cannot_put_in_one_frame():
    from experiments.phantom.simulate import SimulationSettings, simulate

    dataset = simulate(measurement=SimulationSettings(seed=3))
    first, second = _split(dataset, 0), _split(dataset, 1)
    shifted = replace(second, outer_rest=second.outer_rest + [0.5, 0.0, 0.0])
    with pytest.raises(DatasetError, match="moved"):
        merge_captures([first, shifted], ["a.npz", "b.npz"])
    # within the noise: kept, on the first capture's rest
    jitter = replace(second, outer_rest=second.outer_rest + 2 * dataset.noise_mm)
    assert np.array_equal(merge_captures([first, jitter]).outer_rest, first.outer_rest)
    other_grid = replace(
        second,
        outer_rest=second.outer_rest[:-1],
        inner_rest=second.inner_rest[:-1],
        outer_loaded=second.outer_loaded[:, :-1],
    )
    with pytest.raises(DatasetError, match="marker grid"):
        merge_captures([first, other_grid])
    with pytest.raises(DatasetError, match="probe_radius"):
        merge_captures([first, replace(second, probe_radius=None)])


def test_next_proposes_a_press_the_simulator_can_make(session, tmp_path, capsys, monkeypatch):
    """On FE data of the paper's two presses, with the defaults (step 0 chooses the
    model): a press inside the marked area, within the safe range, with its reason; for
    the question it answers, and over all the open questions (eq. D7), it promises more
    than pressing the centre again (the dataset's central presses repeated, judged on the
    same information pool)."""
    from experiments.data.designfile import read_presses
    from experiments.design import sequential

    folder, both, _ = session
    out = tmp_path / "n"
    searched = _recorded(monkeypatch, sequential, "search")
    assert dvs(["next", str(folder / "both.npz"), "--budget", "8", "--out", str(out)]) == 0
    document = json.loads((out / "next.json").read_text())
    assert document["schema"] == "dvs-design/1" and document["kind"] == "next"
    assert document["presses_so_far"] == 2 and document["stop"] is None
    [(contact, force)] = read_presses(out / "next.json")
    rest = both.outer_rest.reshape(-1, 3)
    assert np.all(contact[:2] >= rest[:, :2].min(axis=0) - 1e-9)
    assert np.all(contact[:2] <= rest[:, :2].max(axis=0) + 1e-9)
    assert np.linalg.norm(force) == pytest.approx(0.25)
    why = document["why"]
    assert why["question"] in document["open"]
    pool, criterion, _, own = searched["args"][:4]
    [proposed] = searched["result"].chosen
    question = next(q for q in criterion.asked if q.label(pool.layout) == why["question"])

    def ratio(design):
        matrix = pool.totals(design).matrix()
        return question.value(matrix, pool.layout, criterion.sigma) / question.needed

    def progress(design):
        now = criterion.score(pool.totals(own).matrix())
        return criterion.score(pool.totals(design).matrix()) - now

    assert ratio(own + [proposed]) == pytest.approx(why["ratio_after"])  # next.json's value
    naive = [own[k] for k in _central(both)]  # the paper's two presses, both at the centre
    naive_values = [(ratio(own + [k]), progress(own + [k])) for k in naive]
    with capsys.disabled():
        print(why, naive_values)  # -s: the proposal's margins over the naive presses
    assert why["ratio_after"] > max(r for r, _ in naive_values), (why, naive_values)
    assert why["progress"] > max(p for _, p in naive_values), (why, naive_values)
    assert document["model"]["energy"] == "linear-elastic"  # step 0 on FE tissue
    assert "base_choice" in document and document["wall_time_s"] > 0
    assert (out / "next.png").stat().st_size > 0
    assert why["question"] in (out / "report.md").read_text()
    assert "next press at" in capsys.readouterr().out


def test_the_same_captures_give_the_same_proposal_and_the_merged_dataset(session, tmp_path):
    """One file, or the two presses as filmed, give the same press (the proposal is a
    deterministic function of the data); the merge is written for the next round."""
    folder, both, captures = session
    common = ["--budget", "8", "--energy", "linear-elastic", "--grid", "11x11x3"]
    one, two = tmp_path / "one", tmp_path / "two"
    assert dvs(["next", str(folder / "both.npz"), *common, "--out", str(one)]) == 0
    parts = [str(folder / "press0.npz"), str(folder / "press1.npz")]
    assert dvs(["next", *parts, *common, "--out", str(two)]) == 0
    first, second = (json.loads((d / "next.json").read_text()) for d in (one, two))
    assert first["presses"] == second["presses"] and first["why"] == second["why"]
    assert first["questions"] == second["questions"]
    merged = load_dataset(two / "dataset.npz")
    assert np.array_equal(merged.outer_loaded, both.outer_loaded, equal_nan=True)
    assert not (one / "dataset.npz").exists()


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--budget", "0"], "--budget"),
        (["--budget", "2", "--force-range", "0.3", "0.8"], "safe range"),
        (["--budget", "2", "--margin", "5"], "--energy linear-elastic"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, extra, message):
    from experiments.phantom.simulate import SimulationSettings, simulate

    data = tmp_path / "d.npz"
    save_dataset(data, simulate(measurement=SimulationSettings(seed=1)))
    out = tmp_path / "out"
    code = dvs(["next", str(data), *extra, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_an_empty_dataset_exits_2(tmp_path, capsys):
    from experiments.data.dataset import to_arrays
    from experiments.phantom.simulate import SimulationSettings, simulate

    arrays = to_arrays(simulate(measurement=SimulationSettings(seed=1)))
    for key in ("forces", "contacts", "outer_loaded", "probe_radius"):
        if key in arrays:
            arrays[key] = arrays[key][:0]
    np.savez(tmp_path / "empty.npz", **arrays)
    code = dvs(["next", str(tmp_path / "empty.npz"), "--budget", "2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "K >= 1" in err[0]
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def inclusion_data(tmp_path_factory):
    """FE data (scikit-fem) of a 10 mm disc twice as stiff at (6, -5) mm, 10 presses."""
    from experiments.phantom.fe import ReferenceSlab, design_cases, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    slab = ReferenceSlab(elements=(12, 12, 2), inclusion=(6.0, -5.0, 10.0, 2.0))
    forces, contacts = design_cases("diagnosis", slab)
    data = reference_dataset(
        slab, forces, contacts, 4.0, (7, 7), SimulationSettings(noise_mm=0.02, seed=3)
    )
    path = tmp_path_factory.mktemp("field") / "disc.npz"
    save_dataset(path, data)
    return path


@pytest.fixture(scope="module")
def field_proposal(inclusion_data, tmp_path_factory):
    """``dvs next --target field`` on the inclusion data: its output folder, what eq. (I13)
    scored (``press_scores``: the rows, the presses so far, the candidates, the
    templates, the posterior's weights) and the candidates offered (their contacts)."""
    from experiments.design import nextfield
    from solvers.imaging import fielddesign

    out = tmp_path_factory.mktemp("field") / "field"
    argv = ["next", str(inclusion_data), "--budget", "4", "--target", "field", "--out", str(out)]
    with pytest.MonkeyPatch.context() as patch:
        scored = _recorded(patch, fielddesign, "press_scores")
        offered = _recorded(patch, nextfield, "candidates")
        assert dvs(argv) == 0
    return out, scored, offered


def _field_margins(field_proposal, naive) -> dict:
    """The proposal's and the presses ``naive``'s (pool rows, each added alone to the
    presses so far) eq. (I13) score and information at the posterior's mode, with the
    proposal's values from next.json checked against the recorded rows."""
    out, scored, _ = field_proposal
    why = json.loads((out / "next.json").read_text())["why"]
    rows, own, pool, templates, weights = scored["args"]
    proposed = pool[int(np.argmax(scored["result"]))]
    mode = int(np.argmax(weights))

    def information(design):
        return float(np.sum((rows.select(design)[0] @ templates[:, mode]) ** 2))

    assert information(own + [proposed]) == pytest.approx(why["information_after"])
    assert float(np.max(scored["result"])) == pytest.approx(why["progress"])
    return {
        "proposal": (why["progress"], why["information_after"]),
        "naive": [
            (float(score), information(own + [k]))
            for k, score in zip(naive, scored["original"](rows, own, naive, templates, weights))
        ],
    }


def _central_presses(inclusion_data, tilted: bool) -> list[int]:
    """The dataset's presses at its central contact, tilted or along the normal."""
    dataset = load_dataset(inclusion_data)
    forces = dataset.forces
    along = np.linalg.norm(forces[:, :2], axis=1) > 1e-9 * np.linalg.norm(forces, axis=1)
    return [k for k in _central(dataset) if along[k] == tilted]


def test_next_for_the_stiffness_map_presses_where_the_inclusion_is_likely(
    field_proposal, inclusion_data
):
    """``--target field``: the posterior's mode lies near the disc (the data's own model
    is step 0's, not the FE slab's), the proposed press lies near the mode, and it
    promises more than pressing the centre again as the candidates press (along the
    normal: the dataset's normal press there repeated, and the candidate at the centre,
    0.25 N), on the same rows: a larger expected growth of the inclusion's signal over
    the posterior (eq. I13), and a larger signal at the mode."""
    from experiments.data.designfile import read_presses

    out, scored, offered = field_proposal
    document = json.loads((out / "next.json").read_text())
    assert document["target"] == "field" and document["stop"] is None
    posterior = document["posterior"]
    assert np.linalg.norm(np.array(posterior["mode_mm"]) - [6.0, -5.0]) <= 5.0
    [(contact, force)] = read_presses(out / "next.json")
    assert np.linalg.norm(contact[:2] - posterior["mode_mm"]) <= 10.0
    assert np.linalg.norm(force) == pytest.approx(0.25)
    dataset = load_dataset(inclusion_data)
    centre = dataset.contacts[_central(dataset)[0], :2]
    points = offered["result"][1][:, :2]
    nearest = int(np.argmin(np.linalg.norm(points - centre, axis=1)))
    assert np.linalg.norm(points[nearest] - centre) < 0.5  # the 7 x 7 grid has the centre
    naive = _central_presses(inclusion_data, tilted=False) + [dataset.n_loads + nearest]
    margins = _field_margins(field_proposal, naive)
    print(margins)  # -s: the proposal's (I13 score, information) and the naive presses'
    (score, information), others = margins["proposal"], margins["naive"]
    assert score > max(s for s, _ in others) and information > max(i for _, i in others)


@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="the candidates of --target field press along the normal only (docs/imaging.md, "
    "'Adaptive imaging'); repeating the dataset's 0.25 N press tilted at the centre scores "
    "higher by eq. (I13) (0.456 against the proposal's 0.260) and at the mode (29.5 against "
    "23.3)",
)
def test_next_for_the_stiffness_map_beats_repeating_the_tilted_central_press(
    field_proposal, inclusion_data
):
    """The proposal promises more than repeating any press already made at the centre,
    tilted ones included."""
    naive = _central_presses(inclusion_data, tilted=True)
    assert naive  # the diagnosis design tilts its second press at every contact
    margins = _field_margins(field_proposal, naive)
    print(margins)
    (score, information), others = margins["proposal"], margins["naive"]
    assert score > max(s for s, _ in others) and information > max(i for _, i in others)
