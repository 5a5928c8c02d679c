"""Hostile inputs for the contract tests: mutated datasets, damaged files and odd options.

Strategies (hypothesis) draw mutations of a valid dataset's arrays (keys, dtypes,
shapes, values) and of its file's bytes, and command lines with odd option values.
``check_contract`` runs one command in-process and asserts the contract of docs/cli.md:

- exit 0 with a trustworthy result (``success`` true where a JSON says it);
- or exit 2 and one line on stderr, and no output left behind;
- or exit 3 (a computation that did not converge) with one line, and a JSON that says
  ``success: false`` where one is written;
- never a traceback, never an exception out of ``main``, never a hang.
"""

from __future__ import annotations

import io
import json
import signal
import zipfile
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from experiments.command.cli import main
from experiments.data.validation import KNOWN_KEYS, REQUIRED_KEYS

KEYS = (*KNOWN_KEYS, "load_ramp_s", "marker_std_mm")
"""The keys a mutation changes: the format's, and its two documented extras."""
SPECIAL = (np.nan, np.inf, -np.inf, 0.0, -1.0, 1e308, -1e308, 1e-308, 1e150, -1e150, 1e30)
DTYPES = ("bool", "complex128", "int8", "uint8", "float16", "float32", "U4", "S4")


class Hang(Exception):
    """The call outlived its time limit."""


@contextmanager
def time_limit(seconds: int):
    """Raise ``Hang`` when the body runs longer than ``seconds`` (SIGALRM, main thread)."""

    def alarm(signum, frame):
        raise Hang(f"no answer after {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


# ---------------------------------------------------------------------- mutations
@st.composite
def array_mutation(draw, arrays: dict) -> tuple[str, dict]:
    """One change of a valid dataset's arrays; returns (a label, the mutated arrays)."""
    arrays = {k: np.array(v, copy=True) for k, v in arrays.items()}
    key = draw(st.sampled_from(KEYS))
    kind = draw(
        st.sampled_from(("drop", "dtype", "reshape", "values", "scale", "add", "swap", "empty"))
    )
    present = key in arrays
    if kind == "drop" and present:
        del arrays[key]
    elif kind == "dtype" and present:
        dtype = draw(st.sampled_from(DTYPES))
        try:
            with np.errstate(invalid="ignore", over="ignore"):  # NaN or 1e300 to int: meant
                arrays[key] = arrays[key].astype(dtype)
        except (ValueError, TypeError, OverflowError):
            arrays[key] = np.zeros(arrays[key].shape, dtype=dtype)
    elif kind == "reshape" and present:
        shape = draw(st.lists(st.integers(0, 12), min_size=0, max_size=5))
        size = int(np.prod(shape)) if shape else 1
        flat = np.resize(arrays[key].ravel(), size) if arrays[key].size else np.zeros(size)
        arrays[key] = flat.reshape(shape)
    elif kind == "values" and present and arrays[key].dtype.kind == "f":
        value = draw(st.sampled_from(SPECIAL))
        mask = np.zeros(arrays[key].size, dtype=bool)
        count = draw(st.integers(1, max(arrays[key].size, 1)))
        mask[draw(st.permutations(range(mask.size)))[:count]] = True
        flat = arrays[key].ravel()
        flat[mask] = value
        arrays[key] = flat.reshape(arrays[key].shape)
    elif kind == "scale":
        factor = draw(st.sampled_from((1e150, 1e-150, 1e6, -1.0, 0.0, 1e-12)))
        for name in ("outer_rest", "inner_rest", "contacts", "outer_loaded", "outer_series"):
            if name in arrays and arrays[name].dtype.kind == "f":
                with np.errstate(all="ignore"):
                    arrays[name] = arrays[name] * factor
    elif kind == "add":
        shape = draw(st.lists(st.integers(0, 5), max_size=3))
        arrays[key] = np.full(shape, draw(st.sampled_from(SPECIAL)))
    elif kind == "swap" and present:
        other = draw(st.sampled_from([k for k in arrays if k != key] or [key]))
        arrays[key], arrays[other] = arrays[other], arrays[key]
    elif kind == "empty":
        arrays[key] = np.zeros((0,) + (arrays[key].shape[1:] if present else ()))
    return f"{kind}:{key}", arrays


@st.composite
def byte_mutation(draw, data: bytes) -> tuple[str, bytes]:
    """A damaged copy of a valid file's bytes: truncated, flipped, padded or forged."""
    kind = draw(st.sampled_from(("truncate", "flip", "append", "forge", "empty")))
    if kind == "truncate":
        return kind, data[: draw(st.integers(0, len(data) - 1))]
    if kind == "flip":
        copy = bytearray(data)
        for _ in range(draw(st.integers(1, 16))):
            copy[draw(st.integers(0, len(copy) - 1))] ^= draw(st.integers(1, 255))
        return kind, bytes(copy)
    if kind == "append":
        return kind, data + draw(st.binary(min_size=1, max_size=64))
    if kind == "forge":
        return kind, forged_header(data, draw(st.sampled_from(REQUIRED_KEYS)))
    return kind, b""


def forged_header(data: bytes, key: str) -> bytes:
    """The archive with ``key``'s .npy header claiming 10^12 elements."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    name = f"{key}.npy"
    if name not in members:
        return data
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (10**6, 10**6)}
    )
    body = members[name]
    members[name] = header.getvalue() + body[len(header.getvalue()) :]
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for member, payload in members.items():
            archive.writestr(member, payload)
    return out.getvalue()


VALUES = ("0", "-1", "1e308", "nan", "inf", "-inf", "", " ", "x", "1,2", ",", "2x2x2", "9x9x100")


@st.composite
def option_argv(draw, data: str, out: str) -> list[str]:
    """A command line of simulate, fit or forward with odd option values."""
    command = draw(st.sampled_from(("simulate", "fit", "forward")))
    options = {
        "simulate": ("--noise", "--seed", "--effect", "--design"),
        "fit": ("--grid", "--params", "--method", "--objective"),
        "forward": ("--force", "--k0"),
    }[command]
    argv = [command] + ([data] if command == "fit" else [])
    for option in draw(st.lists(st.sampled_from(options), max_size=3)):
        argv += [option, draw(st.sampled_from(VALUES + ("bending=1e6", "heterogeneity=5")))]
    suffix = ".npz" if command == "simulate" else ""
    return argv + ["--out", out + suffix]


# ------------------------------------------------------------------ the contract
def check_contract(argv: list[str], out: Path, seconds: int = 60) -> int:
    """Run ``dvs argv`` in-process and assert the contract; returns the exit code."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with time_limit(seconds), redirect_stdout(stdout), redirect_stderr(stderr):
        try:
            code = main(argv)
        except SystemExit as stop:  # argparse: --help or a usage error
            code = stop.code if isinstance(stop.code, int) else 2
    err = stderr.getvalue()
    label = " ".join(argv)
    assert "Traceback" not in err, f"{label}: {err}"
    assert code in (0, 2, 3), f"{label}: exit {code}: {err}"
    result = out / "result.json"
    if code == 0:
        if result.exists():
            assert json.loads(result.read_text())["success"] is True, label
        return code
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line]
    assert len(lines) == 1, f"{label}: {err}"
    if code == 2:
        assert not out.exists(), f"{label}: left {out}"
    if code == 3 and result.exists():
        assert json.loads(result.read_text())["success"] is False, label
    return code


