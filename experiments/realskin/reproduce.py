"""The original authors' fit of the extensometer, reproduced, then one assumption at a time.

``dvs realskin authors --out DIR`` fits (E, nu) of the plane-strain neo-Hookean model on
the authors' assumptions (``experiments.realskin.authors``: free outer edges, the .geo
pads as holes, their frame rule and force, their cost) on our own mesh of
``geometry.geo`` (``experiments.realskin.mesh2d``), then changes one assumption at a time
and refits:

* ``ring``: the outer edges held at 0 (the project's membrane) instead of free;
* ``plane``: plane stress instead of plane strain;
* ``frames``: the frames up to 3.83 mm of travel (every healthy DIC frame) instead of
  3 (or 2);
* ``gap``: the pads placed at the pad files' reference points (the project's placement:
  36.5 mm apart for healthy skin, not the .geo's 32; the DIC origin at the moving pad's
  inner-edge midpoint); for the keloid both placements coincide and the row is skipped;
* ``force``: the pad force as the sum of the internal forces on the pad's nodes instead
  of the traction integral over its edges;
* ``project``: ring, plane stress, frames to 3.83 mm and the pad files' gap together.

The options set the baseline; each variant changes one thing from it. The keloid is
fitted as two materials, (E, nu) of the keloid's triangles with the skin held: at the
authors' own healthy values (tag 5) on their assumptions, and at our healthy fit under
the same assumptions otherwise.

**Fit**: scipy's trust-region least squares on z = (ln E, nu), nu in [-0.9, 0.499], with
the exact Jacobian of the residuals of J = 1/2 |r|^2 (``planar.Extensometer``).

Writes ``authors.json`` (every fit, with the authors' values and the source) and
``authors.md`` (the table of docs/realskin.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.realskin import authors, mesh2d
from experiments.realskin.data import load_case
from experiments.realskin.planar import Assumptions, EquilibriumFailed, Extensometer
from experiments.realskin.planarfit import NU_BOUNDS, Fit, least_squares_fit

ALL_TRAVEL_MM = 3.83
"""'Frames to 3.8 mm': the project's healthy range (every healthy DIC frame)."""

VARIANTS = {
    "ring": "edge ring fixed",
    "plane": "plane stress",
    "frames": "frames to 3.8 mm",
    "gap": "pads at the pad files' points",
    "force": "reaction force",
    "project": "the project's four (ring, stress, 3.8 mm, gap)",
}
"""One assumption changed at a time (or the project's four together): name -> label."""

START = {"healthy": (0.03, 0.2), "keloid": (0.12, 0.38)}
"""Start values (E [N/mm], nu)."""


@dataclass(frozen=True)
class Setting:
    """One fit's choices.

    Attributes
    ----------
    case : {"healthy", "keloid"}
    travel_mm : float
        Frames among those with pad travel up to this [mm].
    assumptions : planar.Assumptions
    pads : {"geo", "files"}
        Where the pads are: the .geo's, with the authors' DIC origin, or at the pad
        files' reference points (the project's placement: the gap between them, the DIC
        origin at the moving pad's inner-edge midpoint).
    gap_mm : float or None
        A pad gap [mm] of one's own (placed as "files"); None: as ``pads`` says.
    mesh_size_mm : float
        Element size around the pads and the gap [mm] (4x elsewhere).
    """

    case: str = "healthy"
    travel_mm: float = 3.0
    assumptions: Assumptions = Assumptions()
    pads: str = "geo"
    gap_mm: float | None = None
    mesh_size_mm: float = 1.0

    @property
    def theirs(self) -> bool:
        """All of the authors' assumptions (their values are comparable)."""
        return (
            self.assumptions == Assumptions() and not self.placed and self.travel_mm in (3.0, 2.0)
        )

    @property
    def placed(self) -> bool:
        """The pads at the pad files' points (or a gap of one's own), not the .geo's."""
        return self.pads == "files" or self.gap_mm is not None

    def gap(self) -> float | None:
        """The gap to warp the mesh's pads to [mm]; None keeps the .geo's."""
        if self.gap_mm is not None:
            return self.gap_mm
        if self.pads == "files" and not same_gap(self.case):
            return pad_file_gap(self.case)
        return None


@lru_cache(maxsize=2)
def measured(case: str):
    """The case's data (``experiments.realskin.data.load_case``), read once."""
    return load_case(case)


