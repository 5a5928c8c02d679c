"""A synthetic twin of the keloid extensometer: can the design localise a stiff keloid?

The twin keeps what the pipeline sees of the real keloid case (slab model, pads and pad
motions, the 6 fitted frames, the kept DIC points, one force per frame) and replaces
the measurements by the model's prediction with a stiffer second material occupying
exactly the keloid outline of ``geometry.geo`` (``region_indicator``), plus Gaussian
noise. It then goes through ``realskin.close_the_loop`` unchanged (linear fit, score
tests, rectangle scan; the scan never sees the outline).

Truth: the isotropic model without Poisson coupling, linear (``k0=0``, default) or
with the exponential stiffening of eq. (1) at a given k0 (``--k0``, e.g. the real fit's
3.3); ratio inside / outside as given; alpha_u, alpha_w the linear fit of the *real*
keloid data by the twin's own model (outline region, ratio and k0 fixed), so that
forces and displacements have the real magnitudes (``base="calibrated"``;
``"homogeneous"`` puts the homogeneous fit outside, and the forces grow with the ratio).
Noise: DIC sigma ``dic_noise_mm(case)`` on x and y of every point and frame, force
sigma ``FORCE_NOISE_N`` per frame.

Run ``python -m experiments.realskin.twin [--ratios 3.5,23] [--seeds 0,1,2]``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from experiments.command.options import Command
from experiments.data.paths import shared_data_dir
from experiments.realskin.cases import force_weight, load_cases
from experiments.realskin.geometry import points_in_polygon
from experiments.realskin.scan import SCAN, CellGrid, overlap
from experiments.realskin.setup import RealSkinSettings, Setup, build
from experiments.realskin.skinloop import close_the_loop
from experiments.realskin.slab import region_indicator
from experiments.realskin.stages import fit_stage, score_test, stage_solver
from solvers.forward.equilibrium import EquilibriumSolver
from solvers.inverse.problem import PlanarProblem
from solvers.inverse.space import SkinParameterSpace
from symbolic.skin_slab import REGION_RATIO, SkinSlabModel

FORCE_NOISE_N = 0.02
"""Force noise [N] per frame: the real keloid's RMS force residual after the loop."""
TRUTH_NAMES = ("alpha_u", "alpha_w", REGION_RATIO)


def _quiet(*_args) -> None:
    return None


def truth_model(
    setup: Setup, ratio: float, settings: RealSkinSettings, k0: float = 0.0
) -> SkinSlabModel:
    """The slab model with a second material of stiffness ratio ``ratio`` [1] inside the
    keloid outline (smoothed over ``settings.smoothing_mm``) and stiffening ``k0`` [1]."""
    geometry = setup.case.geometry
    chi = region_indicator(geometry.region, geometry.keloid, settings.smoothing_mm)
    parameters = {**setup.model.parameters, "k0": float(k0)}
    return dataclasses.replace(
        setup.model, parameters=parameters, region=chi, region_ratio=float(ratio), _fast={}
    )


def base_parameters(
    setup: Setup, truth: SkinSlabModel, settings: RealSkinSettings, base: str = "calibrated"
) -> dict:
    """alpha_u, alpha_w [N/mm] of the truth: a linear fit of the real keloid data, by the
    truth model with its ratio fixed ("calibrated") or by the homogeneous model."""
    if base not in ("calibrated", "homogeneous"):
        raise ValueError(f"base must be 'calibrated' or 'homogeneous', got {base!r}")
    model = truth if base == "calibrated" else setup.model
    space = SkinParameterSpace.build(setup.base_names, setup.start, settings.bounds)
    return fit_stage(model, setup.cases, space, f"{base} base", _quiet).as_dict()


