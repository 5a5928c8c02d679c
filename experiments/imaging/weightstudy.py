"""Which weight rule can see a small inclusion: a linearised Monte Carlo (docs/imaging.md,
"Which weight").

The benchmark inclusion of docs/imaging.md (a disc twice as stiff, 8 mm across, centre drawn
by ``numpy.random.default_rng(seed)`` over |x|, |y| <= 15 mm) on the scikit-fem slab,
10-load design, 0.02 mm noise, and the same slab and noise draw without the disc
(``inclusion_datasets``). Their difference is the FE disc's exact whitened signal d
(the noise cancels). At the disc-free homogeneous fit the field's J (N columns) and
nu's column are formed once; each draw is then the linear problem

    min_c |y + J c|^2 + beta c^T L c,   y = d + e,  e ~ N(0, I),  nu profiled,

solved in closed form on a grid of beta, so that every rule (Morozov, eq. I8's
default; GCV, eq. I10; UPRE, |r|^2 + 2 k - n; the marginal likelihood of the
Gaussian prior) and every fixed beta is scored on the same draws by docs/imaging.md's
criteria: the peak within 3 mm, the contrast within 30 % of 2, and 90 % of the nodes
over the markers within 2 std of the truth. Linear, without model error: a rule that
fails here fails on the full problem too.

Usage: ``dvs study imageweights --seed 7 --grid 23x23x4 --draws 200``; with a comma list of
seeds (``--seed 7,8,9``) it ends with the places table (docs/results/imaging-weights.md,
"At a random place"), and ``--oracle-press MM`` adds one press near the disc.
"""

from __future__ import annotations

import json
import time

import numpy as np

from experiments.command.options import Command

DIAMETER_MM = 8.0
RATIO = 2.0
BETAS = np.logspace(1.0, 9.0, 33)
"""The weights [mm^2] every draw is solved at: 4 per decade."""
ORACLE_FORCE_N = 0.25
"""The force [N] of ``--oracle-press``'s extra press: the paper's larger force."""
MARKED_HALF_MM = 20.0
"""Half the side of the marked area (9 x 9 markers over 40 mm)."""


def oracle_contact(centre, offset_mm: float) -> np.ndarray:
    """The oracle press's contact (x, y) [mm]: ``offset_mm`` from the disc's centre
    towards the patch's centre (0: on the disc)."""
    centre = np.asarray(centre, dtype=float)
    length = float(np.linalg.norm(centre))
    return centre if length < 1e-12 else centre * (1.0 - min(offset_mm / length, 1.0))


def study_cases(slab, oracle=None) -> tuple[np.ndarray, np.ndarray]:
    """Forces (K, 3) [N] and contacts (K, 2) [mm]: the 10-load diagnosis design, and with
    ``oracle`` (x, y) [mm] an eleventh press there, ``ORACLE_FORCE_N`` along -z."""
    from experiments.phantom.fe import design_cases

    forces, contacts = design_cases("diagnosis", slab)
    if oracle is None:
        return forces, contacts
    press = np.array([[0.0, 0.0, -ORACLE_FORCE_N]])
    return np.vstack([forces, press]), np.vstack([contacts, np.asarray(oracle, dtype=float)])


def inclusion_datasets(seed: int, oracle_mm: float | None = None):
    """(disc, none, centre): the acceptance datasets of one draw, sharing the noise draw.

    ``oracle_mm`` adds an eleventh press, 0.25 N along the normal, ``oracle_mm`` from the
    disc's true centre towards the patch's centre (``oracle_contact``), to the 10-load
    design: an oracle press, which says whether a miss at this place is one of
    information (the design) or of the method.
    """
    from experiments.phantom.fe import ReferenceSlab, reference_dataset
    from experiments.phantom.simulate import SimulationSettings

    centre = np.random.default_rng(seed).uniform(-15.0, 15.0, size=2)
    oracle = None if oracle_mm is None else oracle_contact(centre, oracle_mm)
    made = []
    for inclusion in ((float(centre[0]), float(centre[1]), DIAMETER_MM, RATIO), None):
        slab = ReferenceSlab(elements=(24, 24, 4), inclusion=inclusion)
        forces, contacts = study_cases(slab, oracle)
        measurement = SimulationSettings(noise_mm=0.02, seed=seed)
        made.append(reference_dataset(slab, forces, contacts, 4.0, (9, 9), measurement))
    return made[0], made[1], centre