def pad_file_gap(case: str) -> float:
    """The distance of the two pad files' reference points at frame 0 [mm] (project's gap)."""
    data = measured(case)
    return float(data.pad_fixed_mm[0, 0] - data.pad_moving_mm[0, 0])


def same_gap(case: str) -> bool:
    """The pad files' gap is the .geo's (the keloid: both placements coincide)."""
    return abs(pad_file_gap(case) - measured(case).geometry.pad_gap_mm) < 1e-3


def variant(setting: Setting, name: str) -> Setting | None:
    """``setting`` with one assumption changed (None when the change is no change)."""
    a = setting.assumptions
    if name == "ring":
        return replace(setting, assumptions=replace(a, fix_ring=not a.fix_ring))
    if name == "plane":
        return replace(
            setting, assumptions=replace(a, plane="stress" if a.plane == "strain" else "strain")
        )
    if name == "force":
        force = "reaction" if a.force == "traction" else "traction"
        return replace(setting, assumptions=replace(a, force=force))
    if name == "frames":
        return (
            None
            if setting.travel_mm >= ALL_TRAVEL_MM
            else replace(setting, travel_mm=ALL_TRAVEL_MM)
        )
    if name == "gap":
        if same_gap(setting.case) and setting.gap_mm is None:
            return None
        return replace(setting, pads="geo" if setting.placed else "files", gap_mm=None)
    if name == "project":
        project = Assumptions(plane="stress", fix_ring=True, force=a.force)
        return replace(setting, assumptions=project, travel_mm=ALL_TRAVEL_MM, pads="files")
    raise ValueError(f"unknown variant {name!r}; use {', '.join(VARIANTS)}")


# ----------------------------------------------------------------------- the set-up
_MESHES: dict = {}


def mesh_for(case: str, size: float, gap: float | None) -> mesh2d.Mesh2D:
    """Our mesh of the case's ``geometry.geo`` (cached), pads moved to ``gap`` if given."""
    key = (case, size, gap)
    if key not in _MESHES:
        mesh = mesh2d.build_mesh(measured(case).geometry, size)
        _MESHES[key] = mesh if gap is None else mesh2d.warp_gap(mesh, gap)
    return _MESHES[key]


def problem(setting: Setting, held=None) -> Extensometer:
    """The forward problem of a setting (keloid: region 1 fitted, ``held`` elsewhere)."""
    mesh = mesh_for(setting.case, setting.mesh_size_mm, setting.gap())
    origin = None
    if setting.placed:  # the project's placement: the pad's inner-edge midpoint
        origin = (mesh.pad_moving.x1, 0.5 * (mesh.pad_moving.y0 + mesh.pad_moving.y1))
    frames = authors.load_frames(measured(setting.case), setting.travel_mm, origin=origin)
    region = 1 if setting.case == "keloid" else None
    return Extensometer(mesh, frames, setting.assumptions, fitted_region=region, held=held)


# ------------------------------------------------------------------------- the fit
def fit(extensometer: Extensometer, start, max_evaluations: int = 60) -> Fit:
    """Least squares on z = (ln E, nu) with the exact Jacobian (``least_squares_fit``)."""
    return least_squares_fit(
        lambda p, previous: extensometer.solve(p, previous=previous),
        extensometer, start, np.array([True, False]), extensometer.cost,
        (EquilibriumFailed, FloatingPointError), ftol=1e-10, max_evaluations=max_evaluations,
    )  # fmt: skip


def gradient_at(extensometer: Extensometer, p) -> dict:
    """The cost and its gradient dJ/d(E, nu) at p (e.g. a published value)."""
    solution = extensometer.solve(np.asarray(p, dtype=float))
    r, jac = extensometer.residuals(solution), extensometer.jacobian(solution)
    return {
        "p": list(map(float, p)),
        **extensometer.cost(solution),
        "gradient": (jac.T @ r).tolist(),
    }


# --------------------------------------------------------------------- the study
def describe(setting: Setting) -> dict:
    """The assumptions of a row, for the JSON."""
    a = setting.assumptions
    gap = setting.gap()
    gap = measured(setting.case).geometry.pad_gap_mm if gap is None else gap
    return {
        "plane": a.plane, "edges": "ring fixed" if a.fix_ring else "free", "force": a.force,
        "max_travel_mm": setting.travel_mm, "gap_mm": gap,
        "dic_origin": "moving pad's inner-edge midpoint" if setting.placed else "authors'",
    }  # fmt: skip


