"""Real in vivo skin in a two-pad extensometer: fit the volume spline model, close the loop.

For each case of ``skin-extensometer`` (healthy skin, a keloid scar):

1. fit the linear model (isotropic tension alpha, foundation alpha_w) to the DIC markers
   (x, y) and the moving pad's force of several frames jointly;
2. show what is left: the residual displacement field and the force curve;
3. find what the model lacks with score tests of the candidate extensions at the fit:
   stiffening k0 (eq. 1) and, where the geometry has a keloid outline, a second
   material inside it (stiffness ratio 1 + theta); add the best candidate while it is
   significant and worth it, and refit;
4. report the errors before and after, the estimates with standard errors, and a
   comparison with the original authors' 2D neo-Hookean fit.

Run ``python -m experiments.realskin --out DIR``; see ``docs/realskin.md``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, astuple, dataclass, field
from pathlib import Path

import numpy as np

from experiments.atomic import atomic_write_json, atomic_write_text
from experiments.cli import OneLineParser
from experiments.realskin_cases import FrameData, force_weight, frame_data, load_cases
from experiments.realskin_figures import case_figures, stage_summary
from experiments.realskin_model import (
    ANISOTROPY,
    POISSON,
    REGION_RATIO,
    Pads,
    SkinParameterSpace,
    SkinSlabModel,
    region_indicator,
    slab_volume,
)
from experiments.realskin_report import report
from experiments.realskin_scan import (
    SCAN,
    CellGrid,
    CellTerms,
    ScanResult,
    overlap,
    rect_indicator,
    scan,
    with_region,
)
from experiments.realskin_stages import LABELS, NULL, ONE_SIDED, StageFit, fit_stage, score_test
from experiments.realskin_strain import figure as strain_figure
from experiments.skindata import Rect, SkinCase, dic_noise_mm, load_case
from solvers.equilibrium import EquilibriumError
from symbolic.model import BoundaryConditions
from symbolic.stiffening import exponential_stiffening, quadratic_stiffening

STIFFENING = {"exponential": exponential_stiffening, "quadratic": quadratic_stiffening}
AUTHORS = {
    "healthy": {"E": (0.027, 0.031), "nu": (0.14, 0.22)},
    "keloid": {"E": (0.07, 0.14), "nu": (0.35, 0.42)},
}
"""The original authors' 2D neo-Hookean fits (README of the data; units probably N/mm)."""


@dataclass(frozen=True)
class RealSkinSettings:
    """Choices of the study (see ``docs/realskin.md`` for the reasons).

    Attributes
    ----------
    thickness_mm : float
        Skin slab thickness [mm].
    grid : tuple of int
        In-plane control points (M, N) over the 100 x 50 mm region; L = 2, bicubic.
    boundary : {"inner", "lateral"}
        "inner": the inner layer is fixed (skin on a subcutaneous layer attached to the
        fascia, alpha_w estimated); "lateral": the region's edge ring is fixed and the
        inner layer free (a membrane, alpha_w fixed large so the layers move together).
    stiffening : {"exponential", "quadratic"}
        s(eps) of eq. (1): exp(k0 eps^2) (Fung-like) or 1 + k0 eps^2.
    pad_points : int
        Prescribed points per pad side (pad_points^2 per pad).
    dic_frames : int
        Frames with DIC and force, spread over the loading.
    force_only : int
        Extra force-only frames beyond the DIC (healthy skin: 3.8 to 8.4 mm of travel).
    smoothing_mm : float
        Width of the keloid indicator's transition [mm] (``outline_region`` only).
    outline_region : bool
        Put the second material inside the keloid outline of ``geometry.geo`` (the old,
        predefined region; off: the region is found by the scan, ``realskin_scan``).
    significance : float
        An effect is added only if its score test has p below this...
    min_gain : float
        ...and its predicted cost decrease is at least this fraction of the cost.
    max_effects : int
        At most this many effects are added.
    candidates : tuple of str
        The effects the loop may add.
    starts : dict
        Start values tried when a parameter is added, e.g. {"k0": (0, 1, 3, 10)}
        (``--k0-starts``; the lowest cost wins, a start without equilibrium is skipped).
        Default: none, every parameter starts at its null value. The stiffening fits
        have local minima (docs/realskin.md, "Sensitivity"); several starts cost one
        fit each.
    diagnostics : tuple of str
        Extensions scored at the final fit but never added.
    bounds : dict
        Bounds of every parameter (natural units).
    """

    thickness_mm: float = 2.0
    grid: tuple[int, int] = (21, 11)
    boundary: str = "inner"
    stiffening: str = "exponential"
    pad_points: int = 4
    dic_frames: int = 6
    force_only: int = 4
    smoothing_mm: float = 1.0
    outline_region: bool = False
    significance: float = 1e-3
    min_gain: float = 0.05
    max_effects: int = 4
    candidates: tuple[str, ...] = ("k0", POISSON, ANISOTROPY, SCAN)
    starts: dict = field(default_factory=dict)
    diagnostics: tuple[str, ...] = ()
    bounds: dict = field(
        default_factory=lambda: {
            "alpha_u": (1e-5, 1e3),
            "alpha_w": (1e-6, 1e3),
            "k0": (0.0, 100.0),
            REGION_RATIO: (0.1, 100.0),
            ANISOTROPY: (1e-3, 1e3),
            POISSON: (0.0, 20.0),
        }
    )


