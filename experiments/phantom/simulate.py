"""Synthetic datasets from the forehead phantom (``dvs simulate``).

The truth is the phantom model (``experiments.phantom.forehead``). Markers are
material points of its skin; the dataset holds what a camera rig would
measure: marker positions before and under each load, with Gaussian noise,
markers hidden under the probe and a few missing at random. The geometry the
inverse sees is rebuilt from those markers, so a fit on a simulated dataset
also carries the (small) error of re-fitting the rest shape.

``simulate_with_effects`` hides effects the dataset does not declare (``--effect
NAME[=VALUE]``), on the paper's design or the diagnosis design
(``experiments.phantom.designs``); with no effects it gives ``simulate``'s dataset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.command.options import (
    Command,
    UsageError,
    add_noise_seed_arguments,
    check_noise_seed,
    check_output_file,
    make_parser,
    path_argument,
    plural,
    write_dataset,
)
from experiments.data.dataset import Dataset
from experiments.phantom.designs import DESIGNS, design_loads, design_options, press_loads
from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver
from solvers.inverse.problem import InverseProblem, observation_case
from solvers.inverse.space import ParameterSpace
from symbolic.effects.library import EFFECT_NAMES, make_effect
from symbolic.loads import ProbeForce

TRUTH_NAMES = ("alpha_u", "alpha_v", "alpha_w")
"""Parameters of the truth problem that evaluates the phantom with effects."""


@dataclass(frozen=True)
class SimulationSettings:
    """What the synthetic measurement adds to the truth.

    Attributes
    ----------
    noise_mm : float
        Standard deviation of each marker coordinate [mm], rest and loaded.
    seed : int
        Random seed.
    missing_fraction : float
        Fraction of markers lost at random in each loaded capture.
    occlusion_radius_mm : float
        Markers closer than this to the contact are hidden by the probe [mm].
    """

    noise_mm: float = 0.02
    seed: int = 0
    missing_fraction: float = 0.03
    occlusion_radius_mm: float = 2.0

    def __post_init__(self) -> None:
        if not 0 <= self.noise_mm < np.inf:
            raise ValueError(f"noise must be a finite number >= 0 mm, got {self.noise_mm}")
        if not 0 <= self.missing_fraction < 0.5:
            raise ValueError("missing_fraction must lie in [0, 0.5)")


def measured_dataset(
    rest: np.ndarray,
    inner: np.ndarray,
    positions: list,
    forces: np.ndarray,
    contacts: np.ndarray,
    measurement: SimulationSettings,
    shape: tuple[int, int],
    probe_radius: np.ndarray | None = None,
) -> Dataset:
    """What the camera rig records of true marker positions.

    Parameters
    ----------
    rest, inner : numpy.ndarray
        True rest markers and inner-surface points, (U V, 3) [mm].
    positions : list of numpy.ndarray
        True marker positions under every load, each (U V, 3) [mm].
    forces, contacts : numpy.ndarray
        Declared force vectors [N] and contact points [mm], (K, 3).
    measurement : SimulationSettings
        Noise, occlusion radius, missing fraction and seed.
    shape : tuple of int
        Marker grid (U, V).
    probe_radius : numpy.ndarray, optional
        Declared probe radius of every load [mm] (default 0: point forces).
    """
    rng = np.random.default_rng(measurement.seed)
    loaded = []
    for position, contact in zip(positions, contacts):
        observed = position + rng.normal(0.0, measurement.noise_mm, rest.shape)
        hidden = np.linalg.norm(rest - contact, axis=1) < measurement.occlusion_radius_mm
        hidden |= rng.random(len(rest)) < measurement.missing_fraction
        observed[hidden] = np.nan
        loaded.append(observed.reshape(shape + (3,)))
    noisy_rest = rest + rng.normal(0.0, measurement.noise_mm, rest.shape)
    radius = np.zeros(len(forces)) if probe_radius is None else np.asarray(probe_radius, float)
    return Dataset(
        outer_rest=noisy_rest.reshape(shape + (3,)),
        inner_rest=np.asarray(inner).reshape(shape + (3,)),
        forces=np.asarray(forces, dtype=float),
        contacts=np.asarray(contacts, dtype=float),
        outer_loaded=np.stack(loaded),
        noise_mm=float(measurement.noise_mm),
        probe_radius=radius,
    )


def _markers(truth, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True rest markers and the inner-surface points below them, (U V, 3) [mm]."""
    rest = truth.volume.collocation(truth.volume.outer_params(uv)) @ truth.rest
    inner = truth.volume.collocation(np.column_stack([uv, np.zeros(len(uv))])) @ truth.rest
    return rest, inner


def _contacts(truth, loads) -> np.ndarray:
    """The skin point of every load's contact (u, v), (K, 3) [mm]."""
    return np.array(
        [truth.volume.evaluate(truth.volume.outer_params(ld.uv[None]))[0] for ld in loads]
    )


