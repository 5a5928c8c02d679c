"""Real skin with the continuum energies: E and nu of both extensometer cases.

``dvs realskin-continuum --out DIR`` fits the two-pad extensometer (``skin-extensometer``)
with the paper's energy (before) and with isotropic linear elasticity and the
compressible neo-Hookean energy of ``symbolic.continuum_model`` (after), on the same
slab, pads, DIC frames and forces as ``dvs realskin`` (``experiments.realskin.setup``).

**Choice**: the continuum slab is a membrane, its edge ring fixed and its inner face
free (``boundary="lateral"``), linear through its thickness t. A thin plate loaded in
its plane is in plane stress, the authors' 2D model, so E t [N/mm] and nu compare with
their E and nu directly if their E is per unit thickness (the README says "probably
N/mm"); E [kPa] is the modulus of a 3D slab of thickness t.

Writes ``continuum.json`` (estimates, standard errors, RMS errors, the authors' ranges)
and ``continuum.md`` (the table of docs/realskin.md).
"""

from __future__ import annotations

from pathlib import Path

from experiments.atomic import atomic_write_json, atomic_write_text
from experiments.realskin.cases import load_cases
from experiments.realskin.model import SkinParameterSpace
from experiments.realskin.setup import RealSkinSettings, Setup, build
from experiments.realskin.stages import StageFit, fit_stage
from experiments.realskin.study import AUTHORS
from symbolic.continuum import KPA
from symbolic.continuum_model import ENERGIES
from symbolic.model import BoundaryConditions

CONTINUUM_ENERGIES = ("linear-elastic", "neo-hookean")
BOUNDS = {"E": (0.1, 1e4), "nu": (0.0, 0.49)}
"""E [kPa] and nu [1]."""


def start_values(name: str, thickness_mm: float) -> dict[str, float]:
    """The middle of the authors' ranges, E per unit thickness turned into kPa."""
    (e_low, e_high), (nu_low, nu_high) = AUTHORS[name]["E"], AUTHORS[name]["nu"]
    return {"E": 0.5 * (e_low + e_high) / thickness_mm / KPA, "nu": 0.5 * (nu_low + nu_high)}


def fit_energy(setup: Setup, energy: str, thickness_mm: float, log=print) -> StageFit:
    """E and nu of one case with one continuum energy, on the study's slab and frames."""
    name = setup.case.name
    start = start_values(name, thickness_mm)
    model = ENERGIES[energy](
        setup.model.volume,
        dict(start),
        BoundaryConditions(fix_inner=False, fix_lateral=True),
        prescribed=setup.pads.prescribed,
    )
    cases = load_cases(model, setup.pads, setup.data, setup.weight)
    space = SkinParameterSpace.build(("E", "nu"), start, BOUNDS)
    return fit_stage(model, cases, space, f"{name}, {energy}", log)


def paper_fit(setup: Setup, bounds: dict, log=print) -> StageFit:
    """The paper's linear energy (alpha_u, isotropic in the plane) on the same membrane."""
    space = SkinParameterSpace.build(setup.base_names, setup.start, bounds)
    return fit_stage(setup.model, setup.cases, space, f"{setup.case.name}, dnurbs (eq. 18)", log)


def summary(name: str, fit: StageFit, thickness_mm: float) -> dict:
    """One row: estimates with standard errors, E t against the authors, RMS errors."""
    row = {
        "case": name,
        "model": fit.label.split(", ", 1)[1],
        "rms_displacement_mm": fit.rms_displacement_mm,
        "rms_force_n": fit.rms_force_n,
        "cost": fit.cost,
        "seconds": fit.seconds,
        "parameters": {
            n: {"value": float(v), "std": float(s)} for n, v, s in zip(fit.names, fit.x, fit.std)
        },
    }
    if "E" in fit.names:
        young = float(fit.x[list(fit.names).index("E")])
        row["E_times_thickness_n_per_mm"] = young * KPA * thickness_mm
        row["authors"] = AUTHORS[name]
    return row


def table(rows: list[dict]) -> str:
    """The markdown table of docs/realskin.md."""
    lines = [
        "| case | model | E [kPa] | nu | E t [N/mm] | authors E, nu | RMS displacement [mm] "
        "| RMS force [N] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        p = row["parameters"]
        if "E" in p:
            young = f"{p['E']['value']:.2f} +/- {p['E']['std']:.2f}"
            poisson = f"{p['nu']['value']:.3f} +/- {p['nu']['std']:.3f}"
            membrane = f"{row['E_times_thickness_n_per_mm']:.4f}"
            (e0, e1), (n0, n1) = row["authors"]["E"], row["authors"]["nu"]
            authors = f"{e0}-{e1}, {n0}-{n1}"
        else:
            young = poisson = membrane = authors = ""
        lines.append(
            f"| {row['case']} | {row['model']} | {young} | {poisson} | {membrane} | {authors} "
            f"| {row['rms_displacement_mm']:.4f} | {row['rms_force_n']:.4f} |"
        )
    return "\n".join(lines)


def run(out: Path, cases=("healthy", "keloid"), thickness_mm: float = 2.0, log=print) -> dict:
    """Fit every case with the paper's energy and both continua; write the outputs."""
    settings = RealSkinSettings(thickness_mm=thickness_mm, boundary="lateral")
    rows = []
    for name in cases:
        log(f"{name}: fitting the paper's energy and the continua")
        setup = build(name, settings)
        rows.append(summary(name, paper_fit(setup, settings.bounds, log), thickness_mm))
        for energy in CONTINUUM_ENERGIES:
            rows.append(summary(name, fit_energy(setup, energy, thickness_mm, log), thickness_mm))
    document = {"thickness_mm": thickness_mm, "boundary": "lateral", "fits": rows}
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "continuum.json", document)
    atomic_write_text(out / "continuum.md", table(rows) + "\n")
    log(table(rows))
    return document


def build_parser(prog: str = "python -m experiments.realskin.continuum"):
    from experiments.options import make_parser, path_argument

    parser = make_parser(prog, "Fit real skin with the continuum energies (E, nu).")
    parser.add_argument("--cases", default="healthy,keloid", help="comma list of cases")
    parser.add_argument(
        "--thickness", type=float, default=2.0, help="slab thickness [mm] (default 2)"
    )
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    return parser


def main(argv: list[str] | None = None, prog: str = "python -m experiments.realskin.continuum"):
    from experiments.options import UsageError, check_output_dir, run_guarded

    parser = build_parser(prog)
    args = parser.parse_args(argv)

    def work() -> int:
        cases = tuple(c.strip() for c in args.cases.split(",") if c.strip())
        unknown = [c for c in cases if c not in AUTHORS]
        if unknown or not cases:
            raise UsageError(f"--cases must name healthy and/or keloid, got {args.cases!r}")
        if not (0.1 <= args.thickness <= 10.0):
            raise UsageError(f"--thickness must lie in 0.1-10 mm, got {args.thickness}")
        run(check_output_dir(args.out), cases, args.thickness)
        return 0

    return run_guarded(prog, work)


if __name__ == "__main__":
    raise SystemExit(main())
