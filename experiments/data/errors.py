"""The error of a dataset that breaks the format (docs/formats.md): one line, the key."""

from __future__ import annotations

import os


def one_line(error: BaseException) -> str:
    """Exception text squeezed onto one line."""
    return " ".join(str(error).split()) or type(error).__name__


class DatasetError(ValueError):
    """A dataset file or object breaks format v1; the message is one line with the fix.

    Attributes
    ----------
    key : str or None
        The offending key (``None`` for problems with the file itself).
    """

    def __init__(self, message: str, key: str | None = None) -> None:
        text = " ".join(str(message).split())
        super().__init__(f"{key}: {text}" if key is not None else text)
        self.key = key

    def in_file(self, path: str | os.PathLike) -> DatasetError:
        """The same error with the file name in front of the message."""
        error = DatasetError(f"{os.fspath(path)}: {self}")
        error.key = self.key
        return error