def simulate(
    phantom: PhantomSettings | None = None,
    measurement: SimulationSettings | None = None,
    parameters: dict[str, float] | None = None,
    model=None,
) -> Dataset:
    """A dataset v1 from the phantom (or from a given truth ``model``).

    Parameters
    ----------
    phantom : PhantomSettings
        Geometry, markers and forces.
    measurement : SimulationSettings
        Noise, missing markers, occlusion.
    parameters : dict, optional
        True parameters (default ``TRUE_PARAMETERS``).
    model : TissueModel, optional
        A ready truth model (for example one with an undeclared effect).
    """
    phantom = phantom or PhantomSettings()
    truth = model or forehead_model(phantom, parameters or TRUE_PARAMETERS)
    uv = marker_uv(phantom)
    markers = truth.volume.collocation(truth.volume.outer_params(uv))
    solver = EquilibriumSolver(truth)
    loads = probe_loads(truth, phantom)
    positions = [markers @ solver.solve(truth.generalized_force(ld)).positions for ld in loads]
    rest, inner = _markers(truth, uv)
    return measured_dataset(
        rest,
        inner,
        positions,
        np.array([ld.force for ld in loads]),
        _contacts(truth, loads),
        measurement or SimulationSettings(),
        phantom.markers,
        np.full(len(loads), phantom.probe_radius),
    )


def parse_effect_specs(specs, n_cases: int = 2) -> dict[str, float]:
    """``["rigid_motion=0.05", "bending"]`` -> {name: magnitude} (defaults for bare names).

    Parameters
    ----------
    specs : list of str
        ``NAME`` or ``NAME=VALUE``.
    n_cases : int
        Load cases of the design (per-case effects' ranges depend on it).

    Raises
    ------
    ValueError
        For an unknown name, a repeated name, a value that is not a finite number, or a
        magnitude outside the effect's own bounds (``Effect.magnitude_range``).
    """
    effects: dict[str, float] = {}
    for spec in specs or []:
        name, _, value = str(spec).partition("=")
        name = name.strip()
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r}; choose from {', '.join(EFFECT_NAMES)}")
        if name in effects:
            raise ValueError(f"effect {name} given twice")
        effect = make_effect(name)
        if not value.strip():
            effects[name] = effect.default_magnitude
            continue
        try:
            magnitude = float(value)
        except ValueError:
            raise ValueError(f"--effect {spec!r}: the value must be a number") from None
        low, high = effect.magnitude_range(n_cases)
        if not low <= magnitude <= high:
            unit = "" if effect.magnitude_unit in ("", "1") else f" {effect.magnitude_unit}"
            raise ValueError(
                f"--effect {spec!r}: {name} takes {low:.4g} to {high:.4g}{unit} "
                f"(realistic: {effect.default_magnitude:g})"
            )
        effects[name] = magnitude
    return effects


def effect_table(n_cases: int = 2) -> str:
    """Every effect's realistic magnitude and admissible range, for ``--help``."""
    lines = []
    for name in EFFECT_NAMES:
        effect = make_effect(name)
        low, high = effect.magnitude_range(n_cases)
        unit = "" if effect.magnitude_unit in ("", "1") else f" {effect.magnitude_unit}"
        lines.append(f"  {name}={effect.default_magnitude:g}  ({low:.3g} to {high:.3g}{unit})")
    return "\n".join(lines)


def _truth_states(truth, loads, uv, effects: dict[str, float]) -> list[np.ndarray]:
    """Marker positions under every load of the phantom with the effects switched on."""
    from solvers.diagnosis.extended import ExtendedProblem

    rest = truth.volume.collocation(truth.volume.outer_params(uv)) @ truth.rest
    cases = [observation_case(truth, load, rest, uv) for load in loads]
    space = ParameterSpace.create(TRUTH_NAMES, {n: TRUE_PARAMETERS[n] for n in TRUTH_NAMES})
    base = InverseProblem(truth, cases, space)
    active = [make_effect(n) for n in EFFECT_NAMES if n in effects and n != "contact_patch"]
    problem = ExtendedProblem(base, loads, active)
    p = problem.start()
    for effect in active:
        p[problem.slice_of(effect.name)] = effect.true_parameters(effects[effect.name], len(loads))
    r, _, _ = problem.evaluate(p)
    m = len(uv)
    return [rest + r[3 * m * k : 3 * m * (k + 1)].reshape(3, m).T for k in range(len(loads))]


