"""Adaptive stiffness imaging: image, choose the press, press, image again (docs/imaging.md,
"Adaptive imaging").

The acceptance inclusion of the imaging issue (a disc twice as stiff, 8 mm across, centre
drawn by ``numpy.random.default_rng(seed)`` over |x|, |y| <= 15 mm) in the scikit-fem
slab, 0.02 mm noise, starting from the 10-load design. The candidates are presses of
0.25 N along the normal on a 7 x 7 grid over |x|, |y| <= 15 mm; each is pressed at most
once. The slab, with and without the disc and the same noise draw, is pressed by every
design and candidate load once (``place_rows``), and the problem is linearised at the
disc-free homogeneous fit, as in the weight study (``experiments.imaging.weightstudy``):
each press's rows of J, of nu's column and of the data are kept apart
(``solvers.imaging.fielddesign.PressRows``), so that any set of presses is the map of an
experiment that made those presses.

The loop (``adaptive_run``): map the presses so far (H1, the GCV weight: the rule the
weight study chose, over the study's 33 weights, nu profiled); the posterior of the
inclusion's place (eq. I12); stop when it is localised within 3 mm, or "no inclusion",
with probability ``GOAL`` (eq. I14), or when ``BUDGET`` presses were added; else press
the candidate of eq. (I13) and map again. Each map is scored by docs/imaging.md's criteria
(peak within 3 mm, contrast 2 +- 30 %, 90 % of the nodes over the markers within 2 std)
and, on the disc-free data, by the strongest departure (no node beyond 2 std).

Usage: ``dvs study imageadaptive --out DIR`` (seeds 17-26, the 27x27x4 model, 20 fresh draws).
"""

from __future__ import annotations

import time

import numpy as np

from experiments.command.options import (
    Command,
    UsageError,
    check_grid,
    check_output_dir,
    check_seed,
    make_parser,
    parse_grid,
    parse_numbers,
    path_argument,
)
from experiments.imaging.weightstudy import (
    DIAMETER_MM,
    MARKED_HALF_MM,
    RATIO,
    LinearStudy,
    passes,
    study_cases,
)
from solvers.imaging.fielddesign import (
    PlacePosterior,
    PressRows,
    inclusion_templates,
    per_press,
    press_scores,
)

CANDIDATE_SIDE = 7
"""Candidate contacts per side of the grid over the disc's range."""
CANDIDATE_SPAN_MM = 15.0
"""The candidates' grid covers |x|, |y| <= this [mm] (the disc's range)."""
CANDIDATE_FORCE_N = 0.25
"""Every candidate presses along the normal with the paper's larger force [N]."""
BUDGET = 4
"""Adaptive presses at most (docs/imaging.md)."""
GOAL = 0.9
"""Posterior mass that stops the loop (eq. I14)."""
PRECISION = 0.1
"""The inclusion's amplitude known to this fraction of the target's log-contrast (its
standard error lambda^-1/2, eq. I14) before the loop stops: the contrast criterion is
+-30 %, log(1.3) = 0.38 of log 2, so 0.1 leaves most of that band to the map's bias."""
LOCALISED_MM = 3.0
"""The radius of eq. (I14): docs/imaging.md's peak criterion."""


def candidate_contacts() -> np.ndarray:
    """(C, 2) contacts [mm] of the candidate presses."""
    side = np.linspace(-CANDIDATE_SPAN_MM, CANDIDATE_SPAN_MM, CANDIDATE_SIDE)
    return np.array([(x, y) for x in side for y in side])


