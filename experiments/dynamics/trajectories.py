"""Marker trajectories of the phantom under a probe step: the dynamic inverse's data.

A probe steps onto the phantom's skin at t = 0 and a 1 kHz camera rig records the
markers for 40 ms (``simulate_dynamic``; the truth is integrated by CVODES, not by the
scheme the inverse uses). ``build_dynamic_problem`` turns such a dataset (format v1
with ``times`` and ``outer_series``) into a ``DynamicProblem``. The choice of truth and
window is explained in ``experiments.dynamics.inverse``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from experiments.data.dataset import Dataset
from experiments.phantom.forehead import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from experiments.problem.fitting import FitSettings, dataset_loads, rest_geometry
from solvers.dynamic.problem import DynamicProblem, TimeGrid, step_profile, trajectory_case
from solvers.dynamic.scheme import TrapezoidalScheme
from solvers.forward.equilibrium import EquilibriumSolver
from solvers.inverse.space import ParameterSpace
from solvers.transient.profiles import Load, ramp_load
from solvers.transient.sundials import integrate_casadi
from symbolic.constraints import BoundaryConditions
from symbolic.model import TissueModel

DYNAMIC_TRUTH = {**TRUE_PARAMETERS, "gamma": 0.1}
"""Truth of the dynamic experiment: the phantom's, with gamma near critical damping."""
DYNAMIC_PHANTOM = PhantomSettings(forces=(0.25,))
"""One probe load of 0.25 N (in the linear model a second force adds no new shape)."""
DEFAULT_FRAMES = 1e-3 * np.arange(1, 41)
"""Frame times [s]: 1 kHz for 40 ms after the load onset."""
DEFAULT_SUBSTEPS = 2
"""Scheme steps per frame interval (0.5 ms): bias below 0.5 standard errors."""
DYNAMIC_NAMES = ("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")
"""Estimated parameters."""
RAMP_KEY = "load_ramp_s"
"""Dataset ``extra`` key of the load's rise time [s] (absent: a step at t = 0)."""


def _profile(ramp_s: float | None):
    return step_profile if not ramp_s else ramp_load(np.zeros((1, 3)), ramp_s).profile


def truth_trajectories(
    model: TissueModel, force: np.ndarray, frames, integrator="cvodes", substeps=8, ramp_s=None
) -> np.ndarray:
    """Displacements B_free - B0_free at the frames from rest, (T, n_free, 3) [mm].

    ``integrator`` "cvodes": SUNDIALS BDF at rtol 1e-10 (independent of the fit's
    scheme); "scheme": the trapezoidal scheme with ``substeps`` per frame interval.
    """
    frames = np.asarray(frames, dtype=float)
    profile = _profile(ramp_s)
    if integrator == "cvodes":
        times = frames if frames[0] == 0 else np.concatenate([[0.0], frames])
        path = integrate_casadi(model, Load(force, profile), times, rtol=1e-10, atol=1e-12)
        return path[-frames.size :]
    if integrator != "scheme":
        raise ValueError(f"integrator must be 'cvodes' or 'scheme', got {integrator!r}")
    grid = TimeGrid(frames, substeps)
    scale = np.array([float(profile(t)) for t in grid.nodes])
    loads = scale[:, None] * np.asarray(force).T.reshape(-1)[None, :]
    run = TrapezoidalScheme(model, (), grid).run(loads, [])
    states = run.displacements[grid.frame_nodes]
    return states.reshape(frames.size, 3, -1).transpose(0, 2, 1)