# ------------------------------------------------------------------------------- set-up
def pad_rects(case: SkinCase) -> tuple[Rect, Rect]:
    """8 x 8 mm pads whose inner-edge midpoints are the pad files' reference points.

    For the keloid this is exactly the ``geometry.geo`` pads; for healthy skin it gives
    the 36.5 mm gap of the pad files instead of the .geo's 32 mm (docs/realskin.md).
    """
    geometry, offset = case.geometry, case.dic_to_model_mm
    size, half = geometry.pad_moving.width, 0.5 * geometry.pad_moving.height
    moving = case.pad_moving_mm[0] + offset
    fixed = case.pad_fixed_mm[0] + offset
    return (
        Rect(moving[0] - size, moving[1] - half, moving[0], moving[1] + half),
        Rect(fixed[0], fixed[1] - half, fixed[0] + size, fixed[1] + half),
    )


@dataclass
class Setup:
    """Everything one case's fits share."""

    case: SkinCase
    model: SkinSlabModel
    pads: Pads
    pad_rects: tuple[Rect, Rect]
    data: FrameData
    cases: list
    weight: float
    noise_mm: float
    base_names: tuple[str, ...]
    start: dict
    grid: CellGrid | None = None
    cells: CellTerms | None = None


def build(name: str, settings: RealSkinSettings, pads: tuple[Rect, Rect] | None = None) -> Setup:
    """The slab model, pads, frames and load cases of one case."""
    case = load_case(name)
    geometry = case.geometry
    rects = pad_rects(case) if pads is None else pads
    inner = settings.boundary == "inner"
    if settings.boundary not in ("inner", "lateral"):
        raise ValueError(f"boundary must be 'inner' or 'lateral', got {settings.boundary!r}")
    region = None
    if settings.outline_region and geometry.keloid is not None:
        region = region_indicator(geometry.region, geometry.keloid, settings.smoothing_mm)
    # start: T = 0.02 N/mm; inner: foundation decay length 10 mm; lateral: layers coupled
    tension = 0.02
    area = geometry.region.width * geometry.region.height
    alpha_u = tension * geometry.region.height / geometry.region.width
    alpha_w = tension / 100.0 * area if inner else tension * area / settings.thickness_mm**2
    pad_set = Pads.build(geometry.region, *rects, settings.pad_points)
    model = SkinSlabModel(
        slab_volume(geometry.region, settings.thickness_mm, settings.grid),
        {"alpha_u": alpha_u, "alpha_w": alpha_w},
        BoundaryConditions(fix_inner=inner, fix_lateral=not inner),
        stiffening=STIFFENING[settings.stiffening],
        prescribed=pad_set.prescribed,
        isotropic=True,
        region=region,
    )
    data = frame_data(case, settings.dic_frames, settings.force_only)
    weight = force_weight(data)
    names = ("alpha_u", "alpha_w") if inner else ("alpha_u",)
    start = {"alpha_u": alpha_u, "alpha_w": alpha_w}
    cases = load_cases(model, pad_set, data, weight)
    grid = CellGrid.of(model, geometry.region)
    return Setup(
        case, model, pad_set, rects, data, cases, weight, dic_noise_mm(case), names, start, grid
    )