def linearise(disc, none, grid, shape=(16, 16), log=print) -> dict:
    """J, nu's column, the disc signal d, L and the nodes' x-y at the disc-free fit; the
    disc-free data's own residual there, r0 (noise and model error; d + r0 is the disc
    dataset's), and the tissue's lengths [mm] for a regulariser."""
    from experiments.problem.fitting import FitSettings, build_problem, solve
    from solvers.imaging.fieldproblem import FieldProblem
    from solvers.imaging.regularization import Tikhonov
    from symbolic.field import StiffnessField, tissue_lengths

    fit = FitSettings(
        names=("E", "nu"), energy="linear-elastic", grid=grid, degrees=(3, 3, 2), margin=10.0
    )
    problem = build_problem(none, fit)
    result = solve(problem, "nested")
    young, poisson = (float(v) for v in result.x)
    field = StiffnessField(tuple(shape), "surface")
    zero = np.zeros(field.size)
    plain = FieldProblem(problem, field, young, poisson)
    with_disc = FieldProblem(build_problem(disc, fit), field, young, poisson)
    d = with_disc.residual(zero) - plain.residual(zero)
    log(f"  disc-free fit: E {young:.3f} kPa, nu {poisson:.4f}; disc signal |d|^2 {d @ d:.1f}")
    model = problem.model
    return {
        "J": plain.sensitivities(zero),
        "nu": plain.poisson_sensitivity(zero),
        "d": d,
        "L": Tikhonov(field, tissue_lengths(model)).matrix.toarray(),
        "xy": np.asarray(model.volume.collocation(field.nodes()) @ model.rest)[:, :2],
        "E": young,
        "r0": plain.residual(zero),
        "lengths": np.asarray(tissue_lengths(model)),
    }


