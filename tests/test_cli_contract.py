"""The command-line contract, on every dvs subcommand, in fresh processes.

A bad output path or an option outside its documented range gives exit 2, one line on
stderr that names it, no traceback and no file written, before any work starts: an
expensive command fails in no more CPU time than its own ``--help`` plus a second.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from experiments.command.cli import (
    COMMANDS,
    FORMER,
    GROUPS,
    VERBS,
    build_parser,
    main,
    resolve,
)
from experiments.data.paths import shared_data_dir

ROOT = Path(__file__).resolve().parents[1]

TRUTH_CUBE = shared_data_dir() / "truth-cube" / "uniaxial_positions.csv"
RECIPE = shared_data_dir() / "phantom-compression" / "data" / "EF10_0T"
SKIN_CASE = shared_data_dir() / "skin-extensometer" / "healthy"

DIRECTORY_OUTPUT = {
    "demo": [],
    "fit": ["{data}"],
    "study compare": [],
    "diagnose": ["{data}"],
    "transient": [],
    "study paper": [],
    "bench inverse": [],
    "study batch": [],
    "study forward": [],
    "study dynamic": [],
    "study diagnosis": [],
    "study detection": [],
    "realskin fit": [],
    "study realcheck": ["--data", "{tmp}"],
    "study phantoms": ["--recipes", "EF10_0T"],
    "study truth-cube": [],
    "study continuum": [],
    "image": ["{data}"],
    "bench image": [],
    "study imageadaptive": [],
    "design": ["{data}"],
    "next": ["{data}", "--budget", "3"],
    "bench design": [],
}
"""Commands whose ``--out`` is a directory, with the other arguments they need."""

FILE_OUTPUT = {
    "simulate": ("--out", ".npz", []),
    "reconstruct": ("--out", ".npz", ["{tmp}"]),
    "study outoflibrary": ("--out", ".npz", []),
    "realskin strain": ("--figure", ".png", []),
    "bench sidebyside": ("--json", ".json", ["--other", "{tmp}", "A"]),
    "import truth-cube": ("--out", ".npz", [str(TRUTH_CUBE)]),
    "import compression": ("--out", ".npz", [str(RECIPE)]),
    "import extensometer": ("--out", ".npz", [str(SKIN_CASE)]),
}
"""Commands that write one file: (option, suffix, other arguments)."""

NO_OUTPUT = {"realskin data", "bench board", "study imageweights", "bench factorisation"}
"""Commands that only print."""

EXPENSIVE = (
    "study phantoms",
    "study truth-cube",
    "demo",
    "study compare",
    "study diagnosis",
    "study detection",
    "realskin fit",
    "bench inverse",
    "study continuum",
    "bench image",
    "study imageadaptive",
    "bench design",
)


def _unwritable(tmp: Path) -> Path:
    """A directory no one may write in: /sys for root (chmod does not stop root)."""
    if os.geteuid() == 0:
        return Path("/sys")
    folder = tmp / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    return folder


def _child_cpu() -> float:
    """CPU time [s] of this process's finished children, user and system."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(argv: list[str], cwd: Path) -> tuple[int, str, float]:
    """Exit code, stderr and the child's CPU time [s] (not wall time: a busy machine
    stretches wall time, not the work done; only valid for one child at a time)."""
    begin = _child_cpu()
    done = subprocess.run(
        [sys.executable, "-m", "experiments.command.cli", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"},
    )
    return done.returncode, done.stderr, _child_cpu() - begin


def _fill(args: list[str], data: Path, tmp: Path) -> list[str]:
    return [a.replace("{data}", str(data)).replace("{tmp}", str(tmp)) for a in args]


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    """A scratch folder with a file in it, a dataset and an unwritable directory."""
    tmp = tmp_path_factory.mktemp("contract")
    (tmp / "afile").write_text("not a directory")
    data = tmp / "data.npz"
    subprocess.run(
        [sys.executable, "-m", "experiments.command.cli", "simulate", "--out", str(data)],
        cwd=tmp,
        check=True,
        capture_output=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    return tmp, data, _unwritable(tmp)


def _bad_path_cases(tmp: Path, data: Path, locked: Path) -> list[tuple[str, list[str]]]:
    cases = []
    for name, args in DIRECTORY_OUTPUT.items():
        base = [*name.split(), *_fill(args, data, tmp), "--out"]
        cases += [
            (f"{name}: existing file", [*base, str(tmp / "afile")]),
            (f"{name}: file as parent", [*base, str(tmp / "afile" / "sub")]),
            (f"{name}: unwritable", [*base, str(locked / "dvs-out")]),
        ]
    for name, (option, suffix, args) in FILE_OUTPUT.items():
        base = [*name.split(), *_fill(args, data, tmp), option]
        cases += [
            (f"{name}: a directory", [*base, str(tmp)]),
            (f"{name}: file as parent", [*base, str(tmp / "afile" / f"x{suffix}")]),
            (f"{name}: unwritable", [*base, str(locked / f"x{suffix}")]),
        ]
    cases.append(("render: file as parent", ["study", "render", str(tmp / "afile" / "run")]))
    cases.append(("render: unwritable", ["study", "render", str(locked / "run")]))
    return cases


OUT_OF_RANGE = [
    (["simulate", "--effect", "heterogeneity=5", "--out", "x.npz"], "heterogeneity"),
    (["simulate", "--effect", "bending=1e6", "--out", "x.npz"], "bending"),
    (["simulate", "--effect", "nonlinear_stiffening=-5", "--out", "x.npz"], "nonlinear"),
    (["simulate", "--noise", "nan", "--out", "x.npz"], "--noise"),
    (["simulate", "--seed", "-1", "--out", "x.npz"], "--seed"),
    (["simulate", "--out", "x.txt"], ".npz"),
    (["fit", "{data}", "--grid", "2x2x2", "--out", "o"], "--grid"),
    (["fit", "{data}", "--grid", "9x9x100", "--out", "o"], "--grid"),
    (["fit", "{data}", "--params", ",", "--out", "o"], "--params"),
    (["fit", "{data}", "--margin", "-1", "--out", "o"], "--margin"),
    (["fit", "{data}", "--margin", "5", "--method", "paper", "--out", "o"], "--margin"),
    (["diagnose", "{data}", "--margin", "nan", "--out", "o"], "--margin"),
    (["study continuum", "--margin", "500", "--out", "o"], "--margin"),
    (["study compare", "--starts", "100000", "--out", "o"], "--starts"),
    (["diagnose", "{data}", "--level", "2", "--out", "o"], "--level"),
    (["transient", "--k0", "-1", "--out", "o"], "--k0"),
    (["study paper", "--noise", "-1", "--out", "o"], "--noise"),
    (["bench inverse", "--grids", "2x2x2"], "--grids"),
    (["bench inverse", "--methods", "magic"], "--methods"),
    (["study batch", "--count", "0"], "--count"),
    (["study forward", "--force", "100", "--out", "o"], "--force"),
    (["study dynamic", "--substeps", "0", "--out", "o"], "--substeps"),
    (["study diagnosis", "--seeds", "-1", "--out", "o"], "--seeds"),
    (["study detection", "--factors", "0", "--out", "o"], "--factors"),
    (["study outoflibrary", "--noise", "5", "--out", "x.npz"], "--noise"),
    (["study continuum", "--scenarios", "gravity", "--out", "o"], "--scenarios"),
    (["image", "{data}", "--field", "1x1", "--out", "o"], "--field"),
    (["image", "{data}", "--weight", "-3", "--out", "o"], "--weight"),
    (["image", "{data}", "--field", "5x5", "--over", "layers", "--out", "o"], "--field"),
    (["image", "{data}", "--noise", "0", "--out", "o"], "--noise"),
    (["bench image", "--sizes", "15"], "--sizes"),
    (["bench factorisation", "--grids", "2x2x2"], "--grids"),
    (["bench factorisation", "--solvers", "magic"], "--solvers"),
    (["design", "{data}", "--budget", "0", "--out", "o"], "--budget"),
    (["design", "{data}", "--target", "gravity", "--out", "o"], "--target"),
    (["design", "{data}", "--force-range", "0.1", "2", "--out", "o"], "--force-range"),
    (["design", "{data}", "--target", "rigid_motion", "--out", "o"], "rigid_motion"),
    (["design", "{data}", "--criterion", "d", "--target", "bending", "--out", "o"], "--criterion"),
    (["next", "{data}", "--budget", "0", "--out", "o"], "--budget"),
    (["next", "{data}", "--budget", "2", "--force-range", "0.2", "0.9", "--out", "o"], "range"),
    (["next", "{data}", "--budget", "2", "--grid", "9x9x3", "--out", "o"], "--grid"),
    (["bench design", "--budget", "0"], "--budget"),
    (["bench image", "--methods", "magic"], "--methods"),
    (["diagnose", "{data}", "--degrees", "9x9x9", "--out", "o"], "--degrees"),
    (["realskin fit", "--candidates", "gravity", "--out", "o"], "--candidates"),
    (["realskin strain", "--frames", "x"], "--frames"),
    (["realskin data", "--case", "nope"], "--case"),
    (["study imageweights", "--draws", "0"], "--draws"),
    (["study imageadaptive", "--field", "1x1", "--out", "o"], "--field"),
    (["study realcheck", "--out", "o", "--data", "{tmp}/missing"], "--data"),
    (["study render", "run", "--scale", "100"], "--scale"),
    (["bench board", "--full-size-images", "0"], "--full-size-images"),
    (["bench sidebyside", "--other", "{tmp}", "Z"], "unknown dataset"),
    (["bench sidebyside", "--other", "{tmp}", "A"], "--other"),
    (["demo", "--out", ""], "--out"),
    (["reconstruct", "{tmp}", "--out", "x.txt"], ".npz"),
    (["import truth-cube", str(TRUTH_CUBE), "--out", "x.txt"], ".npz"),
    (["study phantoms", "--recipes", "EF99_0T", "--out", "o"], "--recipes"),
    (["study truth-cube", "--loop-energy", "magic", "--out", "o"], "--loop-energy"),
    (["import compression", str(RECIPE), "--samples", "0", "--out", "x.npz"], "--samples"),
    (["import extensometer", str(SKIN_CASE), "--out", "x.txt"], ".npz"),
    (["reconstruct", "{tmp}", "--intrinsics", "{tmp}/none.json", "--out", "x.npz"], "intrinsics"),
]


def _assert_contract(label: str, code: int, err: str, before: set, after: set) -> None:
    assert code == 2, f"{label}: exit {code}: {err}"
    assert len(err.strip().splitlines()) == 1, f"{label}: {err}"
    assert "Traceback" not in err, f"{label}: {err}"
    assert after == before, f"{label}: wrote {sorted(after - before)}"


def _listing(tmp: Path) -> set:
    return {str(p.relative_to(tmp)) for p in tmp.rglob("*")}


def test_every_command_is_covered():
    covered = set(DIRECTORY_OUTPUT) | set(FILE_OUTPUT) | NO_OUTPUT | {"study render"}
    assert covered == set(COMMANDS)
    assert {argv[0] for argv, _ in OUT_OF_RANGE} == set(COMMANDS)


def test_the_top_level_lists_verbs_and_groups_alone(capsys):
    """``dvs --help`` shows at most 13 entries: the verbs, then the groups (``import``,
    the thirteenth, is the design card's ``dvs import KIND``)."""
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    lines = capsys.readouterr().out.splitlines()
    listed = [line.split()[0] for line in lines if line.startswith("    ") and line.strip()]
    listed = [word for word in listed if word in VERBS or word in GROUPS]
    assert listed == [*VERBS, *GROUPS]
    assert len(listed) <= 13


def test_every_former_name_runs_its_command_in_a_group():
    """The flat names of before the groups (and a group given an option where its
    command goes) reach the same modules, with the arguments as given."""
    for old, new in FORMER.items():
        assert resolve([old, "--out", "x"]) == (new, ["--out", "x"])
        assert new in COMMANDS
    for group, (_, table, default) in GROUPS.items():
        assert default in table
        assert resolve([group, "--out", "x"]) == (f"{group} {default}", ["--out", "x"])
        assert resolve([group]) is None and resolve([group, "--help"]) is None


def _run_here(argv: list[str], capsys) -> tuple[int, str]:
    """Exit code and stderr of ``dvs argv`` run in this process."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr().err


def test_bad_output_paths_exit_2_with_one_line_and_write_nothing(places, capsys):
    """Each command's first bad path in a fresh process (the console's contract), its
    other two in this one (the same ``main``, without a process start per case)."""
    tmp, data, locked = places
    cases = _bad_path_cases(tmp, data, locked)
    fresh = [case for case in cases if case[0].endswith(("existing file", "a directory"))]
    assert len(fresh) == len(DIRECTORY_OUTPUT) + len(FILE_OUTPUT)
    before = _listing(tmp)
    with ThreadPoolExecutor(max_workers=4) as pool:
        results = dict(zip(map(id, fresh), pool.map(lambda case: _run(case[1], tmp), fresh)))
    for case in cases:
        label, argv = case
        code, err = results[id(case)][:2] if id(case) in results else _run_here(argv, capsys)
        _assert_contract(label, code, err, before, _listing(tmp))
        assert any(part in err for part in (argv[-1], Path(argv[-1]).name)), f"{label}: {err}"


def test_out_of_range_options_exit_2_naming_the_option(places, capsys):
    tmp, data, _ = places
    before = _listing(tmp)
    cases = [
        (_fill([*argv[0].split(), *argv[1:]], data, tmp), fragment)
        for argv, fragment in OUT_OF_RANGE
    ]
    firsts = {}
    for case in cases:  # each command's first case in a fresh process, the rest here
        firsts.setdefault(case[0][0], case)
    fresh = list(firsts.values())
    with ThreadPoolExecutor(max_workers=4) as pool:
        results = dict(zip(map(id, fresh), pool.map(lambda case: _run(case[0], tmp), fresh)))
    for case in cases:
        argv, fragment = case
        code, err = results[id(case)][:2] if id(case) in results else _run_here(argv, capsys)
        label = " ".join(argv)
        _assert_contract(label, code, err, before, _listing(tmp))
        assert fragment in err, f"{label}: {err}"


@pytest.mark.parametrize("name", EXPENSIVE)
def test_an_expensive_command_fails_before_any_work(name, places):
    """Bad output path: no more CPU time than the command's own --help plus a second
    (the faster of two runs against one of --help, one child at a time: noise in --help's
    time can only loosen the bound)."""
    tmp, data, _ = places
    help_time = _run([*name.split(), "--help"], tmp)[2]
    argv = [*name.split(), *_fill(DIRECTORY_OUTPUT[name], data, tmp), "--out", str(tmp / "afile")]
    runs = [_run(argv, tmp) for _ in range(2)]
    assert all(code == 2 for code, _, _ in runs)
    elapsed = min(t for _, _, t in runs)
    assert elapsed < help_time + 1.0, f"{name}: {elapsed:.2f} s against --help {help_time:.2f} s"