def run_fit(setting: Setting, label: str, held=None, held_from=None, log=print) -> dict:
    """Fit one setting; one progress line; the row of the table."""
    extensometer = problem(setting, held)
    result = fit(extensometer, START[setting.case])
    frames, mesh = extensometer.frames, extensometer.mesh
    row = {
        "label": label,
        "case": setting.case,
        "assumptions": describe(setting),
        "frames": list(frames.indices),
        "last_travel_mm": float(-frames.pad_ux_mm[-1]),
        "names": ["E", "nu"] if held is None else ["E_keloid", "nu_keloid"],
        "E_n_per_mm": float(result.x[0]),
        "nu": float(result.x[1]),
        "mu_n_per_mm": float(result.x[0] / (2 * (1 + result.x[1]))),
        "nu_at_bound": bool(min(abs(result.x[1] - b) for b in NU_BOUNDS) < 1e-6),
        **result.measures,
        "evaluations": result.evaluations,
        "newton_per_frame": result.solution.newton,
        "seconds": result.seconds,
        "success": result.success,
        "forces_model_n": result.solution.force.tolist(),
        "forces_measured_n": frames.force_n.tolist(),
        "mesh": {"nodes": mesh.n_nodes, "triangles": mesh.n_triangles, **mesh.info},
    }
    if held is not None:
        row["held_skin"] = {"E_n_per_mm": held[0], "nu": held[1], "from": held_from}
    log(
        f"{setting.case} {setting.travel_mm:g} mm, {label}: E {result.x[0]:.5f} N/mm, "
        f"nu {result.x[1]:.4f}, J {row['cost']:.4g}, RMS {row['rms_displacement_mm']:.4f} mm / "
        f"{row['rms_force_n']:.4f} N, {result.seconds:.1f} s"
    )
    return row


def held_skin(setting: Setting, log=print) -> tuple[tuple, str]:
    """The skin's (E, nu) for a keloid fit: theirs on their assumptions, else our healthy
    fit under the same assumptions."""
    if setting.theirs:
        return authors.HELD_SKIN[setting.travel_mm], "authors' healthy fit (mesh tag 5)"
    row = run_fit(replace(setting, case="healthy"), "healthy skin to hold", log=log)
    return (row["E_n_per_mm"], row["nu"]), "our healthy fit, same assumptions"


def change_label(name: str, base: Setting, changed: Setting | None) -> str:
    """What a row changed, said for the direction it went (the baseline may be any)."""
    if name == "baseline":
        return "authors' assumptions" if base.theirs else "baseline (options)"
    if changed is None or name in ("frames", "project"):
        return VARIANTS[name]
    a = changed.assumptions
    return {
        "ring": "edge ring fixed" if a.fix_ring else "edges free",
        "plane": f"plane {a.plane}",
        "force": "reaction force" if a.force == "reaction" else "traction force",
        "gap": VARIANTS["gap"] if changed.placed else "pads of the .geo",
    }[name]


def run(setting: Setting, out: Path, names=tuple(VARIANTS), log=print) -> dict:
    """The baseline and each variant; writes ``authors.json`` and ``authors.md``."""
    rows, keloid_check = [], None
    plan = [("baseline", setting)] + [(n, variant(setting, n)) for n in names]
    for name, chosen in plan:
        label = change_label(name, setting, chosen)
        if chosen is None:
            log(f"{setting.case}: {label} is the baseline itself here; skipped")
            continue
        held, source = held_skin(chosen, log) if setting.case == "keloid" else (None, None)
        rows.append(run_fit(chosen, label, held, source, log))
        if name == "baseline" and setting.case == "keloid" and setting.theirs:
            theirs = authors.KELOID[setting.travel_mm][1]
            keloid_check = gradient_at(problem(chosen, held), theirs)
    document = {
        "source": authors.SOURCE,
        "case": setting.case,
        "travel_mm": setting.travel_mm,
        "mesh_size_mm": setting.mesh_size_mm,
        "authors": {
            "E_range_n_per_mm": authors.authors_range(setting.case, setting.travel_mm, "E"),
            "nu_range": authors.authors_range(setting.case, setting.travel_mm, "nu"),
            "per_mesh_tag": (authors.HEALTHY if setting.case == "healthy" else authors.KELOID)[
                setting.travel_mm
            ],
        },
        "fits": rows,
    }
    if keloid_check is not None:
        document["at_authors_keloid_value_tag1"] = keloid_check
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "authors.json", document)
    atomic_write_text(out / "authors.md", table(rows) + "\n")
    return document