def make_twin(
    real: Setup,
    truth: SkinSlabModel,
    truth_x,
    seed: int,
    dic_noise_mm: float,
    force_noise_n: float = FORCE_NOISE_N,
) -> tuple[Setup, Setup]:
    """Noisy and noise-free twins of ``real``: the same model, pads, frames and points,
    with the truth's predictions at ``truth_x`` (+ Gaussian noise of the given sigmas
    [mm], [N]) as data and the force weight recomputed from them, as the pipeline does."""
    solver = EquilibriumSolver(truth, TRUTH_NAMES)
    n = 3 * truth.n_free
    clean_u, clean_f = [], []
    for case in real.cases:
        state = solver.solve(case.force, np.asarray(truth_x, float), case.prescribed).state
        delta = state[:n].reshape(3, -1).T
        clean_u.append((case.rows @ delta)[:, :2] if case.rows.shape[0] else None)
        clean_f.append(float((case.force_rows @ state[n:])[0]))
    rng = np.random.default_rng(seed)
    noisy_u = [None if u is None else u + rng.normal(0.0, dic_noise_mm, u.shape) for u in clean_u]
    noisy_f = np.array(clean_f) + rng.normal(0.0, force_noise_n, len(clean_f))
    out = []
    for disp, force in ((noisy_u, noisy_f), (clean_u, np.array(clean_f))):
        data = dataclasses.replace(real.data, force_n=force, displacement_mm=disp)
        weight = force_weight(data)
        cases = load_cases(real.model, real.pads, data, weight)
        out.append(dataclasses.replace(real, data=data, cases=cases, weight=weight))
    return out[0], out[1]


def cost_at(model: SkinSlabModel, cases, names, x, settings: RealSkinSettings) -> float:
    """1/2 |r|^2 [mm^2] of a model at parameters x of ``names`` (no fit)."""
    space = SkinParameterSpace.build(names, dict(zip(names, x)), settings.bounds)
    r, _ = stage_solver(PlanarProblem(model, cases, space)).evaluate(space.to_internal(space.start))
    return 0.5 * float(r @ r)


def best_possible_iou(grid: CellGrid, polygon: np.ndarray, step: float = 0.25) -> tuple:
    """The scan's candidate rectangle with the largest IoU with the polygon: (Rect, IoU)."""
    region = grid.region
    x = np.arange(region.x0 + step / 2, region.x1, step)
    y = np.arange(region.y0 + step / 2, region.y1, step)
    xx, yy = (g.ravel() for g in np.meshgrid(x, y, indexing="ij"))
    inside = points_in_polygon(np.column_stack([xx, yy]), np.asarray(polygon, float))
    i = np.clip(np.searchsorted(grid.x_edges, xx, side="right") - 1, 0, grid.shape[0] - 1)
    j = np.clip(np.searchsorted(grid.y_edges, yy, side="right") - 1, 0, grid.shape[1] - 1)
    cell_in = np.bincount((i * grid.shape[1] + j)[inside], minlength=grid.n_cells) * step**2
    cell_area = np.outer(np.diff(grid.x_edges), np.diff(grid.y_edges)).ravel()
    boxes = grid.boxes()
    masks = np.array([grid.mask(b) for b in boxes])
    both, area = masks @ cell_in, masks @ cell_area
    iou = both / (area + cell_in.sum() - both)
    best = int(np.argmax(iou))
    return grid.rect(boxes[best]), float(iou[best])


def _rect(rect) -> list:
    return [round(float(v), 2) for v in (rect.x0, rect.x1, rect.y0, rect.y1)]


