"""From a dataset to an inverse problem, a fit and ``result.json`` (``dvs fit``).

The rest geometry is rebuilt from the dataset: the volume is fitted to the
(outer_rest, inner_rest) grid, and each marker's material coordinates (u, v)
are its projection onto the fitted skin.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.plausibility import dataset_warnings
from experiments.problem.surroundings import extend_grid, margin_rows
from solvers.diagnosis.verdict import fit_verdict
from solvers.inverse.identifiability import IdentifiabilityReport, analyse
from solvers.inverse.nested import NestedSolver
from solvers.inverse.problem import InverseProblem, control_point_case, observation_case
from solvers.inverse.result import InverseResult
from solvers.inverse.simultaneous import SimultaneousSolver
from solvers.inverse.space import ParameterSpace
from symbolic.constraints import BoundaryConditions
from symbolic.continuum_model import ENERGIES
from symbolic.loads import PointForce, ProbeForce
from symbolic.model import TissueModel
from symbolic.volume import VolumeSpline

DEFAULT_NAMES = ("alpha_u", "alpha_v", "alpha_w", "mu", "gamma")
"""The paper estimated mu and alpha; gamma is included to show it is not identifiable."""

ENERGY_NAMES = {
    "dnurbs": DEFAULT_NAMES,
    "linear-elastic": ("E", "nu"),
    "neo-hookean": ("E", "nu"),
    "exponential": ("E", "nu", "k1"),
    "fibres": ("E", "nu", "kf1", "fibre_angle"),
}
"""What ``dvs fit`` estimates by default for each ``--energy``."""


@dataclass(frozen=True)
class FitSettings:
    """How a dataset becomes an inverse problem.

    Attributes
    ----------
    names : tuple of str
        Estimated parameters.
    grid : tuple of int or None
        Control grid (M, N, L) of the volume; None follows the data: up to 9 control
        points along u and v, no more than the markers there (``control_grid``), L = 2.
        A finer grid refines the geometry fitted on the markers (``rest_geometry``).
    degrees : tuple of int
        Degrees of the volume, lowered where the grid has too few points for them.
    objective : {"markers", "control_points"}
        Compare marker positions (default) or, as the paper did, the control
        points of a spline fitted to the measured loaded skin.
    fix_lateral : bool
        Also fix the lateral ring of control points.
    fixed : dict
        Values of parameters that are not estimated.
    energy : {"dnurbs", "linear-elastic", "neo-hookean", "exponential", "fibres"}
        The base model: the paper's eq. (18), isotropic linear elasticity, the
        compressible neo-Hookean energy (``symbolic.continuum_model``, parameters E
        and nu), the neo-Hookean with strain stiffening (also k1 and k2, eq. C10) or that
        with a fibre family (also kf1, kf2 and fibre_angle, eq. C13).
    margin : float
        Width [mm] of the band of tissue beyond the markers that the volume also
        covers (``experiments.problem.surroundings``); 0, the default, ends the volume at the
        markers as the paper did. Only with ``objective="markers"``.
    start : dict, optional
        Start values of estimated parameters by name (default the paper's starts,
        ``ParameterSpace.create``); step 0 passes its estimate.
    """

    names: tuple[str, ...] = DEFAULT_NAMES
    grid: tuple[int, int, int] | None = None
    degrees: tuple[int, int, int] = (3, 3, 1)
    objective: str = "markers"
    fix_lateral: bool = False
    fixed: dict | None = None
    energy: str = "dnurbs"
    margin: float = 0.0
    start: dict | None = None

    def __post_init__(self) -> None:
        if self.objective not in ("markers", "control_points"):
            raise ValueError("objective must be 'markers' or 'control_points'")
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(f"margin must be a length >= 0 mm, got {self.margin!r}")
        if self.margin > 0 and self.objective != "markers":
            raise ValueError("a margin needs objective 'markers' (control points follow the grid)")
        if self.energy not in ENERGIES:
            raise ValueError(f"energy must be one of {sorted(ENERGIES)}, got {self.energy!r}")


DEFAULT_GRID = (9, 9, 2)
"""The paper's control grid, used where the markers allow it."""