class LinearStudy:
    """The estimates of every beta on a grid, for any data y.

    ``regularizer`` None: Tikhonov with ``parts["L"]``, in closed form. Otherwise an
    object with ``hessian(c)`` and ``value(c)`` (``solvers.imaging.regularization``), e.g.
    total variation, solved by lagged diffusivity from the largest beta down, each beta
    warm-started from the last; its dof and standard deviations are then those of the
    lagged Hessian at the estimate, as ``solvers.imaging.laplace.laplace`` forms them.
    """

    def __init__(self, parts: dict, centre, betas=BETAS, regularizer=None):
        q = parts["nu"] / np.linalg.norm(parts["nu"])
        self.project = lambda a: a - np.outer(q, q @ a) if a.ndim == 2 else a - q * (q @ a)
        self.J = self.project(parts["J"])
        self.d = self.project(parts["d"])
        self.L = parts["L"]
        self.n = self.J.shape[0]
        self.betas = np.asarray(betas)
        self.regularizer = regularizer
        self.normal = self.J.T @ self.J
        if regularizer is None:
            self.inverse = [np.linalg.inv(self.normal + b * self.L) for b in self.betas]
            self.dof = np.array([np.trace(h @ self.normal) for h in self.inverse])
            self.std = [np.sqrt(np.diag(h)) for h in self.inverse]
            self.logdet = np.array(
                [np.linalg.slogdet(self.normal + b * self.L)[1] for b in self.betas]
            )
        self.rank = int(np.linalg.matrix_rank(self.L))
        xy = parts["xy"]
        inside = np.linalg.norm(xy - np.asarray(centre), axis=1) <= DIAMETER_MM / 2
        self.truth = np.where(inside, np.log(RATIO), 0.0)
        self.xy, self.centre = xy, np.asarray(centre)
        self.markers = np.all(np.abs(xy) <= MARKED_HALF_MM, axis=1)

    def _lagged(self, rhs, beta, c, tolerance=1e-6, iterations=500):
        """The minimiser of |y + J c|^2 / 2 + beta R(c) by lagged diffusivity, and the
        Gauss-Newton Hessian J^T J + beta R''(c) there."""
        for _ in range(iterations):
            hessian = self.normal + beta * self.regularizer.hessian(c).toarray()
            new = np.linalg.solve(hessian, rhs)
            done = np.max(np.abs(new - c)) < tolerance
            c = new
            if done:
                break
        return c, self.normal + beta * self.regularizer.hessian(c).toarray()

    def path(self, y: np.ndarray):
        """Estimates, chi^2, penalty, effective dof and nodal std at every beta."""
        if self.regularizer is None:
            maps = [-(h @ (self.J.T @ y)) for h in self.inverse]
            penalty = np.array([b * c @ self.L @ c for b, c in zip(self.betas, maps)])
            dof, std = self.dof, self.std
        else:
            rhs, c = -(self.J.T @ y), np.zeros(self.J.shape[1])
            count = len(self.betas)
            maps, std, dof, penalty = (
                [None] * count,
                [None] * count,
                np.zeros(count),
                np.zeros(count),
            )
            for k in np.argsort(self.betas)[::-1]:
                c, hessian = self._lagged(rhs, self.betas[k], c)
                inverse = np.linalg.inv(hessian)
                maps[k], std[k] = c, np.sqrt(np.diag(inverse))
                dof[k] = np.trace(inverse @ self.normal)
                penalty[k] = 2 * self.betas[k] * self.regularizer.value(c)
        chi2 = np.array([np.sum((y + self.J @ c) ** 2) for c in maps])
        return maps, chi2, penalty, dof, std

    def choose(self, chi2: np.ndarray, penalty: np.ndarray, dof: np.ndarray) -> dict:
        """The index of beta each rule picks (the marginal likelihood: Tikhonov only)."""
        below = np.flatnonzero(chi2 <= self.n)
        rules = {
            "morozov": int(below.max()) if below.size else 0,
            "gcv": int(np.argmin(self.n * chi2 / (self.n - dof) ** 2)),
            "upre": int(np.argmin(chi2 + 2 * dof - self.n)),
        }
        if self.regularizer is None:
            evidence = chi2 + penalty + self.logdet - self.rank * np.log(self.betas)
            rules["marginal likelihood"] = int(np.argmin(evidence))
        return rules

    def own_draw(self, r0: np.ndarray) -> dict:
        """Each rule on the disc dataset's own noise: y = d + r0 (``linearise``)."""
        maps, chi2, penalty, dof, std = self.path(self.d + self.project(r0))
        found = {}
        for rule, k in self.choose(chi2, penalty, dof).items():
            contrast, distance, coverage, _ = self.score(maps[k], std[k])
            found[rule] = {
                "beta_mm2": float(self.betas[k]),
                "contrast": round(contrast, 3),
                "peak_mm": round(distance, 2),
                "coverage": round(coverage, 3),
            }
        return found

    def score(self, c: np.ndarray, std: np.ndarray) -> tuple[float, float, float, float]:
        """Contrast, peak distance [mm], coverage over the markers, strongest |z|."""
        best = np.flatnonzero(self.markers)[np.argmax(c[self.markers])]
        contrast = float(np.exp(c[best] - np.median(c[self.markers])))
        distance = float(np.linalg.norm(self.xy[best] - self.centre))
        coverage = float(np.mean(np.abs((c - self.truth) / std)[self.markers] <= 2.0))
        strongest = float(np.max(np.abs(c - c.mean()) / std))
        return contrast, distance, coverage, strongest


def study_regularizer(parts: dict, name: str):
    """None for "h1" (the study's closed form), else eq. (I7) on the 16 x 16 field."""
    if name == "h1":
        return None
    from solvers.imaging.regularization import TotalVariation
    from symbolic.field import StiffnessField

    side = int(round(np.sqrt(parts["J"].shape[1])))
    return TotalVariation(StiffnessField((side, side), "surface"), tuple(parts["lengths"]))