# ---------------------------------------------------------------- paths and folders
def hostile_path(kind: str, folder: Path, valid: Path) -> Path:
    """An input path of one hostile kind, made inside ``folder``."""
    import os

    path = folder / f"{kind}.npz"
    if kind == "missing":
        return folder / "nowhere" / "x.npz"
    if kind == "directory":
        path.mkdir(exist_ok=True)
    elif kind == "fifo":
        if not path.exists():
            os.mkfifo(path)
    elif kind == "device":
        return Path("/dev/zero")
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "long_name":
        return folder / ("n" * 300 + ".npz")
    elif kind == "loop":
        if not path.is_symlink():
            path.symlink_to(path)
    elif kind == "text":
        path.write_text("outer_rest = 1\n")
    elif kind == "valid_copy":
        path.write_bytes(valid.read_bytes())
    return path


PATH_KINDS = ("missing", "directory", "fifo", "device", "empty", "long_name", "loop", "text")

ODD = VALUES + ("0.5", "3", "100000", "1e9", "-0.5", "paper", "diagnosis", "healthy", "a,b")


@st.composite
def any_command_argv(draw, commands: dict, out: str) -> list[str]:
    """A command line of any dvs command with odd option values and an unwritable output.

    Valid options then stop at the output check, so no command starts its work.
    """
    from experiments.command.cli import command_parser

    name = draw(st.sampled_from(sorted(commands)))
    parser = command_parser(name)
    options = [a for a in parser._actions if a.option_strings and a.option_strings[0] != "-h"]
    argv = [*name.split(), *commands[name]]
    for action in draw(st.lists(st.sampled_from(options), max_size=3)) if options else []:
        argv.append(action.option_strings[-1])
        if action.nargs != 0:
            count = action.nargs if isinstance(action.nargs, int) else 1
            argv += [draw(st.sampled_from(ODD)) for _ in range(count)]
    return argv + out.split()


@st.composite
def experiment_mutation(draw, spec: dict) -> tuple[str, dict, str]:
    """A change of ``experiment.json`` and, optionally, of one image: (label, spec, image)."""
    import copy

    spec = copy.deepcopy(spec)
    fields = ("keep", "cameras", "markers", "board", "loads", "frame", "schema")
    field = draw(st.sampled_from(fields))
    value = draw(
        st.sampled_from(
            (None, 0, -1, 1, 10**9, 1e300, "x", [], {}, [1], [3, 10**6], [[1]], True, float("nan"))
        )
    )
    if field == "keep":
        pass
    elif field == "board" and isinstance(spec["board"], dict):
        spec["board"][draw(st.sampled_from(("pattern", "square_mm", "views")))] = value
    elif field == "loads" and draw(st.booleans()):
        spec["loads"][0][draw(st.sampled_from(("force_N", "contact_mm", "probe_radius_mm")))] = (
            value
        )
    elif value is None:
        spec.pop(field, None)
    else:
        spec[field] = value
    image = draw(st.sampled_from(("none", "white", "noise", "truncated", "missing")))
    return f"{field}/{image}", spec, image
