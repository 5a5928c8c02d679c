"""The options of the imaging commands that need checking: the field's shape and the
regularisation weight (docs/cli.md, ``dvs image``).

Kept apart from the commands so that a bad option, and the studies that share them, answer
before the solvers are imported.
"""

from __future__ import annotations

import math

MAX_FIELD_SIZE = 2000
"""Largest number of field coefficients ``dvs image`` accepts."""


def parse_field(text: str, over: str) -> tuple[int, ...]:
    """'5x5' (surface) or '5x5x3' (layers, volume): nodes per direction, at least 2 along u, v."""
    from experiments.command.options import UsageError

    wanted = 2 if over == "surface" else 3
    try:
        shape = tuple(int(part) for part in text.lower().split("x"))
    except ValueError:
        shape = ()
    least = (2, 2, 2 if over == "volume" else 1)
    if len(shape) != wanted or any(n < m for n, m in zip(shape, least)):
        example = "5x5" if wanted == 2 else "5x5x2"
        raise UsageError(
            f"--field must look like {example} for --over {over} "
            f"(at least {'x'.join(map(str, least[:wanted]))} nodes), got {text!r}"
        )
    size = math.prod(shape)
    if size > MAX_FIELD_SIZE:
        raise UsageError(f"--field {text}: at most {MAX_FIELD_SIZE} coefficients, got {size}")
    return shape


def parse_weight(text: str) -> str | float:
    """'morozov', 'gcv', 'lcurve' or a positive beta [mm^2]."""
    from experiments.command.options import UsageError

    if text in ("morozov", "gcv", "lcurve"):
        return text
    try:
        beta = float(text)
    except ValueError:
        beta = float("nan")
    if not beta > 0 or beta == float("inf"):
        raise UsageError(
            f"--weight must be morozov, gcv, lcurve or a positive number [mm^2], got {text!r}"
        )
    return beta