def passes(contrast, distance, coverage) -> bool:
    """The three criteria of docs/imaging.md on one map."""
    return 1.4 <= contrast <= 2.6 and distance <= 3.0 and coverage >= 0.9


def monte_carlo(study: LinearStudy, draws: int, seed: int = 0) -> dict:
    """Per rule: the median beta and the rates of each criterion; per fixed beta too;
    and on the disc-free data, how often a rule's map has a node beyond 2 std."""
    rng = np.random.default_rng(seed)
    rules: dict[str, list] = {}
    fixed = np.zeros((draws, len(study.betas), 5))
    null: dict[str, list] = {}
    for i in range(draws):
        noise = study.project(rng.standard_normal(study.n))
        maps, chi2, penalty, dof, std = study.path(study.d + noise)
        for rule, k in study.choose(chi2, penalty, dof).items():
            rules.setdefault(rule, []).append((study.betas[k],) + study.score(maps[k], std[k]))
        for k, c in enumerate(maps):
            fixed[i, k] = study.score(c, std[k]) + (dof[k],)
        maps, chi2, penalty, dof, std = study.path(noise)
        for rule, k in study.choose(chi2, penalty, dof).items():
            null.setdefault(rule, []).append(study.score(maps[k], std[k])[3])
    table = {}
    for rule, rows in rules.items():
        rows = np.array(rows)
        ok = [passes(*row[1:4]) for row in rows]
        table[rule] = {
            "median_beta_mm2": float(np.median(rows[:, 0])),
            "median_contrast": float(np.median(rows[:, 1])),
            "contrast_ok": float(np.mean((rows[:, 1] >= 1.4) & (rows[:, 1] <= 2.6))),
            "peak_ok": float(np.mean(rows[:, 2] <= 3.0)),
            "coverage_ok": float(np.mean(rows[:, 3] >= 0.9)),
            "all_ok": float(np.mean(ok)),
            "null_node_beyond_2_std": float(np.mean(np.array(null[rule]) > 2.0)),
        }
    per_beta = [
        {
            "beta_mm2": float(b),
            "dof": float(np.median(fixed[:, k, 4])),
            "median_contrast": float(np.median(fixed[:, k, 0])),
            "all_ok": float(np.mean([passes(*row[:3]) for row in fixed[:, k]])),
        }
        for k, b in enumerate(study.betas)
    ]
    return {
        "draws": draws,
        "n": study.n,
        "signal_chi2": float(study.d @ study.d),
        "rules": table,
        "fixed_beta": per_beta,
    }


def build_parser(prog: str = "python -m experiments.imaging.weightstudy"):
    """The options of ``dvs study imageweights``."""
    from experiments.command.options import make_parser

    parser = make_parser(
        prog, "Which weight rule sees the acceptance inclusion: a linearised Monte Carlo."
    )
    parser.add_argument(
        "--seed",
        default="7",
        help="the disc's draw, or a comma list of draws for the places table (default: 7)",
    )
    parser.add_argument("--grid", default="23x23x4", help="control grid MxNxL of the model")
    parser.add_argument("--draws", type=int, default=200, help="noise draws (default: 200)")
    parser.add_argument(
        "--oracle-press",
        type=float,
        metavar="MM",
        help="add an 11th press (0.25 N, normal) MM from the disc's true centre towards the "
        "patch's centre (0: on the disc): an oracle press",
    )
    parser.add_argument(
        "--regularizer",
        choices=("h1", "tv"),
        default="h1",
        help="h1 (closed form, default) or tv (lagged diffusivity, about 10x slower)",
    )
    return parser


def nearest_press_mm(centre, oracle_mm: float | None = None) -> float:
    """Distance [mm] from ``centre`` (x, y) to the nearest contact of the study's design."""
    from experiments.phantom.fe import ReferenceSlab

    oracle = None if oracle_mm is None else oracle_contact(centre, oracle_mm)
    _, contacts = study_cases(ReferenceSlab(elements=(1, 1, 1)), oracle)
    return float(np.min(np.linalg.norm(contacts - np.asarray(centre), axis=1)))