def simulate_dynamic(
    noise_mm: float = 0.02,
    seed: int = 0,
    times=None,
    *,
    parameters: dict | None = None,
    phantom: PhantomSettings | None = None,
    integrator: str = "cvodes",
    substeps: int = 8,
    ramp_s: float | None = None,
    missing_fraction: float = 0.0,
    occlusion_radius_mm: float = 2.0,
) -> Dataset:
    """A dataset v1 with marker trajectories of the phantom under a probe load from rest.

    Parameters
    ----------
    noise_mm : float
        Standard deviation of every marker coordinate [mm]: rest markers, every frame
        and the steady-state capture (``outer_loaded``) each get their own noise.
    seed : int
        Random seed.
    times : array_like, optional
        Frame times [s] (default ``DEFAULT_FRAMES``, 1 kHz for 40 ms).
    parameters : dict, optional
        Truth (default ``DYNAMIC_TRUTH``).
    phantom : PhantomSettings, optional
        Geometry, markers and forces (default ``DYNAMIC_PHANTOM``, one 0.25 N load).
    integrator : {"cvodes", "scheme"}
        How the truth is integrated (see ``truth_trajectories``).
    substeps : int
        Steps per frame interval of the "scheme" integrator.
    ramp_s : float, optional
        Rise time of the load [s] (stored as ``extra["load_ramp_s"]``); default a step.
    missing_fraction : float
        Fraction of markers lost at random in each frame.
    occlusion_radius_mm : float
        Markers closer than this to the contact are hidden in every frame [mm].
    """
    phantom = phantom or DYNAMIC_PHANTOM
    frames = DEFAULT_FRAMES if times is None else np.asarray(times, dtype=float)
    values = tuple(sorted((parameters or DYNAMIC_TRUTH).items()))
    clean = _clean_measurement(phantom, values, tuple(frames), integrator, substeps, ramp_s)
    rng = np.random.default_rng(seed)
    shape = phantom.markers
    rest = clean["rest"]
    series, loaded = [], []
    for path, steady, contact in zip(clean["series"], clean["steady"], clean["contacts"]):
        hidden = np.linalg.norm(rest - contact, axis=1) < occlusion_radius_mm
        moved = path + rng.normal(0.0, noise_mm, path.shape)
        steady = steady + rng.normal(0.0, noise_mm, steady.shape)
        moved[:, hidden] = np.nan
        moved[rng.random(moved.shape[:2]) < missing_fraction] = np.nan
        steady[hidden] = np.nan
        series.append(moved.reshape((frames.size, *shape, 3)))
        loaded.append(steady.reshape((*shape, 3)))
    return Dataset(
        outer_rest=(rest + rng.normal(0.0, noise_mm, rest.shape)).reshape((*shape, 3)),
        inner_rest=clean["inner"].reshape((*shape, 3)),
        forces=clean["forces"],
        contacts=clean["contacts"],
        outer_loaded=np.stack(loaded),
        noise_mm=float(noise_mm),
        probe_radius=np.full(len(clean["forces"]), phantom.probe_radius),
        times=frames,
        outer_series=np.stack(series),
        extra={} if not ramp_s else {RAMP_KEY: np.array(float(ramp_s))},
    )


@lru_cache(maxsize=8)
def _clean_measurement(phantom, parameters, frames, integrator, substeps, ramp_s) -> dict:
    """Noise-free markers of the truth: rest, trajectories, steady state (cached)."""
    frames = np.array(frames)
    truth = forehead_model(phantom, dict(parameters))
    uv = marker_uv(phantom)
    rows = truth.volume.collocation(truth.volume.outer_params(uv))
    rest = rows @ truth.rest
    loads = probe_loads(truth, phantom)
    series, steady, contacts = [], [], []
    for load in loads:
        force = truth.generalized_force(load)
        path = truth_trajectories(truth, force, frames, integrator, substeps, ramp_s)
        series.append(rest[None] + np.einsum("mn,tnc->tmc", rows[:, truth.free].toarray(), path))
        steady.append(rows @ EquilibriumSolver(truth).solve(force).positions)
        contacts.append(truth.volume.evaluate(truth.volume.outer_params(load.uv[None]))[0])
    inner = truth.volume.collocation(np.column_stack([uv, np.zeros(len(uv))])) @ truth.rest
    return {
        "rest": rest,
        "inner": inner,
        "series": series,
        "steady": steady,
        "contacts": np.array(contacts),
        "forces": np.array([load.force for load in loads]),
    }


def build_dynamic_problem(
    dataset: Dataset,
    names=DYNAMIC_NAMES,
    substeps: int = DEFAULT_SUBSTEPS,
    cases: list[int] | None = None,
    start: dict | None = None,
    settings: FitSettings | None = None,
) -> DynamicProblem:
    """The dynamic inverse problem of a dataset's trajectories (geometry as ``fitting``).

    The load is a step at t = 0 unless ``extra["load_ramp_s"]`` gives a rise time.
    """
    if dataset.times is None or dataset.outer_series is None:
        raise ValueError(
            "the dataset has no trajectories (times, outer_series); "
            "simulate one with experiments.dynamics.inverse.simulate_dynamic"
        )
    settings = settings or FitSettings(names=tuple(names))
    volume, uv = rest_geometry(dataset, settings)
    boundary = BoundaryConditions(fix_lateral=settings.fix_lateral)
    model = TissueModel(volume, dict(settings.fixed or {}), boundary)
    loads = dataset_loads(dataset, volume)
    ramp = dataset.extra.get(RAMP_KEY)
    profile = _profile(None if ramp is None else float(ramp))
    frames = dataset.times.size
    problem_cases = [
        trajectory_case(
            model,
            loads[k],
            dataset.outer_series[k].reshape(frames, -1, 3),
            uv,
            profile,
            label=f"{np.linalg.norm(dataset.forces[k]):.3g} N",
        )
        for k in (range(dataset.n_loads) if cases is None else cases)
    ]
    space = ParameterSpace.create(tuple(names), start)
    return DynamicProblem(
        model, problem_cases, space, dataset.times, substeps, dataset.noise_mm, rest_noise=True
    )