# ---------------------------------------------------------------------------- the loop
def _space(names, start, settings: RealSkinSettings) -> SkinParameterSpace:
    return SkinParameterSpace.build(names, start, settings.bounds)


def _score_all(setup: Setup, fit: StageFit, names, settings) -> dict:
    """Score test of every candidate at the fit; the scan's entry is a ``ScanResult``."""
    out = {}
    for name in names:
        if name == SCAN:
            if setup.cells is None:
                setup.cells = CellTerms.build(setup.model, setup.grid)
            out[name] = scan(
                setup.model,
                setup.cases,
                fit.names,
                fit.x,
                settings.bounds,
                setup.grid,
                setup.cells,
            )
        else:
            out[name] = score_test(
                setup.model,
                setup.cases,
                fit.names,
                fit.x,
                name,
                NULL[name],
                settings.bounds,
                ONE_SIDED[name],
            )
    return out


def fit_from_starts(
    setup: Setup, names: tuple, start: dict, settings: RealSkinSettings, label: str, log
) -> StageFit:
    """Fit ``names`` from ``start``; a parameter at its null value with several start
    values (``settings.starts``) is fitted from each in turn, the other parameters
    starting from the best fit so far (a continuation: with k0 larger, the tensions
    must be smaller). The lowest cost wins; a start without equilibrium is skipped."""
    name = next(
        (n for n in names if start.get(n) == NULL.get(n) and len(settings.starts.get(n, ())) > 1),
        None,
    )
    if name is None:
        return fit_stage(setup.model, setup.cases, _space(names, start, settings), label, log)
    best = None
    for value in settings.starts[name]:
        trial = {**(start if best is None else best.as_dict()), name: value}
        log(f"  start {name} = {value:g}")
        try:
            fit = fit_stage(setup.model, setup.cases, _space(names, trial, settings), label, log)
        except EquilibriumError as error:
            log(f"  {label}: start skipped ({error})")
            continue
        if best is None or fit.cost < best.cost:
            best = fit
    if best is None:
        raise EquilibriumError(f"{label}: no start reached an equilibrium")
    return best


def _score(entry):
    return entry.score if isinstance(entry, ScanResult) else entry


def close_the_loop(setup: Setup, settings: RealSkinSettings, log=print) -> dict:
    """Linear fit, then score tests and refits while a candidate is worth adding.

    Returns
    -------
    dict
        ``stages`` (list of StageFit, the linear fit first), ``rounds`` (per round the
        scores of every remaining candidate and the chosen one) and ``diagnostics``
        (scores of extensions that are not candidates, at the final fit).
    """
    stage = fit_stage(
        setup.model, setup.cases, _space(setup.base_names, setup.start, settings), "linear", log
    )
    stages, rounds = [stage], []
    available = [
        c for c in settings.candidates if c != REGION_RATIO or setup.model.region is not None
    ]
    found = None
    while available and len(stages) <= settings.max_effects:
        entries = _score_all(setup, stage, available, settings)
        scores = {k: _score(v) for k, v in entries.items()}
        best = max(scores.values(), key=lambda s: s.statistic)
        worth = best.p_value < settings.significance and (
            best.predicted_decrease >= settings.min_gain * stage.cost
        )
        rounds.append({"scores": scores, "chosen": best.name if worth else None})
        if SCAN in entries:
            rounds[-1]["scan"] = entries[SCAN]
        log(
            "  scores: "
            + ", ".join(
                f"{s.name} T={s.statistic:.3g} (p={s.p_value:.2g}, "
                f"predicted -{s.predicted_decrease:.3g})"
                for s in scores.values()
            )
            + f" -> {best.name if worth else 'stop'}"
        )
        if not worth:
            break
        parameter = REGION_RATIO if best.name == SCAN else best.name
        if best.name == SCAN:
            found = entries[SCAN]
            setup.model = with_region(setup.model, rect_indicator(setup.grid.region, found.rect))
            log(f"  found region: {found.rect} (direction {found.score.direction:+.0f})")
        names = stage.names + (parameter,)
        start = {**stage.as_dict(), parameter: NULL[parameter]}
        stage = fit_from_starts(setup, names, start, settings, f"+ {LABELS[best.name]}", log)
        stages.append(stage)
        available.remove(best.name)
    diagnostics = {
        k: _score(v) for k, v in _score_all(setup, stage, settings.diagnostics, settings).items()
    }
    return {"stages": stages, "rounds": rounds, "diagnostics": diagnostics, "found": found}