def table(rows: list[dict]) -> str:
    """The markdown table: each assumption changed one at a time (keloid: the skin held)."""
    held = any("held_skin" in r for r in rows)
    lines = [
        "| case | assumption changed | frames (last travel) | E [N/mm] | E / baseline | nu "
        "| mu [N/mm] | J (Q + L^2/2) | RMS u [mm] | RMS f [N] | time [s] |"
        + (" skin held at (E, nu) |" if held else ""),
        "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if held else ""),
    ]
    base = rows[0]["E_n_per_mm"] if rows else 1.0
    for r in rows:
        skin = r.get("held_skin")
        lines.append(
            f"| {r['case']} | {r['label']} | {len(r['frames'])} ({r['last_travel_mm']:.2f} mm) "
            f"| {r['E_n_per_mm']:.5f} | {r['E_n_per_mm'] / base:.2f} | {r['nu']:.4f}"
            f"{' (bound)' if r['nu_at_bound'] else ''} | {r['mu_n_per_mm']:.5f} "
            f"| {r['cost']:.4g} ({r['cost_displacement']:.4g} + {r['cost_force']:.2g}) "
            f"| {r['rms_displacement_mm']:.4f} | {r['rms_force_n']:.4f} | {r['seconds']:.1f} |"
            + (f" {skin['E_n_per_mm']:.5f}, {skin['nu']:.4f} ({skin['from']}) |" if skin else "")
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------- command
def build_parser(prog: str = "python -m experiments.realskin.reproduce"):
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "The authors' plane-strain fit, then one assumption at a time.")
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument("--case", choices=("healthy", "keloid"), default="healthy")
    parser.add_argument(
        "--travel", type=float, choices=authors.TRAVELS_MM, default=3.0,
        help="frames up to this pad travel [mm] (their 3 or 2)",
    )  # fmt: skip
    parser.add_argument("--plane", choices=("strain", "stress"), default="strain")
    parser.add_argument("--fix-ring", action="store_true", help="hold the outer edges at 0")
    parser.add_argument("--force", choices=("traction", "reaction"), default="traction")
    parser.add_argument(
        "--gap", type=float, default=None,
        help="pad gap [mm] (default: the .geo's, with their DIC origin)",
    )  # fmt: skip
    parser.add_argument(
        "--mesh-size", type=float, default=1.0,
        help="element size at the pads [mm], 4x elsewhere",
    )  # fmt: skip
    parser.add_argument(
        "--variants", default=",".join(VARIANTS),
        help=f"comma list from {','.join(VARIANTS)}, or none",
    )  # fmt: skip
    return parser


def parse_variants(text: str) -> tuple[str, ...]:
    """'ring,plane' -> ('ring', 'plane'); 'none' -> ()."""
    from experiments.command.options import UsageError

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if names == ("none",):
        return ()
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or not names:
        raise UsageError(
            f"--variants takes a comma list from {', '.join(VARIANTS)} or none, got {text!r}"
        )
    return names


def work(args) -> int:
    from experiments.command.options import UsageError, check_output_dir

    out = check_output_dir(args.out)
    names = parse_variants(args.variants)
    if not (np.isfinite(args.mesh_size) and 0.3 <= args.mesh_size <= 4.0):
        raise UsageError(f"--mesh-size must lie in 0.3-4 mm, got {args.mesh_size}")
    if args.gap is not None and not (np.isfinite(args.gap) and 20.0 <= args.gap <= 60.0):
        raise UsageError(f"--gap must lie in 20-60 mm, got {args.gap}")
    assumptions = Assumptions(args.plane, args.fix_ring, args.force)
    setting = Setting(
        args.case, args.travel, assumptions, gap_mm=args.gap, mesh_size_mm=args.mesh_size
    )
    try:
        problem(setting, authors.HELD_SKIN[args.travel])  # the DIC lies in the mesh
    except ValueError as error:
        raise UsageError(f"--gap {args.gap:g} mm: {error}" if args.gap else str(error)) from None
    run(setting, out, names)
    return 0


main = Command("experiments.realskin.reproduce", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
