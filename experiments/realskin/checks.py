"""Checks of the keloid result: is the stiff region at the moving pad an artefact?

The keloid loop (``experiments.realskin``) puts its stiff region around the moving pad,
not on the keloid outline, while the measured strain is concentrated at the fixed pad
(``experiments.realskin.strain``). Three variations of the data or of the scan test
whether that concentration, which the 5.6 mm knot spans cannot resolve, is what pulls
the region away:

- ``edges``: the DIC points within ``margin`` mm of either pad are dropped;
- ``slip``: the DIC points within 1 mm of the fixed pad are dropped, and the fixed pad
  is given, per frame, the x displacement the DIC measures next to it (median of the
  points 1 to 1.8 mm from its edge): a fixed pad that slips;
- ``two-sided``: after the k0 fit, the scan may also choose a *softer* rectangle (a
  compliant zone at the fixed pad would show as one).

Each check runs the unchanged loop (or, for ``two-sided``, the linear and k0 fits and
one scan) and reports the region and its overlap with the outline.

Run ``python -m experiments.realskin.checks [--check edges,slip,two-sided]`` (about
1 min per check).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from experiments.command.options import Command
from experiments.data.paths import shared_data_dir
from experiments.realskin.cases import force_weight, load_cases
from experiments.realskin.scan import overlap, scan
from experiments.realskin.setup import RealSkinSettings, Setup, build
from experiments.realskin.skinloop import close_the_loop
from experiments.realskin.twin import _quiet

CHECKS = ("edges", "slip", "two-sided")
EDGE_MARGIN_MM = 3.0
"""``edges``: DIC points closer than this to a pad [mm] are dropped (half a knot span)."""


def with_points(setup: Setup, keep: np.ndarray) -> Setup:
    """The set-up with only the DIC points ``keep`` (bool mask), force weight and load
    cases rebuilt as the study builds them."""
    data = setup.data
    data = dataclasses.replace(
        data,
        displacement_mm=[None if d is None else d[keep] for d in data.displacement_mm],
        reference_mm=data.reference_mm[keep],
    )
    weight = force_weight(data)
    cases = load_cases(setup.model, setup.pads, data, weight)
    return dataclasses.replace(setup, data=data, weight=weight, cases=cases)


def near_pads(setup: Setup, margin_mm: float) -> np.ndarray:
    """Mask of the DIC points within ``margin_mm`` [mm] (in x) of either pad's inner edge."""
    x = setup.data.reference_mm[:, 0]
    moving, fixed = setup.pad_rects
    return (x < moving.x1 + margin_mm) | (x > fixed.x0 - margin_mm)


def fixed_pad_slip(setup: Setup) -> tuple[Setup, np.ndarray]:
    """The ``slip`` variant: returns the set-up and the fixed pad's x displacement per
    load case [mm] (the median DIC u_x 1 to 1.8 mm from its edge)."""
    x = setup.data.reference_mm[:, 0]
    edge = setup.pad_rects[1].x0
    beside = (x > edge - 1.8) & (x < edge - 1.0)
    slip = np.array(
        [0.0 if d is None else float(np.median(d[beside, 0])) for d in setup.data.displacement_mm]
    )
    out = with_points(setup, x < edge - 1.0)
    for case, value in zip(out.cases, slip):
        case.prescribed[setup.pads.n_moving :, 0] = value
    return out, slip


def _region(setup: Setup, rect, ratio) -> dict:
    geometry = setup.case.geometry
    return {
        "rect_mm": [round(float(v), 2) for v in (rect.x0, rect.x1, rect.y0, rect.y1)],
        "ratio": ratio,
        "overlap": overlap(rect, geometry.keloid, geometry.region),
    }