def likelihood_ratio(before: StageFit, after: StageFit) -> float:
    """2 (cost_before - cost_after) / sigma_after^2: chi^2 with the added parameters."""
    return 2.0 * (before.cost - after.cost) / after.sigma**2


# ------------------------------------------------------------------------ per-case run
def run_case(name: str, settings: RealSkinSettings, out: Path, log=print) -> dict:
    """Close the loop on one case and write its figures; returns its summary."""
    begin = time.perf_counter()
    setup = build(name, settings)
    with_dic = sum(d is not None for d in setup.data.displacement_mm)
    log(
        f"{name}: {len(setup.cases)} frames ({with_dic} with DIC), "
        f"{len(setup.data.reference_mm)} DIC points, force weight "
        f"{setup.weight:.1f} mm/N, DIC noise {setup.noise_mm:.4f} mm"
    )
    base_model = setup.model
    loop = close_the_loop(setup, settings, log)
    stages = loop["stages"]
    found = loop["found"]
    summary = {
        "dic_noise_mm": setup.noise_mm,
        "force_weight_mm_per_N": setup.weight,
        "frames": setup.data.labels,
        "pads_mm": [asdict(r) for r in setup.pad_rects],
        "stages": [stage_summary(setup, s) for s in stages],
        "rounds": [
            {
                "chosen": r["chosen"],
                "scores": {k: asdict(v) for k, v in r["scores"].items()},
                "scan_rect_mm": asdict(r["scan"].rect) if "scan" in r else None,
                "scan_candidates": r["scan"].n_candidates if "scan" in r else None,
            }
            for r in loop["rounds"]
        ],
        "diagnostics": {k: asdict(v) for k, v in loop["diagnostics"].items()},
        "likelihood_ratio": [likelihood_ratio(a, b) for a, b in zip(stages, stages[1:])],
        "authors": AUTHORS[name],
    }
    summary["heterogeneity"] = _heterogeneity(setup, found, stages)
    summary["variants"] = _variants(name, settings, stages, found, log)
    paths = case_figures(out, name, setup, stages, found)
    strain_path = out / f"strain_{name}.png"
    frames = [f for f in setup.data.frames if f is not None]
    strain_figure(setup.case, frames, strain_path, pads=setup.pad_rects)
    summary["figures"] = [p.name for p in [*paths, strain_path]]
    setup.model = base_model
    summary["seconds"] = time.perf_counter() - begin
    first, last = stages[0], stages[-1]
    log(
        f"{name}: RMS displacement {first.rms_displacement_mm:.4f} -> "
        f"{last.rms_displacement_mm:.4f} mm (DIC noise {setup.noise_mm:.4f} mm), RMS force "
        f"{first.rms_force_n:.4f} -> {last.rms_force_n:.4f} N ({summary['seconds']:.0f} s)"
    )
    return summary


def _heterogeneity(setup: Setup, found: ScanResult | None, stages: list[StageFit]) -> dict | None:
    """The scanned region, its fitted ratio and, where there is one, its overlap with
    the keloid outline of ``geometry.geo`` (which the scan never saw)."""
    if found is None:
        return None
    ratio = stages[-1].as_dict().get(REGION_RATIO)
    out = {
        "rect_mm": asdict(found.rect),
        "cells": list(found.box),
        "candidates": found.n_candidates,
        "score": asdict(found.score),
        "ratio": ratio,
        "cell_statistic": found.cell_statistic.tolist(),
    }
    keloid = setup.case.geometry.keloid
    if keloid is not None:
        out["overlap"] = overlap(found.rect, keloid, setup.case.geometry.region)
    return out