def place_rows(seed: int, grid, log=print, shape=(16, 16)) -> dict:
    """The FE slab with and without the seed's disc, pressed by the 10-load design and by
    every candidate (one dataset of each, the same noise draw), linearised at the
    disc-free fit: the rows per press, the disc's exact signal per press, the field's L
    and node positions, the disc's centre and which presses are the design's."""
    from experiments.phantom.fe import ReferenceSlab, SlabSolution, reference_dataset
    from experiments.phantom.simulate import SimulationSettings
    from experiments.problem.fitting import FitSettings, build_problem, solve
    from solvers.imaging.fieldproblem import FieldProblem
    from solvers.imaging.regularization import Tikhonov
    from symbolic.field import StiffnessField, tissue_lengths

    begin = time.perf_counter()
    centre = np.random.default_rng(seed).uniform(-15.0, 15.0, size=2)
    design_forces, design_contacts = study_cases(ReferenceSlab(elements=(1, 1, 1)))
    contacts = candidate_contacts()
    forces = np.vstack([design_forces, np.tile([0.0, 0.0, -CANDIDATE_FORCE_N], (len(contacts), 1))])
    contacts = np.vstack([design_contacts, contacts])
    made = []
    for inclusion in ((float(centre[0]), float(centre[1]), DIAMETER_MM, RATIO), None):
        slab = ReferenceSlab(elements=(24, 24, 4), inclusion=inclusion)
        measurement = SimulationSettings(noise_mm=0.02, seed=seed)
        made.append(
            reference_dataset(
                slab, forces, contacts, 4.0, (9, 9), measurement, solver=SlabSolution(slab)
            )
        )
    disc, none = made
    seconds = time.perf_counter() - begin
    log(f"  FE data: {len(forces)} presses with and without the disc ({seconds:.0f} s)")
    fit = FitSettings(
        names=("E", "nu"), energy="linear-elastic", grid=grid, degrees=(3, 3, 2), margin=10.0
    )
    problem = build_problem(none, fit)
    young, poisson = (float(v) for v in solve(problem, "nested").x)
    field = StiffnessField(tuple(shape), "surface")
    zero = np.zeros(field.size)
    plain = FieldProblem(problem, field, young, poisson)
    with_disc = FieldProblem(build_problem(disc, fit), field, young, poisson)
    J, nu = plain.sensitivities(zero), plain.poisson_sensitivity(zero)
    rows = PressRows.split(plain, J, nu, with_disc.residual(zero))
    noise = per_press(plain, plain.residual(zero))
    model = problem.model
    log(
        f"  disc-free fit E {young:.3f} kPa, nu {poisson:.4f}; sensitivities of "
        f"{len(forces)} presses ({time.perf_counter() - begin:.0f} s)"
    )
    return {
        "rows": rows,
        "signal": [a - b for a, b in zip(rows.y, noise)],
        "own_noise": noise,
        "L": Tikhonov(field, tissue_lengths(model)).matrix.toarray(),
        "xy": np.asarray(model.volume.collocation(field.nodes()) @ model.rest)[:, :2],
        "centre": centre,
        "design": list(range(len(design_forces))),
        "candidates": list(range(len(design_forces), len(forces))),
        "contacts": contacts,
    }


def image(rows: PressRows, presses, place: dict, data=None) -> dict:
    """The GCV map of ``presses`` (data ``data`` per press, default the stored) and the
    the scores of docs/imaging.md."""
    J, y, q = rows.select(presses, data)
    study = LinearStudy(
        {"J": J, "nu": q, "d": y, "L": place["L"], "xy": place["xy"]}, place["centre"]
    )
    maps, chi2, penalty, dof, std = study.path(y)
    k = study.choose(chi2, penalty, dof)["gcv"]
    contrast, distance, coverage, strongest = study.score(maps[k], std[k])
    z = np.abs(maps[k] - maps[k].mean()) / std[k]
    return {
        "beta_mm2": float(study.betas[k]),
        "dof": float(dof[k]),
        "contrast": contrast,
        "peak_mm": distance,
        "coverage": coverage,
        "passes": bool(passes(contrast, distance, coverage)),
        "strongest_z": strongest,
        "beyond_2_std": bool(np.any(z[study.markers] > 2.0)),
        "signal_chi2": None,
    }


def adaptive_run(place: dict, data=None, budget: int = BUDGET, log=print) -> dict:
    """The loop on one place's data (``data`` per press: default the FE disc data with
    their own noise): the path of maps, posteriors and presses."""
    rows = place["rows"]
    marked = np.all(np.abs(place["xy"]) <= MARKED_HALF_MM, axis=1)
    places = place["xy"][marked]
    templates = inclusion_templates(place["xy"], places, DIAMETER_MM / 2, np.log(RATIO))
    chosen, path = list(place["design"]), []
    while True:
        J, y, _ = rows.select(chosen, data)
        posterior = PlacePosterior.of(J, y, templates, places)
        known = posterior.known(J, templates, LOCALISED_MM, GOAL, PRECISION)
        row = {
            "presses": len(chosen),
            "map": image(rows, chosen, place, data),
            "localised": posterior.localised(LOCALISED_MM),
            "no_inclusion": posterior.none,
            "mode_mm": [float(v) for v in posterior.mode()],
            "press": None,
        }
        path.append(row)
        added = len(chosen) - len(place["design"])
        if known or added >= budget:
            row["stop"] = "known" if known else "budget spent"
            break
        left = [k for k in place["candidates"] if k not in chosen]
        weights = posterior.probability / posterior.probability.sum()
        scores = press_scores(rows, chosen, left, templates, weights)
        best = left[int(np.argmax(scores))]
        row["press"] = [float(v) for v in place["contacts"][best]]
        chosen.append(best)
        log(
            f"    {len(chosen) - 1} presses: map peak {row['map']['peak_mm']:.1f} mm, contrast "
            f"{row['map']['contrast']:.2f}, localised {row['localised']:.2f} -> press at "
            f"({row['press'][0]:.0f}, {row['press'][1]:.0f}) mm"
        )
    return {"path": path, "final": path[-1]["map"], "fixed": path[0]["map"]}


def fresh_draw(place: dict, rng, with_disc: bool = True) -> list:
    """Data per press of a new noise draw: the disc's signal (or none) plus loaded-marker
    noise and the shared rest-marker noise (raw covariance I + P P^T, over sigma)."""
    rows = place["rows"]
    rest = rng.standard_normal(rows.P[0].shape[1])
    return [
        (s if with_disc else 0.0) + rng.standard_normal(len(s)) + p @ rest
        for s, p in zip(place["signal"], rows.P)
    ]


