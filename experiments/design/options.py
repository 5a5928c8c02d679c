"""The options ``dvs design`` and ``dvs next`` share: the candidate presses
(``--contacts``, ``--tilt``, ``--azimuths``, ``--force-range``, ``--levels``, ``--level``:
``experiments.design.plan.DesignSettings``) and the sequential loop's model.

Kept apart from the command modules so that ``dvs next --help`` imports no design code.
"""

from __future__ import annotations

SEQUENTIAL_MODEL = {"grid": None, "degrees": (3, 3, 2), "margin": 10.0}
"""The sequential loop's model when no option says otherwise (``SequentialSettings``;
grid None: its 15 x 15 x 3)."""


def add_candidate_arguments(parser, contacts: str, force_range: str, levels: str) -> None:
    """The candidate presses' options (eq. D4). ``--contacts``, ``--force-range`` and
    ``--levels`` default to None (not given: ``given`` takes the mode's default), which
    ``contacts``, ``force_range`` and ``levels`` state, e.g. "5, 3 with --sequential"."""
    parser.add_argument(
        "--contacts",
        type=int,
        default=None,
        help=f"candidate contacts per side of the grid over the marked area (2-15; default "
        f"{contacts})",
    )
    parser.add_argument(
        "--tilt",
        type=float,
        default=20.0,
        help="tilt of the candidate forces from the normal [deg], 0-60",
    )
    parser.add_argument("--azimuths", type=int, default=4, help="tilt directions (0-12)")
    parser.add_argument(
        "--force-range",
        type=float,
        nargs=2,
        default=None,
        metavar=("LOW", "HIGH"),
        help=f"safe force range [N], at most 0.5 (default {force_range})",
    )
    parser.add_argument(
        "--levels",
        type=int,
        default=None,
        help=f"force magnitudes in the range (default {levels})",
    )
    parser.add_argument("--level", type=float, default=0.01, help="significance level")


def given(value, default):
    """The option's value, or the mode's default when it was not given."""
    return default if value is None else value
