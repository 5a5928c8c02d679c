"""Design files (schema ``dvs-design/1``, docs/formats.md): the presses a file asks for.

``dvs design`` and ``dvs next`` write them (``experiments.design``); ``dvs simulate
--design FILE.json`` and the sequential loop's lab read them here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from solvers.design.candidates import MAX_FORCE_N

SCHEMA = "dvs-design/1"


def read_presses(path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The presses of a design file: (contact [mm], force [N]) pairs.

    Raises
    ------
    ValueError
        One line saying what is wrong: not JSON, another schema, no presses, a contact
        or force that is not three finite numbers, or a force outside the safe range
        (0, ``MAX_FORCE_N``].
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"design file {path} does not exist; make one with dvs design")
    try:
        document = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(document, dict) or document.get("schema") != SCHEMA:
        raise ValueError(
            f"{path}: not a design file (schema must be {SCHEMA!r}); make one with dvs design"
        )
    presses = document.get("presses")
    if not isinstance(presses, list) or not presses:
        raise ValueError(f"{path}: 'presses' must be a non-empty list")
    out = []
    for k, press in enumerate(presses, 1):
        try:
            contact = np.asarray(press["contact_mm"], dtype=float)
            force = np.asarray(press["force_N"], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise ValueError(
                f"{path}: press {k} needs contact_mm and force_N, three numbers each"
            ) from None
        if (
            contact.shape != (3,)
            or force.shape != (3,)
            or not np.all(np.isfinite([*contact, *force]))
        ):
            raise ValueError(
                f"{path}: press {k}: contact_mm and force_N must be three finite numbers"
            )
        size = float(np.linalg.norm(force))
        if not 0 < size <= MAX_FORCE_N:
            raise ValueError(
                f"{path}: press {k} has a force of {size:g} N, outside the safe "
                f"range (0, {MAX_FORCE_N:g}] N"
            )
        out.append((contact, force))
    return out