def control_grid(
    markers: tuple[int, int], settings: FitSettings, rows: int = 0
) -> tuple[tuple, tuple]:
    """The control grid and degrees of a fit to a U x V marker grid.

    Without ``settings.grid`` the grid follows the data: min(9, U) x min(9, V) x 2 (a
    tensor-product fit of U values needs at most U control points), plus the ``rows``
    added on each side by a margin (``model_grid``). A given grid may be finer than
    the markers: the geometry is then fitted on the markers' grid and refined
    (``rest_geometry``). Each degree is at most the grid's points minus one along its
    direction.
    """
    (u_count, v_count), chosen = markers, settings.grid
    if chosen is None:
        extra = 2 * int(rows)
        chosen = (
            min(DEFAULT_GRID[0], u_count) + extra,
            min(DEFAULT_GRID[1], v_count) + extra,
            DEFAULT_GRID[2],
        )
    degrees = tuple(min(d, g - 1) for d, g in zip(settings.degrees, chosen))
    return tuple(chosen), degrees


def model_grid(dataset: Dataset, settings: FitSettings) -> tuple[tuple, tuple]:
    """The control grid and degrees of the volume ``rest_geometry`` builds."""
    rows = margin_rows(dataset.outer_rest, settings.margin)
    return control_grid(dataset.marker_shape, settings, rows)


def rest_geometry(dataset: Dataset, settings: FitSettings) -> tuple[VolumeSpline, np.ndarray]:
    """Volume fitted to the rest markers and inner surface; markers' (u, v).

    The rest surfaces, extended by ``settings.margin`` (``extend_grid``), are fitted
    on at most the markers' grid (linear through the thickness); a finer or
    higher-degree grid is that geometry refined (``VolumeSpline.refined``): the shape
    stays the measured one and only the space of displacements grows.
    """
    rows = margin_rows(dataset.outer_rest, settings.margin)
    chosen, degrees = control_grid(dataset.marker_shape, settings, rows)
    outer = extend_grid(dataset.outer_rest, settings.margin, rows)
    inner = extend_grid(dataset.inner_rest, settings.margin, rows)
    (u_count, v_count) = outer.shape[:2]
    fitted = (min(chosen[0], u_count), min(chosen[1], v_count), 2)
    fitted_degrees = tuple(min(d, g - 1) for d, g in zip(degrees[:2], fitted)) + (1,)
    grid = np.stack([inner, outer], axis=2)
    volume, _ = VolumeSpline.fit(grid, fitted, fitted_degrees)
    if tuple(chosen) != fitted or tuple(degrees) != fitted_degrees:
        volume, _ = volume.refined(chosen, degrees)
    uv, _ = volume.project_to_outer(dataset.outer_rest.reshape(-1, 3))
    return volume, uv


def dataset_loads(dataset: Dataset, volume: VolumeSpline) -> list:
    """Point or probe loads (of ``dataset.probe_shape``) at the dataset's contacts
    (projected onto the skin)."""
    loads = []
    radius = dataset.probe_radius if dataset.probe_radius is not None else np.zeros(dataset.n_loads)
    shape = dataset.probe_shape or "gauss"
    contacts_uv, _ = volume.project_to_outer(dataset.contacts)  # one search for all
    for force, uv, r in zip(dataset.forces, contacts_uv, radius):
        probe = r > 0
        loads.append(
            ProbeForce(force, float(r), uv=uv, shape=shape) if probe else PointForce(force, uv=uv)
        )
    return loads


def build_problem(
    dataset: Dataset, settings: FitSettings | None = None, cases: list[int] | None = None
) -> InverseProblem:
    """The inverse problem of a dataset (all load cases jointly, or the chosen ones)."""
    settings = settings or FitSettings()
    model, uv = build_model(dataset, settings)
    return problem_on(model, uv, dataset, settings, cases)


