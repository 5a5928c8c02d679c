"""Atomic output files: write to a temporary file beside the target, then rename.

Every writer here follows the same steps:

1. create a temporary file in the directory of ``path`` (same file system, so the
   final rename is atomic);
2. write, flush and ``fsync`` it;
3. ``os.replace`` it onto ``path`` and ``fsync`` the directory (where supported).

If anything fails, the temporary file is removed and the exception propagates:
no partial file ever appears at ``path``, and an existing file there is left untouched.
The new file gets the usual permissions (``0o666`` less the umask), or keeps the mode
of the file it replaces.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np

PathLike = str | os.PathLike


def _current_umask() -> int:
    """Return the process umask (read once; setting it back immediately)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


_DEFAULT_MODE = 0o666 & ~_current_umask()


def _target_mode(path: Path) -> int:
    """Permission bits for the new file: those of the file replaced, else the default."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except OSError:
        return _DEFAULT_MODE


def _fsync_directory(directory: Path) -> None:
    """Make the rename durable; silently skipped where directories cannot be opened."""
    with contextlib.suppress(OSError):
        descriptor = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def _replace_with(target: Path, suffix: str, fill: Callable[[int, str], None]) -> Path:
    """Create a temporary file beside ``target``, let ``fill`` write and sync it, rename it.

    ``fill(descriptor, name)`` owns the open descriptor. On any failure the temporary
    file is removed and ``target`` is untouched.
    """
    descriptor, temporary = tempfile.mkstemp(
        prefix=f".{target.name}.", suffix=suffix, dir=target.parent
    )
    try:
        fill(descriptor, temporary)
        os.chmod(temporary, _target_mode(target))
        os.replace(temporary, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    _fsync_directory(target.parent)
    return target


def atomic_write(path: PathLike, write: Callable[[IO[bytes]], None]) -> Path:
    """Write a file atomically through a callback that receives a binary file handle.

    Parameters
    ----------
    path : str or os.PathLike
        Final location. Its directory must exist.
    write : callable
        ``write(handle)`` writes the whole content to the open binary ``handle``.

    Returns
    -------
    pathlib.Path
        The path written.
    """

    def fill(descriptor: int, name: str) -> None:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())

    return _replace_with(Path(path), ".tmp", fill)


def atomic_write_by_name(path: PathLike, write: Callable[[Path], None]) -> Path:
    """Write a file atomically through a writer that only takes a file name (e.g. meshio).

    The writer gets a temporary name beside ``path`` with the same suffix (so that a
    format taken from the suffix is right); the file is then synced and renamed.
    """
    target = Path(path)

    def fill(descriptor: int, name: str) -> None:
        os.close(descriptor)
        write(Path(name))
        with open(name, "rb+") as handle:
            os.fsync(handle.fileno())

    return _replace_with(target, target.suffix, fill)


def atomic_write_bytes(path: PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    return atomic_write(path, lambda handle: handle.write(data))


def atomic_write_text(path: PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8 by default) and return the path."""
    return atomic_write_bytes(path, text.encode(encoding))


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` into plain JSON types.

    NumPy scalars become Python scalars, arrays become nested lists, tuples and sets
    become lists, paths become strings, and non-finite floats (NaN, +-inf) become
    ``None`` (JSON ``null``). Dictionary keys that are NumPy scalars become Python ones.
    """
    if isinstance(obj, dict):
        return {_jsonable_key(key): to_jsonable(value) for key, value in obj.items()}
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(item) for item in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def _jsonable_key(key: Any) -> Any:
    """Dictionary key for JSON: NumPy scalars become Python scalars."""
    return key.item() if isinstance(key, np.generic) else key


def atomic_write_json(path: PathLike, obj: Any) -> Path:
    """Write ``obj`` as JSON (indent 2, trailing newline) atomically.

    NumPy values are converted and NaN/inf are written as ``null`` (see
    :func:`to_jsonable`); the output is always strict JSON.
    """
    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False) + "\n"
    return atomic_write_text(path, text)


def atomic_save_npz(path: PathLike, **arrays: Any) -> Path:
    """Save named arrays as an uncompressed ``.npz`` archive atomically.

    Unlike :func:`numpy.savez`, no ``.npz`` suffix is appended: the file is written
    exactly at ``path``. Object arrays are refused (they would need pickle to load).
    """
    for name, value in arrays.items():
        if np.asarray(value).dtype == object:
            raise ValueError(f"{name}: object arrays cannot be saved; use a numeric dtype")
    return atomic_write(path, lambda handle: np.savez(handle, **arrays))


VECTOR_TWIN = "pdf"
"""Every PNG figure is also written as a vector twin with this suffix (None: off)."""


def atomic_savefig(fig: Any, path: PathLike, **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically; the format comes from the suffix of ``path``.

    A PNG also gets a PDF twin beside it (``VECTOR_TWIN``), for papers.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure to save.
    path : str or os.PathLike
        Output file, e.g. ``fit.png`` or ``fit.pdf``.
    **kwargs
        Passed to :meth:`matplotlib.figure.Figure.savefig` (``format`` overrides the
        suffix).
    """
    target = Path(path)
    file_format = kwargs.pop("format", None) or target.suffix.lstrip(".").lower()
    if not file_format:
        raise ValueError(f"{target}: no file suffix to take the figure format from; add e.g. .png")
    written = atomic_write(target, lambda handle: fig.savefig(handle, format=file_format, **kwargs))
    if file_format == "png" and VECTOR_TWIN:
        twin = target.with_suffix("." + VECTOR_TWIN)
        vector = {k: v for k, v in kwargs.items() if k != "dpi"}
        atomic_write(twin, lambda handle: fig.savefig(handle, format=VECTOR_TWIN, **vector))
    return written