def simulate_with_effects(
    effects: dict[str, float] | None = None,
    noise_mm: float = 0.02,
    seed: int = 0,
    missing_fraction: float = 0.03,
    phantom: PhantomSettings | None = None,
    contacts=None,
    tilt_deg: float = 0.0,
    presses=None,
) -> Dataset:
    """A dataset from the phantom with undeclared effects (``dvs simulate --effect``).

    The measurement is that of ``simulate`` (same noise on rest and loaded markers,
    occlusion by the probe, random missing markers, same random stream): with no
    effects the two give the same dataset. The dataset declares the nominal loads
    only: point forces along the inward normal at the nominal contact, no probe radius.

    Parameters
    ----------
    effects : dict
        Effect name -> magnitude (``Effect.default_magnitude`` units; see
        ``parse_effect_specs``). ``contact_patch`` is simulated with the
        project's own Gaussian probe (``symbolic.loads.ProbeForce``) of that
        radius [mm], not with the library's expansion.
    noise_mm : float
        Standard deviation of every marker coordinate [mm].
    seed : int
        Random seed.
    missing_fraction : float
        Fraction of loaded markers lost at random.
    contacts : sequence of (u, v), optional
        Probe contact points on the skin (``designs.design_loads``). Default: the
        phantom's single central contact; ``DIAGNOSIS_CONTACTS`` is the diagnosis design.
    tilt_deg : float
        Tilt of the second force at every contact [deg].
    presses : list of (contact [mm], force [N]), optional
        A design file's presses (``designs.press_loads``); replaces ``contacts``.
    """
    effects = dict(effects or {})
    unknown = set(effects) - set(EFFECT_NAMES)
    if unknown:
        raise ValueError(f"unknown effects {sorted(unknown)}; choose from {EFFECT_NAMES}")
    phantom = phantom or PhantomSettings()
    measurement = SimulationSettings(
        noise_mm=noise_mm, seed=seed, missing_fraction=missing_fraction
    )
    truth = forehead_model(phantom, TRUE_PARAMETERS)
    uv = marker_uv(phantom)
    if presses is not None:
        declared = press_loads(truth, presses)
    else:
        declared = design_loads(truth, phantom, contacts, tilt_deg)
    loads = declared
    if effects.get("contact_patch", 0.0) > 0:
        radius = float(effects["contact_patch"])
        loads = [ProbeForce(ld.force, radius, uv=ld.uv) for ld in declared]
    rest, inner = _markers(truth, uv)
    return measured_dataset(
        rest,
        inner,
        _truth_states(truth, loads, uv, effects),
        np.array([ld.force for ld in declared]),
        _contacts(truth, declared),
        measurement,
        phantom.markers,
    )


# ------------------------------------------------------------------- dvs simulate
def add_simulation_arguments(parser) -> None:
    """``--noise MM``, ``--seed N`` and ``--out FILE.npz`` of a command that writes a
    simulated dataset (``dvs simulate``, ``dvs study outoflibrary``)."""
    add_noise_seed_arguments(parser)
    parser.add_argument("--out", type=path_argument, required=True, help="output .npz file")


def check_simulation_arguments(args) -> None:
    """Check the options of ``add_simulation_arguments`` before any work."""
    check_noise_seed(args)
    check_output_file(args.out, ".npz")


def build_parser(prog: str = "python -m experiments.phantom.simulate"):
    """The options of ``dvs simulate``."""
    parser = make_parser(prog, "Write a synthetic dataset from the forehead phantom.")
    parser.epilog = (
        "effects: a bare --effect NAME uses the realistic magnitude; the range is the\n"
        "effect's own bounds (paper design):\n" + effect_table()
    )
    parser.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[=VALUE]",
        help="an effect the dataset does not declare (repeatable; a bare NAME uses its "
        "realistic magnitude, docs/effects.md)",
    )
    parser.add_argument(
        "--design",
        default="paper",
        help=f"where to press: {' or '.join(DESIGNS)}, or a design.json of dvs design",
    )
    add_simulation_arguments(parser)
    return parser


def work(args) -> int:
    """``dvs simulate [--effect NAME[=VALUE] ...] --out FILE.npz``."""
    check_simulation_arguments(args)
    options = design_options(args.design)
    if "presses" in options:
        n_cases = len(options["presses"])
    else:
        n_cases = len(options.get("contacts", [None])) * len(PhantomSettings().forces)
    effects = parse_effect_specs(args.effect, n_cases)
    try:
        dataset = simulate_with_effects(effects, noise_mm=args.noise, seed=args.seed, **options)
    except EquilibriumError:
        raise UsageError(
            f"the phantom has no equilibrium with {effects}; lower the effect magnitudes"
        ) from None
    return write_dataset(
        args.out,
        dataset,
        f"{plural(dataset.n_loads, 'load case')} ({args.design} design), "
        f"{dataset.outer_rest.shape[0]}x{dataset.outer_rest.shape[1]} markers, "
        f"noise {args.noise} mm, seed {args.seed}",
    )


main = Command("experiments.phantom.simulate", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