def study_place(seed: int, grid, draws: int, log=print, shape=(16, 16)) -> dict:
    """One place: the loop on the FE data's own noise, with and without the disc, and
    over ``draws`` fresh noise draws (rates)."""
    begin = time.perf_counter()
    place = place_rows(seed, grid, log, shape)
    centre = place["centre"]
    log(f"seed {seed}: disc at ({centre[0]:.2f}, {centre[1]:.2f}) mm")
    own = adaptive_run(place, log=log)
    null = adaptive_run(place, place["own_noise"], log=lambda _: None)
    rng = np.random.default_rng(1000 + seed)
    rates = {"fixed": 0, "adaptive": 0, "null_fixed": 0, "null_adaptive": 0, "presses": []}
    for _ in range(draws):
        run = adaptive_run(place, fresh_draw(place, rng), log=lambda _: None)
        rates["fixed"] += run["fixed"]["passes"]
        rates["adaptive"] += run["final"]["passes"]
        rates["presses"].append(run["path"][-1]["presses"] - len(place["design"]))
        quiet = adaptive_run(place, fresh_draw(place, rng, False), log=lambda _: None)
        rates["null_fixed"] += quiet["fixed"]["beyond_2_std"]
        rates["null_adaptive"] += quiet["final"]["beyond_2_std"]
    for key in ("fixed", "adaptive", "null_fixed", "null_adaptive"):
        rates[key] = rates[key] / max(draws, 1)
    rates["median_presses"] = float(np.median(rates.pop("presses"))) if draws else None
    return {
        "seed": seed,
        "centre_mm": [float(v) for v in centre],
        "own": own,
        "null": null,
        "rates": rates,
        "draws": draws,
        "seconds": time.perf_counter() - begin,
    }


def table(results: list[dict]) -> str:
    """The places as a markdown table: the fixed design and the adaptive loop side by side."""

    def cell(m):
        verdict = "pass" if m["passes"] else "miss"
        return f"{m['peak_mm']:.1f} / {m['contrast']:.2f} / {m['coverage']:.2f} {verdict}"

    lines = [
        "| seed | disc (x, y) [mm] | 10 loads: peak [mm] / contrast / coverage | presses added "
        "| adaptive: peak / contrast / coverage | homogeneous, after the loop: a node beyond "
        "2 std | over fresh draws: fixed, adaptive, null fixed, null adaptive |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        own = r["own"]
        added = own["path"][-1]["presses"] - own["path"][0]["presses"]
        x, y = r["centre_mm"]
        rates = r["rates"]
        lines.append(
            f"| {r['seed']} | ({x:.2f}, {y:.2f}) | {cell(own['fixed'])} | {added} | "
            f"{cell(own['final'])} | {'yes' if r['null']['final']['beyond_2_std'] else 'no'} | "
            f"{rates['fixed']:.2f}, {rates['adaptive']:.2f}, {rates['null_fixed']:.2f}, "
            f"{rates['null_adaptive']:.2f} |"
        )
    return "\n".join(lines)


def build_parser(prog: str = "python -m experiments.imaging.adaptive"):
    """The options of ``dvs study imageadaptive``."""
    parser = make_parser(prog, "Adaptive stiffness imaging at random places (a study).")
    parser.add_argument(
        "--seeds", default="17,18,19,20,21,22,23,24,25,26", help="the places' draws"
    )
    parser.add_argument(
        "--grid",
        default="27x27x4",
        help="control grid MxNxL of the model (27x27x4: where the continuum reaches the noise)",
    )
    parser.add_argument("--draws", type=int, default=20, help="fresh noise draws per place")
    parser.add_argument("--field", default="16x16", help="nodes of the surface field MxN")
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    return parser


def work(args) -> int:
    """Run the places and write ``adaptive.json`` and ``adaptive.md`` to ``--out``."""
    from experiments.imaging.options import parse_field
    from experiments.output.atomic import atomic_write_json, atomic_write_text

    out = check_output_dir(args.out)
    seeds = [check_seed(s) for s in parse_numbers(args.seeds, "--seeds", int)]
    if not seeds:
        raise UsageError("--seeds takes a comma list of seeds, e.g. 17,18")
    if args.draws < 0:
        raise UsageError(f"--draws must be at least 0, got {args.draws}")
    grid = check_grid(parse_grid(args.grid), (3, 3, 2), args.grid)
    shape = parse_field(args.field, "surface")
    results = []
    for seed in seeds:
        results.append(
            study_place(seed, grid, args.draws, lambda line: print(line, flush=True), shape)
        )
        print(table(results[-1:]).splitlines()[-1], flush=True)
    out.mkdir(parents=True, exist_ok=True)
    document = {"schema": "dvs-adaptive-imaging/1", "field": list(shape), "places": results}
    atomic_write_json(out / "adaptive.json", document)
    atomic_write_text(out / "adaptive.md", table(results) + "\n")
    print(table(results))
    return 0


main = Command("experiments.imaging.adaptive", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