def run_twin(
    ratio: float,
    seed: int,
    settings: RealSkinSettings | None = None,
    force_noise_n: float = FORCE_NOISE_N,
    base: str = "calibrated",
    log=_quiet,
    real: Setup | None = None,
    k0: float = 0.0,
) -> dict:
    """Build one twin and put it through ``close_the_loop``.

    ``real``: the real keloid set-up (``build("keloid", settings)``), built here if not
    given; pass it to share one build between runs.

    Returns
    -------
    dict
        ``ratio``, ``seed``, ``truth`` (parameters), noise levels [mm, N], ``force_scale``
        (RMS twin force / RMS real force), ``first_scan`` (round 1: rectangle
        [x0, x1, y0, y1] mm, statistic, Bonferroni p-value, overlap with the outline),
        ``outline_score`` (the score test of the true outline at the linear fit),
        ``best_possible`` (the candidate rectangle closest to the outline and its IoU),
        ``chosen`` (effects added per round), ``found`` (the loop's region, if it added
        one: rectangle, round, fitted ratio, overlap), RMS errors and ``seconds``.
    """
    begin = time.perf_counter()
    settings = settings or RealSkinSettings()
    real = real if real is not None else build("keloid", settings)
    truth = truth_model(real, ratio, settings, k0)
    params = base_parameters(real, truth, settings, base)
    truth_x = np.array([params["alpha_u"], params["alpha_w"], float(ratio)])
    twin, _ = make_twin(real, truth, truth_x, seed, real.noise_mm, force_noise_n)
    loop = close_the_loop(twin, settings, log)
    stages, rounds = loop["stages"], loop["rounds"]
    linear = stages[0]
    keloid, region = real.case.geometry.keloid, real.case.geometry.region
    scan1 = rounds[0]["scan"]  # round 1 always scores the scan (a default candidate)
    outline = score_test(
        truth, twin.cases, linear.names, linear.x, REGION_RATIO, 1.0, settings.bounds, True
    )
    rect, iou = best_possible_iou(real.grid, keloid)
    rms = np.sqrt(np.mean(twin.data.force_n**2)) / np.sqrt(np.mean(real.data.force_n**2))
    out = {
        "ratio": float(ratio),
        "seed": int(seed),
        "base": base,
        "truth": {**dict(zip(TRUTH_NAMES, map(float, truth_x))), "k0": float(k0)},
        "dic_noise_mm": real.noise_mm,
        "force_noise_n": force_noise_n,
        "force_weight_mm_per_N": twin.weight,
        "force_scale": float(rms),
        "outline_score": dataclasses.asdict(outline),
        "best_possible": {"rect_mm": _rect(rect), "iou": iou},
        "chosen": [r["chosen"] for r in rounds],
        "rms_displacement_mm": [s.rms_displacement_mm for s in stages],
        "rms_force_n": [s.rms_force_n for s in stages],
        "first_scan": {
            "rect_mm": _rect(scan1.rect),
            "statistic": scan1.score.statistic,
            "p_value": scan1.score.p_value,
            "chosen": rounds[0]["chosen"] == SCAN,
            "overlap": overlap(scan1.rect, keloid, region),
        },
        "found": None,
    }
    if loop["found"] is not None:
        found = loop["found"]
        out["found"] = {
            "rect_mm": _rect(found.rect),
            "round": 1 + [r["chosen"] for r in rounds].index(SCAN),
            "p_value": found.score.p_value,
            "ratio": stages[-1].as_dict()[REGION_RATIO],
            "overlap": overlap(found.rect, keloid, region),
        }
    out["seconds"] = time.perf_counter() - begin
    return out


# ---------------------------------------------------------------------------- reporting
def _p(value: float) -> str:
    return "<1e-300" if value == 0.0 else f"{value:.2g}"


def _row(run: dict, label: str, entry: dict, t_ratio: str) -> str:
    o, (x0, x1, y0, y1) = entry["overlap"], entry["rect_mm"]
    cells = [
        f"{run['ratio']:g}",
        str(run["seed"]),
        label,
        f"x {x0:.1f}-{x1:.1f}, y {y0:.1f}-{y1:.1f}",
        _p(entry["p_value"]),
        *(f"{o[k]:.2f}" for k in ("inside_fraction", "chance", "iou", "recall")),
        "yes" if o["centroid_inside"] else "no",
        f"{entry['ratio']:.3g}" if "ratio" in entry else "-",
        t_ratio,
        f"{run['seconds']:.0f}",
    ]
    return "| " + " | ".join(cells) + " |"


def line(run: dict) -> str:
    """One line per run: the first scan's rectangle and overlap, the loop's region."""
    first, found = run["first_scan"], run["found"]
    o = first["overlap"]
    text = (
        f"ratio {run['ratio']:g} seed {run['seed']}: scan 1 {first['rect_mm']} "
        f"p={_p(first['p_value'])} inside {o['inside_fraction']:.2f} (chance "
        f"{o['chance']:.2f}) IoU {o['iou']:.2f} recall {o['recall']:.2f} centroid "
        f"{'in' if o['centroid_inside'] else 'out'}; loop "
        + " > ".join(str(c) for c in run["chosen"])
    )
    if found is not None:
        text += f"; region {found['rect_mm']} (round {found['round']}, ratio {found['ratio']:.3g})"
    return text + f" ({run['seconds']:.0f} s)"


