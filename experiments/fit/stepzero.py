"""Step 0 in the commands beyond ``dvs fit`` and ``dvs diagnose``: ``dvs image`` and
``dvs design`` (the same defaults everywhere, docs/stepzero.md).

With no model option each command runs step 0 (``experiments.basemodel.choose_base``)
on the dataset as fit and diagnose do, prints its choice in the same one line and
records it as ``base_choice`` (docs/stepzero.md). ``--grid``, ``--degrees``
and ``--margin`` set the volume of a chosen ``--energy`` and are refused without one
(``refuse_model_options``), the rule of fit and diagnose. The four options are declared
alike in every such command (``add_model_arguments``) and read alike
(``model_options``).
"""

from __future__ import annotations

import numpy as np

AUTO = "auto"
"""``--energy auto``: step 0 chooses the base model."""


def add_model_arguments(
    parser, energies, energy_help: str, grid: str, degrees: str, margin: str | None = None
) -> None:
    """``--energy`` (default ``auto``), ``--grid``, ``--degrees`` and ``--margin``: the
    base model and the volume of a chosen energy.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    energies : tuple of str
        ``--energy``'s choices, ``auto`` first.
    energy_help : str
        What ``--energy`` chooses, in the command's words.
    grid, degrees : str
        What ``--grid auto`` and no ``--degrees`` mean, e.g. "up to 9x9x2, as the markers
        allow" and "3x3x1".
    margin : str or None
        None: ``--margin`` [mm] defaults to 0 (``add_margin_argument``); else it defaults to
        None (not given; ``model_options`` then takes the mode's default) and ``margin``
        says that default, e.g. "10".
    """
    from experiments.command.options import add_margin_argument

    parser.add_argument("--energy", choices=energies, default=AUTO, help=energy_help)
    parser.add_argument(
        "--grid", default=AUTO, help=f"control grid MxNxL (with a chosen --energy); auto: {grid}"
    )
    parser.add_argument(
        "--degrees",
        default=None,
        help="spline degrees PxQxR along u, v and through the thickness (with a chosen "
        f"--energy; default {degrees})",
    )
    if margin is None:
        add_margin_argument(parser)
        return
    parser.add_argument(
        "--margin",
        type=float,
        default=None,
        help="width [mm] of tissue beyond the markers the volume also covers (with a chosen "
        f"--energy; default {margin}; docs/continuum.md)",
    )


def model_options(args, defaults: dict) -> dict:
    """``--grid``, ``--degrees`` and ``--margin`` checked (exit 2 with one line when bad),
    each the mode's default when not given (``--grid auto``, no ``--degrees``,
    ``--margin`` None): {"grid", "degrees", "margin"}."""
    from experiments.command.options import check_grid, check_margin, parse_degrees, parse_grid

    degrees = defaults["degrees"] if args.degrees is None else parse_degrees(args.degrees)
    grid = defaults["grid"]
    if args.grid != AUTO:
        grid = check_grid(parse_grid(args.grid), degrees, args.grid)
    margin = check_margin(defaults["margin"] if args.margin is None else args.margin)
    return {"grid": grid, "degrees": degrees, "margin": margin}


def refuse_model_options(grid, degrees, margin: float, energies: str = "--energy") -> None:
    """Exit 2 (``UsageError``) when ``--grid``, ``--degrees`` or ``--margin`` was given
    with ``--energy auto``: they set the volume of a chosen energy.

    Parameters
    ----------
    grid, degrees : object or None
        The options' values; None when not given.
    margin : float
        ``--margin`` [mm], checked; 0 counts as not given.
    energies : str
        How to name the ``--energy`` to give (e.g. "--energy linear-elastic").
    """
    from experiments.command.options import UsageError, verb

    chosen = [f"--{n}" for n, v in (("grid", grid), ("degrees", degrees)) if v is not None]
    chosen += ["--margin"] if margin > 0 else []
    if chosen:
        raise UsageError(
            f"{', '.join(chosen)} {verb(chosen)} the volume of a chosen --energy; with "
            f"--energy auto (the default) step 0 chooses the volume, or give {energies} too"
        )


def run_step0(dataset, level: float = 0.01, log=print):
    """Step 0 on ``dataset``: its progress as ``  step 0: ...`` lines and its choice in
    the one line of fit and diagnose (``  base model: ...``); the ``BaseChoice``."""
    from experiments.basemodel import choose_base

    choice = choose_base(dataset, lambda line: log(f"  step 0: {line}"), level)
    log(f"  {choice.line()}")
    return choice


def chosen_base(dataset, level: float = 0.01, log=print):
    """Step 0 on ``dataset`` (``run_step0``): the chosen model's ``FitSettings``, its fit,
    the dataset with the probe radius and shape step 0 estimated, and the ``base_choice``
    record. Step 0's other trials (their built volumes) are released before the
    command's own work."""
    import gc

    choice = run_step0(dataset, level, log)
    found = (choice.settings, choice.chosen.fit, choice.dataset(dataset), choice.record())
    del choice
    gc.collect()  # trials and their families refer to each other
    return found


def model_record(model, margin_mm: float, dataset) -> dict:
    """The volume a command used: {``energy``, ``grid``, ``degrees``, ``margin_mm``,
    ``support``, ``probe_radius_mm`` (the loads' radius, 0 for point forces)}."""
    radius = dataset.probe_radius
    radius = 0.0 if radius is None else float(np.median(np.asarray(radius, dtype=float)))
    return {
        "energy": model.energy,
        "grid": list(model.volume.shape),
        "degrees": list(model.volume.basis.degrees),
        "margin_mm": float(margin_mm),
        "support": "clamped" if model.boundary.fix_lateral else "free",
        "probe_radius_mm": radius,
    }