def build_model(dataset: Dataset, settings: FitSettings) -> tuple[TissueModel, np.ndarray]:
    """The model of a dataset's rest geometry (``rest_geometry``) and the markers' (u, v).

    The load cases are not part of it: ``problem_on`` poses the inverse problem of any
    loads on it (step 0 of the loop fits several probe sizes on one model).
    """
    volume, uv = rest_geometry(dataset, settings)
    boundary = BoundaryConditions(fix_lateral=settings.fix_lateral)
    return ENERGIES[settings.energy](volume, dict(settings.fixed or {}), boundary), uv


def problem_on(
    model: TissueModel,
    uv: np.ndarray,
    dataset: Dataset,
    settings: FitSettings,
    cases: list[int] | None = None,
) -> InverseProblem:
    """The inverse problem of a dataset's load cases on a built model (``build_model``)."""
    loads = dataset_loads(dataset, model.volume)
    chosen = range(dataset.n_loads) if cases is None else cases
    problem_cases = []
    for k in chosen:
        label = f"{np.linalg.norm(dataset.forces[k]):.3g} N"
        observed = dataset.outer_loaded[k].reshape(-1, 3)
        if settings.objective == "markers":
            problem_cases.append(observation_case(model, loads[k], observed, uv, label=label))
        else:
            target = loaded_control_points(model, uv, observed)
            problem_cases.append(control_point_case(model, loads[k], target, label=label))
    space = ParameterSpace.create(settings.names, settings.start)
    rest_noise = settings.objective == "markers"
    return InverseProblem(model, problem_cases, space, dataset.noise_mm, rest_noise)