def place_row(seed: int, centre, result: dict, oracle_mm: float | None = None) -> dict:
    """One place's line of the places table: where the disc is, its signal, and how often
    each rule and the best fixed weight meet all three criteria."""
    best = max(result["fixed_beta"], key=lambda row: row["all_ok"])
    return {
        "seed": seed,
        "centre_mm": [round(float(c), 2) for c in centre],
        "nearest_press_mm": round(nearest_press_mm(centre, oracle_mm), 2),
        "signal_chi2": round(result["signal_chi2"], 1),
        "all_ok": {rule: row["all_ok"] for rule, row in result["rules"].items()},
        "best_fixed": {"beta_mm2": best["beta_mm2"], "all_ok": best["all_ok"]},
    }


def places_table(rows: list[dict]) -> str:
    """The places as a markdown table (docs/results/imaging-weights.md, "At a random place")."""
    rules = list(rows[0]["all_ok"])
    head = "| seed | disc (x, y) [mm] | nearest press [mm] | signal chi^2 | "
    head += " | ".join(rules) + " | best fixed weight [mm^2] |"
    lines = [head, "|" + "---|" * (5 + len(rules))]
    for row in rows:
        x, y = row["centre_mm"]
        rates = " | ".join(f"{row['all_ok'][rule]:.2f}" for rule in rules)
        best = row["best_fixed"]
        lines.append(
            f"| {row['seed']} | ({x:.2f}, {y:.2f}) | {row['nearest_press_mm']:.1f} | "
            f"{row['signal_chi2']:.1f} | {rates} | {best['all_ok']:.2f} at "
            f"{best['beta_mm2']:.3g} |"
        )
    return "\n".join(lines)


def work(args) -> int:
    """Print the rules' rates and the fixed weights' (``dvs study imageweights``), for each
    seed; for several, the places table at the end."""
    from experiments.command.options import (
        UsageError,
        check_grid,
        check_seed,
        parse_grid,
        parse_numbers,
    )

    if args.draws < 1:
        raise UsageError(f"--draws must be at least 1, got {args.draws}")
    if args.oracle_press is not None and not 0.0 <= args.oracle_press <= 30.0:
        raise UsageError(f"--oracle-press must be 0 to 30 mm, got {args.oracle_press}")
    seeds = [check_seed(s) for s in parse_numbers(args.seed, "--seed", int)]
    if not seeds:
        raise UsageError("--seed takes one seed or a comma list of seeds, e.g. 7,8,9")
    grid = check_grid(parse_grid(args.grid), (3, 3, 2), args.grid)
    rows = []
    for seed in seeds:
        begin = time.perf_counter()
        disc, none, centre = inclusion_datasets(seed, args.oracle_press)
        print(f"seed {seed}: disc at ({centre[0]:.2f}, {centre[1]:.2f}) mm", flush=True)
        parts = linearise(disc, none, grid)
        regularizer = study_regularizer(parts, args.regularizer)
        study = LinearStudy(parts, centre, regularizer=regularizer)
        own = study.own_draw(parts["r0"])
        result = monte_carlo(study, args.draws)
        print("the dataset's own noise draw:", json.dumps(own))
        print(json.dumps(result["rules"], indent=1))
        for row in result["fixed_beta"][::2]:
            print(
                f"  beta {row['beta_mm2']:9.3g}: dof {row['dof']:6.1f}, median contrast "
                f"{row['median_contrast']:.2f}, all criteria met {row['all_ok']:.2f}"
            )
        seconds = time.perf_counter() - begin
        print(f"signal chi2 {result['signal_chi2']:.1f} on n = {result['n']}; {seconds:.0f} s")
        rows.append(place_row(seed, centre, result, args.oracle_press))
    if len(rows) > 1:
        print("\nall three criteria met, fraction of the draws:")
        print(places_table(rows))
    return 0


main = Command("experiments.imaging.weightstudy", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