def _variants(name: str, settings: RealSkinSettings, stages: list[StageFit], found, log) -> dict:
    """The other boundary condition (linear and final effect set, the found region kept)
    and, where they differ from the pad files' (healthy skin: 32 mm gap), the .geo pads'
    linear fit."""
    out = {}
    other = "lateral" if settings.boundary == "inner" else "inner"
    variant = RealSkinSettings(**{**asdict(settings), "boundary": other})
    setup = build(name, variant)
    if found is not None:
        setup.model = with_region(setup.model, rect_indicator(setup.grid.region, found.rect))
    added = [n for n in stages[-1].names if n in NULL]
    linear = fit_stage(
        setup.model,
        setup.cases,
        _space(setup.base_names, setup.start, variant),
        f"{other} boundary, linear",
        log,
    )
    out[f"{other}_linear"] = stage_summary(setup, linear)
    if added:
        start = {**linear.as_dict(), **{n: NULL[n] for n in added}}
        final = fit_from_starts(
            setup,
            linear.names + tuple(added),
            start,
            variant,
            f"{other} boundary, + " + ", ".join(LABELS[n] for n in added),
            log,
        )
        out[f"{other}_final"] = stage_summary(setup, final)
    geometry = setup.case.geometry
    shift = np.abs(np.array(astuple(geometry.pad_moving)) - astuple(setup.pad_rects[0]))
    if shift.max() > 0.1:  # the .geo pads differ from the pad files (healthy skin)
        setup = build(name, settings, (geometry.pad_moving, geometry.pad_fixed))
        linear = fit_stage(
            setup.model,
            setup.cases,
            _space(setup.base_names, setup.start, settings),
            f"geometry.geo pads ({geometry.pad_gap_mm:.0f} mm gap), linear",
            log,
        )
        out["geo_pads_linear"] = stage_summary(setup, linear)
    return out


# ---------------------------------------------------------------------------- the study
def run(
    out: Path, settings: RealSkinSettings | None = None, cases=("healthy", "keloid"), log=print
) -> dict:
    """Both cases: fits, scores, figures, ``summary.json`` and ``parameters.md`` in ``out``.

    Returns
    -------
    dict
        Per case the summary written to ``summary.json`` (errors before and after,
        estimates with standard errors, scores, variants), plus the settings and runtime.
    """
    settings = settings or RealSkinSettings()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    begin = time.perf_counter()
    summary = {"settings": asdict(settings)}
    for name in cases:
        summary[name] = run_case(name, settings, out, log)
    summary["seconds"] = time.perf_counter() - begin
    atomic_write_json(out / "summary.json", summary)
    atomic_write_text(out / "parameters.md", report(summary))
    log(
        f"wrote {out / 'summary.json'}, {out / 'parameters.md'} and the figures "
        f"({summary['seconds']:.0f} s)"
    )
    return summary


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m experiments.realskin --out DIR [--boundary lateral]``."""
    parser = OneLineParser(prog="realskin", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("realskin-output"))
    parser.add_argument("--boundary", choices=("inner", "lateral"), default="inner")
    parser.add_argument("--stiffening", choices=tuple(STIFFENING), default="exponential")
    parser.add_argument("--grid", type=int, nargs=2, default=(21, 11), metavar=("M", "N"))
    parser.add_argument("--case", choices=("healthy", "keloid"), action="append")
    parser.add_argument(
        "--k0-starts", default="", metavar="LIST", help="start values of k0, e.g. 0,1,3,10"
    )
    args = parser.parse_args(argv)
    low, high = RealSkinSettings().bounds["k0"]
    try:
        k0_starts = tuple(float(v) for v in args.k0_starts.split(",") if v.strip())
        if not all(low <= v <= high for v in k0_starts):
            raise ValueError
    except ValueError:
        parser.error(
            f"--k0-starts takes a comma list of numbers in [{low:g}, {high:g}], "
            f"got {args.k0_starts!r}"
        )
    settings = RealSkinSettings(
        boundary=args.boundary,
        stiffening=args.stiffening,
        grid=tuple(args.grid),
        starts={"k0": k0_starts} if k0_starts else {},
    )
    run(args.out, settings, tuple(args.case or ("healthy", "keloid")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