def loaded_control_points(model: TissueModel, uv: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Control points of the spline fitted to the measured loaded skin (paper's 'bend').

    Only the outer layer moves; it is the minimum-norm least-squares change
    from the rest shape that fits the observed markers.
    """
    seen = np.all(np.isfinite(observed), axis=1)
    outer = np.zeros(model.rest.shape[0], dtype=bool)
    outer.reshape(model.volume.shape)[:, :, -1] = True
    rows = model.volume.collocation(model.volume.outer_params(uv[seen])).toarray()
    shift = np.linalg.lstsq(rows[:, outer], observed[seen] - rows @ model.rest, rcond=None)[0]
    target = model.rest.copy()
    target[outer] += shift
    return target


SOLVERS = {"simultaneous": SimultaneousSolver, "nested": NestedSolver}

NESTED_UP_TO = 20
"""``auto`` chooses the nested method up to this many estimated parameters: each of its
evaluations solves one sensitivity per parameter, the simultaneous NLP does not."""


def choose_method(problem: InverseProblem) -> tuple[str, str]:
    """The method ``auto`` uses for a problem, and why (measured in docs/inverse.md)."""
    count = len(problem.names)
    if count > NESTED_UP_TO:
        return "simultaneous", (
            f"{count} parameters: the nested method would solve {count} sensitivities per "
            "evaluation"
        )
    if problem.model.componentwise and problem.model.is_linear(problem.names):
        return "nested", (
            "linear model: one scalar factorisation per evaluation, faster than the "
            "simultaneous NLP on every grid measured (33x33x4: 1.2 s against 10.9 s)"
        )
    if problem.model.is_linear(problem.names):
        return "nested", (
            "linear model coupling the components (continuum): one sparse LU per evaluation, "
            "faster than the simultaneous NLP where measured (17x17x4: 2.5 s against 5.7 s)"
        )
    return "nested", (
        "nonlinear model with few parameters: faster than the simultaneous NLP where "
        "measured (17x17x2 with k0 estimated: 6.2 s against 13.7 s)"
    )


def solve(problem: InverseProblem, method: str = "simultaneous", log=None) -> InverseResult:
    """Solve with one method by name ("simultaneous", "nested", "paper" or "auto").

    ``log`` receives progress lines of the slow paper-faithful method.
    """
    if method == "auto":
        method = choose_method(problem)[0]
    if method == "paper":
        from solvers.inverse.paperfaithful import PaperNestedSolver

        return PaperNestedSolver(problem, log=log).solve()
    if method not in SOLVERS:
        raise ValueError(f"unknown method {method!r}; use auto, simultaneous, nested or paper")
    return SOLVERS[method](problem).solve()


def result_document(
    problem: InverseProblem,
    result: InverseResult,
    report: IdentifiabilityReport,
    settings: FitSettings,
    warnings=(),
) -> dict:
    """The ``result.json`` document (schema dvs-result/1, docs/formats.md).

    ``warnings`` are the dataset's plausibility warnings; the verdict's own (a residual
    far above the noise) are added to them.
    """
    errors = problem.point_errors(result.states)
    every = np.concatenate(errors)
    rms = float(np.sqrt(np.mean(every**2)))
    verdict = fit_verdict(problem, result.states, rms, settings.objective)
    return {
        "schema": "dvs-result/1",
        "method": result.method,
        "success": bool(result.success),
        "parameters": {
            p.name: {
                "value": p.value,
                "std": p.std,
                "unit": p.unit,
                "identifiable": p.identifiable,
                "at_bound": p.at_bound,
                "note": p.note,
            }
            for p in report.parameters
        },
        "rms_mm": rms,
        "max_residual_mm": float(every.max()),
        "per_load_rms_mm": {
            case.label: float(np.sqrt(np.mean(e**2))) for case, e in zip(problem.cases, errors)
        },
        "cost": result.cost,
        "solver": {
            "status": result.status,
            "success": result.success,
            "iterations": result.iterations,
            "forward_solves": result.forward_solves,
            "wall_time_s": result.build_time_s + result.solve_time_s,
            "build_time_s": result.build_time_s,
        },
        "identifiability": {
            "singular_values": report.singular_values.tolist(),
            "rank": report.rank,
            "sigma_mm": report.sigma,
            "sigma_source": report.sigma_source,
            "correlation": report.correlation.tolist(),
        },
        "model": {
            "energy": problem.model.energy,
            "grid": list(problem.model.volume.shape),
            "degrees": list(problem.model.volume.basis.degrees),
            "boundary_conditions": {
                "fix_inner": problem.model.boundary.fix_inner,
                "fix_lateral": problem.model.boundary.fix_lateral,
            },
            "objective": settings.objective,
            "margin_mm": settings.margin,
            "fixed_parameters": {
                k: v for k, v in problem.model.parameters.items() if k not in problem.names
            },
        },
        "verdict": verdict.document(),
        "warnings": [*warnings, *verdict.warnings()],
    }


def write_fit_outputs(out, problem, result, document) -> None:
    """result.json plus the residual map and the measured-vs-fitted section."""
    from pathlib import Path

    from experiments.output.atomic import atomic_write_json
    from experiments.output.plots import plot_fitted_section, plot_residual_maps

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_residual_maps(
        problem, result.states, out / "residual_map.png", f"{result.method}: marker residuals"
    )
    plot_fitted_section(problem, result.states, out / "fitted_section.png")
    atomic_write_json(out / "result.json", document)


def fit_dataset(
    dataset: Dataset,
    settings: FitSettings | None = None,
    method: str = "simultaneous",
    log=None,
) -> tuple[InverseProblem, InverseResult, IdentifiabilityReport, dict]:
    """Build, solve, analyse; returns the pieces and the result.json document.

    ``log`` receives progress lines of the slow paper-faithful method.
    """
    settings = settings or FitSettings()
    start = time.perf_counter()
    problem = build_problem(dataset, settings)
    setup = time.perf_counter() - start
    requested = method
    method, reason = choose_method(problem) if method == "auto" else (method, "given")
    result = solve(problem, method, log)
    result.build_time_s += setup
    report = analyse(problem, result.x)
    document = result_document(problem, result, report, settings, dataset_warnings(dataset))
    document["method_choice"] = {"requested": requested, "reason": reason}
    return problem, result, report, document