def table(runs: list[dict]) -> str:
    """Markdown table: per run the round-1 scan, and the loop's region where the loop
    added one from a later round (a different rectangle)."""
    rows = [
        "| ratio | seed | scan (round) | rectangle [mm] | p (Bonferroni) | inside | chance "
        "| IoU | recall | centroid inside | fitted ratio | T scan / T outline | runtime [s] |",
        "|" + "---|" * 13,
    ]
    for run in runs:
        first, found = run["first_scan"], run["found"]
        t_ratio = first["statistic"] / max(run["outline_score"]["statistic"], 1e-300)
        if found is not None and found["round"] == 1:
            first = {**first, "ratio": found["ratio"]}
        label = "1, added" if first["chosen"] else "1, not added"
        rows.append(_row(run, label, first, f"{t_ratio:.3f}"))
        if found is not None and found["round"] > 1:
            rows.append(_row(run, f"{found['round']}, added", found, "-"))
    return "\n".join(rows)


# ------------------------------------------------------------------------- command line
def _numbers(text: str, kind, what: str) -> list:
    try:
        values = [kind(part) for part in text.split(",") if part.strip()]
    except ValueError:
        values = []
    if kind is float:
        ok, need = all(np.isfinite(v) and v > 0 for v in values), "ratios > 0"
    else:
        ok, need = all(v >= 0 for v in values), "integer seeds >= 0"
    if not values or not ok or len(values) > 20:
        raise ValueError(f"{what} takes a comma list of 1-20 {need}, got {text!r}")
    return values


def build_parser(prog: str = "python -m experiments.realskin.twin"):
    """The options of ``dvs realskin twin``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--ratios", default="3.5,23", help="stiffness ratios of the keloid")
    parser.add_argument("--seeds", default="0,1,2", help="noise seeds")
    parser.add_argument(
        "--force-noise", type=float, default=FORCE_NOISE_N, metavar="N", help="force noise [N]"
    )
    parser.add_argument("--k0", type=float, default=0.0, help="stiffening of the truth")
    parser.add_argument(
        "--base",
        choices=("calibrated", "homogeneous"),
        default="calibrated",
        help="the twin's material outside the keloid",
    )
    parser.add_argument("--verbose", action="store_true", help="print the loop's log")
    parser.add_argument("--out", type=path_argument, default=None, help="also write DIR/twin.json")
    return parser


def work(args) -> int:
    """``dvs realskin twin [--ratios 3.5,23] [--seeds 0,1,2]``; one line and exit 2 on bad input."""
    from experiments.command.options import UsageError, check_output_dir
    from experiments.output.atomic import atomic_write_json

    settings = RealSkinSettings()
    ratios = _numbers(args.ratios, float, "--ratios")
    seeds = _numbers(args.seeds, int, "--seeds")
    if not (np.isfinite(args.force_noise) and args.force_noise >= 0):
        raise UsageError(f"--force-noise must be >= 0 N, got {args.force_noise}")
    if not (np.isfinite(args.k0) and 0 <= args.k0 <= settings.bounds["k0"][1]):
        raise UsageError(f"--k0 must be in [0, {settings.bounds['k0'][1]:g}], got {args.k0}")
    if args.out is not None:
        check_output_dir(args.out)
    data = shared_data_dir() / "skin-extensometer" / "keloid"
    if not data.is_dir():
        raise UsageError(f"keloid data not found at {data} (set DVS_SHARED_DATA)")
    runs = []
    real = build("keloid", settings)  # data and model once, for every ratio and seed
    for ratio in ratios:
        for seed in seeds:
            run = run_twin(
                ratio,
                seed,
                settings,
                force_noise_n=args.force_noise,
                base=args.base,
                log=print if args.verbose else _quiet,
                real=real,
                k0=args.k0,
            )
            print(line(run), flush=True)
            runs.append(run)
    print(table(runs))
    print(
        f"truth: k0 {args.k0:g}, outline region; base {args.base}; DIC noise "
        f"{runs[0]['dic_noise_mm']:.4f} mm, force noise {args.force_noise:g} N"
    )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out / "twin.json", {"k0": args.k0, "runs": runs})
    return 0


main = Command("experiments.realskin.twin", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
