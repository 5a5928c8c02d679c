"""Reading ``.npz`` archives safely: regular files only, members checked before they are read.

An archive can lie: a member's ``.npy`` header may claim far more elements than the
member holds (numpy would then allocate them before noticing), a compressed member may
inflate to gigabytes, and a path may name a pipe or a device that blocks on open. So
before any array is read:

1. the path must be an existing regular file (not a directory, pipe, socket or device)
   no larger than ``MAX_FILE_BYTES``;
2. the archive's directory must list ``.npy`` members, each no larger than
   ``MAX_MEMBER_BYTES`` once inflated and all together no larger than ``MAX_TOTAL_BYTES``;
3. each member's header must describe a numeric or string array (never objects, which
   need pickle) whose size is exactly what the member holds.

Only then is the archive read, with ``allow_pickle=False``.
"""

from __future__ import annotations

import os
import stat
import zipfile
from pathlib import Path

import numpy as np

MAX_FILE_BYTES = 2**31
"""Largest archive file accepted [bytes] (2 GiB)."""

MAX_MEMBER_BYTES = 2**29
"""Largest member accepted, inflated [bytes] (512 MiB: a (K, T, U, V, 3) series of
10 x 1000 x 50 x 50 x 3 float64 values is 600 MB)."""

MAX_TOTAL_BYTES = 2**30
"""Largest sum of the inflated members [bytes] (1 GiB)."""


class ArchiveError(ValueError):
    """An archive that cannot be read safely; one line, with the member when there is one.

    Attributes
    ----------
    member : str or None
        The offending member's key (without ``.npy``), or None for the file itself.
    """

    def __init__(self, message: str, member: str | None = None) -> None:
        super().__init__(" ".join(str(message).split()))
        self.member = member


def check_input_file(path: str | os.PathLike, what: str = "file") -> Path:
    """An existing regular file no larger than ``MAX_FILE_BYTES``; never opens it.

    Raises
    ------
    ArchiveError
        For a missing path, a directory, a pipe, socket or device, an unreadable or an
        oversized file.
    """
    source = Path(path)
    try:
        info = source.stat()
    except FileNotFoundError:
        raise ArchiveError(f"{what} not found; check the path") from None
    except OSError as error:
        raise ArchiveError(f"cannot be read ({error.strerror or error}); check the path") from None
    if stat.S_ISDIR(info.st_mode):
        raise ArchiveError(f"is a directory, not a {what}")
    if not stat.S_ISREG(info.st_mode):
        raise ArchiveError(f"is not a regular file (a pipe, socket or device); give a {what}")
    if info.st_size > MAX_FILE_BYTES:
        raise ArchiveError(f"is {info.st_size} bytes, over the {MAX_FILE_BYTES} byte limit")
    return source


def _member_key(name: str) -> str:
    return name[:-4] if name.endswith(".npy") else name


def _check_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    """The member's .npy header describes an array of exactly the member's size."""
    key = _member_key(info.filename)
    with archive.open(info) as handle:
        try:
            version = np.lib.format.read_magic(handle)
            reader = {
                (1, 0): np.lib.format.read_array_header_1_0,
                (2, 0): np.lib.format.read_array_header_2_0,
            }.get(version)
            if reader is None:
                raise ValueError(f"unsupported .npy version {version}")
            shape, _, dtype = reader(handle)
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
            raise ArchiveError(f"not a readable .npy member ({error})", key) from None
        header = handle.tell()
    if dtype.hasobject:
        raise ArchiveError("holds Python objects, which need pickle; store numbers", key)
    count = 1
    for extent in shape:
        count *= int(extent)
    claimed = count * dtype.itemsize
    if claimed != info.file_size - header:
        raise ArchiveError(
            f"its header claims shape {tuple(shape)} ({claimed} bytes) but the member holds "
            f"{info.file_size - header}; the file is damaged or forged",
            key,
        )


def read_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive, after the checks of the module docstring.

    Raises
    ------
    ArchiveError
        One line: what is wrong with the file or which member, and why.
    """
    source = check_input_file(path, "dataset (.npz)")
    try:
        with zipfile.ZipFile(source) as archive:
            infos = archive.infolist()
            total = 0
            for info in infos:
                key = _member_key(info.filename)
                if not info.filename.endswith(".npy"):
                    raise ArchiveError("is not a .npy member; an .npz holds arrays only", key)
                if info.file_size > MAX_MEMBER_BYTES:
                    raise ArchiveError(
                        f"inflates to {info.file_size} bytes, over the {MAX_MEMBER_BYTES} "
                        "byte limit of a member",
                        key,
                    )
                total += info.file_size
                _check_header(archive, info)
            if total > MAX_TOTAL_BYTES:
                raise ArchiveError(f"members total {total} bytes, over {MAX_TOTAL_BYTES}")
    except zipfile.BadZipFile as error:
        with open(source, "rb") as handle:
            single = handle.read(6) == b"\x93NUMPY"
        if single:
            raise ArchiveError(
                "holds a single .npy array, not an .npz archive of named arrays"
            ) from None
        raise ArchiveError(
            f"not a readable .npz archive ({error}); write datasets with "
            "experiments.data.dataset.save_dataset"
        ) from None
    except (OSError, EOFError, ValueError) as error:
        if isinstance(error, ArchiveError):
            raise
        raise ArchiveError(f"cannot be read ({error})") from None
    try:
        with np.load(source, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ArchiveError(f"damaged in the archive ({error}); write the file again") from None