def run_check(
    name: str,
    settings: RealSkinSettings,
    real: Setup,
    log=_quiet,
    margin_mm: float = EDGE_MARGIN_MM,
) -> dict:
    """One check on the keloid case (``real``: ``build("keloid", settings)``).

    Returns
    -------
    dict
        ``check``; ``rms``: (displacement [mm], force [N]) per fitted stage; ``region``:
        the scan's rectangle [x0, x1, y0, y1] mm, its fitted ratio and its overlap with
        the outline; ``chosen`` (effects per round), ``points`` (DIC points kept) and
        ``slip_mm`` (fixed-pad x displacement per case) where they apply; for
        ``two-sided`` the scan's ``direction`` and ``statistic``.
    """
    if name not in CHECKS:
        raise ValueError(f"check must be one of {', '.join(CHECKS)}, got {name!r}")
    out: dict = {"check": name}
    if name == "two-sided":
        loop = close_the_loop(real, dataclasses.replace(settings, candidates=("k0",)), log)
        fit = loop["stages"][-1]
        result = scan(
            real.model, real.cases, fit.names, fit.x, settings.bounds, real.grid, stiffer=False
        )
        out["direction"] = "stiffer" if result.score.direction > 0 else "softer"
        out["statistic"] = result.score.statistic
        out["region"] = _region(real, result.rect, None)
        out["rms"] = [(s.rms_displacement_mm, s.rms_force_n) for s in loop["stages"]]
        return out
    if name == "edges":
        setup = with_points(real, ~near_pads(real, margin_mm))
    else:
        setup, slip = fixed_pad_slip(real)
        out["slip_mm"] = slip.tolist()
    out["points"] = len(setup.data.reference_mm)
    model = setup.model
    loop = close_the_loop(setup, settings, log)
    setup.model = model
    stages = loop["stages"]
    out["rms"] = [(s.rms_displacement_mm, s.rms_force_n) for s in stages]
    out["chosen"] = [r["chosen"] for r in loop["rounds"]]
    if loop["found"] is not None:
        ratio = stages[-1].as_dict().get("region_ratio")
        out["region"] = _region(setup, loop["found"].rect, ratio)
    return out


def line(result: dict) -> str:
    """One line per check."""
    (d0, f0), (d1, f1) = result["rms"][0], result["rms"][-1]
    text = f"{result['check']}: RMS {d0:.4f} mm / {f0:.4f} N -> {d1:.4f} mm / {f1:.4f} N"
    if "region" in result:
        region, o = result["region"], result["region"]["overlap"]
        x0, x1, y0, y1 = region["rect_mm"]
        kind = ""
        if "direction" in result:
            kind = f" ({result['direction']}, T {result['statistic']:.3g})"
        text += (
            f"; region x {x0:.1f}-{x1:.1f}, y {y0:.2f}-{y1:.2f} mm{kind}, inside "
            f"{o['inside_fraction']:.2f} (chance {o['chance']:.2f}), IoU {o['iou']:.2f}, "
            f"centroid {'inside' if o['centroid_inside'] else 'outside'}"
        )
    return text


def build_parser(prog: str = "python -m experiments.realskin.checks"):
    """The options of ``dvs realskin checks``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--check", default=",".join(CHECKS), help="comma list")
    parser.add_argument("--verbose", action="store_true", help="print the loop's log")
    parser.add_argument(
        "--out", type=path_argument, default=None, help="also write DIR/checks.json"
    )
    return parser


def work(args) -> int:
    """``dvs realskin checks [--check a,b]``; one line and exit 2 on bad input."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.output.atomic import atomic_write_json

    names = [c.strip() for c in args.check.split(",") if c.strip()]
    unknown = [c for c in names if c not in CHECKS]
    if not names or unknown:
        raise UsageError(f"--check takes a comma list of {', '.join(CHECKS)}")
    if args.out is not None:
        check_output_dir(args.out)
    if not (shared_data_dir() / "skin-extensometer" / "keloid").is_dir():
        raise UsageError("keloid data not found (set DVS_SHARED_DATA)")
    settings = RealSkinSettings()
    real = build("keloid", settings)
    results = {}
    for name in names:
        results[name] = run_check(name, settings, real, print if args.verbose else _quiet)
        print(line(results[name]), flush=True)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out / "checks.json", results)
    return 0


main = Command("experiments.realskin.checks", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
