"""What marker trajectories can tell, against static data (MODEL.md section 4).

The same report as ``solvers.identifiability.analyse``, with the sensitivity matrix of
the dynamic residual, S = dr/dx, from the exact forward sensitivities of the
trapezoidal scheme (``solvers.dynamic_scheme``):

- singular values of S with relatively scaled columns (x |x|) and the numerical rank;
- parameters without influence (zero column) flagged, never given a standard error;
- parameters at a bound flagged;
- standard errors sigma^2 (S^T S)^-1, or the sandwich
  sigma^2 (S^T S)^-1 S^T (I + P P^T) S (S^T S)^-1 when the rest markers are noisy:
  every frame of every case shares its marker's rest noise (``rest_noise_map``).

Static data leave mu and gamma without influence (they drop out of the steady state of
eq. 22); trajectories of the transient give them finite standard errors.
``contrast`` puts the two reports side by side.
"""

from __future__ import annotations

import numpy as np

from solvers.dynamic import DynamicProblem
from solvers.dynamic_nested import DynamicNestedSolver
from solvers.identifiability import (
    BOUND_TOLERANCE,
    INFLUENCE_TOLERANCE,
    IdentifiabilityReport,
    ParameterReport,
)
from solvers.problem import DYNAMIC_ONLY, ParameterSpace
from symbolic.model import PARAMETERS


def analyse_dynamic(
    problem: DynamicProblem, x: np.ndarray, sigma: float | None = None
) -> IdentifiabilityReport:
    """Identifiability and uncertainty of a dynamic estimate ``x`` (natural units).

    Parameters
    ----------
    problem : DynamicProblem
        The problem that was solved.
    x : numpy.ndarray
        The estimate.
    sigma : float, optional
        Noise standard deviation [mm]; default ``problem.noise_mm`` or estimated
        as sqrt(RSS / (m - p)).
    """
    space = problem.space
    x = np.asarray(x, dtype=float)
    z = space.to_internal(x)
    residual, jac_z = DynamicNestedSolver(problem).evaluate(z)
    sensitivity = jac_z / space.natural_derivative(z)[None, :]
    return report_from_sensitivity(
        space, x, residual, sensitivity, sigma, problem.noise_mm, problem.rest_noise_map(), False
    )


def report_from_sensitivity(
    space: ParameterSpace,
    x: np.ndarray,
    residual: np.ndarray,
    sensitivity: np.ndarray,
    sigma: float | None = None,
    noise_mm: float | None = None,
    rest_map=None,
    static: bool = False,
) -> IdentifiabilityReport:
    """The identifiability report from a residual and its sensitivity dr/dx.

    Parameters
    ----------
    space : ParameterSpace
        Names, bounds and scaling of the parameters.
    x : numpy.ndarray
        The estimate (natural units).
    residual : numpy.ndarray
        r at x, (m,) [mm].
    sensitivity : numpy.ndarray
        dr/dx, (m, p) [mm per unit of x].
    sigma, noise_mm : float, optional
        Noise standard deviation [mm] given, or the dataset's; else estimated.
    rest_map : scipy.sparse matrix, optional
        P of the shared rest-marker noise (sandwich covariance).
    static : bool
        True for static data: a non-influential mu or gamma is then "not
        identifiable from static data".
    """
    scale = np.where(space.log_scaled, np.abs(x), space.linear_scale)
    scaled = sensitivity * scale[None, :]
    norms = np.linalg.norm(scaled, axis=0)
    influential = norms > INFLUENCE_TOLERANCE * max(norms.max(), 1e-300)
    singular = np.linalg.svd(scaled, compute_uv=False)
    rank = int(np.sum(singular > 1e-10 * max(singular.max(), 1e-300)))
    at_bound = _at_bound(space, x)
    estimable = influential & ~at_bound
    m, p = residual.size, int(estimable.sum())
    dof = max(m - p, 1)
    if sigma is not None:
        source = "given"
    elif noise_mm is not None:
        sigma, source = float(noise_mm), "given"
    else:
        sigma, source = float(np.sqrt(residual @ residual / dof)), "estimated"
    std = np.full(len(x), np.nan)
    correlation = np.full((len(x), len(x)), np.nan)
    collinear = np.zeros(len(x), dtype=bool)
    if p:
        sub_singular = np.linalg.svd(scaled[:, estimable], compute_uv=False)
        if sub_singular.min() > 1e-10 * sub_singular.max():
            covariance = sigma**2 * sandwich_covariance(sensitivity[:, estimable], rest_map)
            deviation = np.sqrt(np.diag(covariance))
            std[estimable] = deviation
            index = np.flatnonzero(estimable)
            if np.all(deviation > 0):
                correlation[np.ix_(index, index)] = covariance / np.outer(deviation, deviation)
        else:
            collinear[estimable] = True
    reports = [
        ParameterReport(
            name=name,
            value=float(x[i]),
            unit=PARAMETERS[name].unit,
            std=None if np.isnan(std[i]) else float(std[i]),
            identifiable=bool(estimable[i] and not collinear[i]),
            at_bound=bool(at_bound[i]),
            note=_note(name, influential[i], at_bound[i], collinear[i], static),
        )
        for i, name in enumerate(space.names)
    ]
    return IdentifiabilityReport(
        reports, sensitivity, singular, rank, float(sigma), source, dof, correlation
    )


def _at_bound(space: ParameterSpace, x: np.ndarray) -> np.ndarray:
    z = space.to_internal(x)
    lower, upper = space.internal_bounds()
    span = np.where(np.isfinite(upper - lower), upper - lower, 1.0)
    return (np.abs(z - lower) < BOUND_TOLERANCE * span) | (
        np.abs(upper - z) < BOUND_TOLERANCE * span
    )


def _note(name: str, influential: bool, at_bound: bool, collinear: bool, static: bool) -> str:
    if not influential:
        if static and name in DYNAMIC_ONLY:
            return "not identifiable from static data"
        return "no influence on the data"
    if at_bound:
        return "at bound"
    if collinear:
        return "not identifiable: collinear with other parameters"
    return ""


def sandwich_covariance(sensitivity: np.ndarray, rest_map=None) -> np.ndarray:
    """(S^T S)^-1, or (S^T S)^-1 S^T (I + P P^T) S (S^T S)^-1 with shared rest noise."""
    inverse = np.linalg.inv(sensitivity.T @ sensitivity)
    if rest_map is None:
        return inverse
    shared = rest_map.T @ sensitivity
    return inverse @ (sensitivity.T @ sensitivity + shared.T @ shared) @ inverse


def contrast(static: IdentifiabilityReport, dynamic: IdentifiabilityReport) -> list[dict]:
    """One row per parameter: value, standard error and verdict from both reports."""
    rows = []
    by_name = static.by_name()
    for p in dynamic.parameters:
        s = by_name.get(p.name)
        rows.append(
            {
                "name": p.name,
                "unit": p.unit,
                "static_value": None if s is None else s.value,
                "static_std": None if s is None else s.std,
                "static_identifiable": None if s is None else s.identifiable,
                "static_note": "" if s is None else s.note,
                "dynamic_value": p.value,
                "dynamic_std": p.std,
                "dynamic_identifiable": p.identifiable,
                "dynamic_note": p.note,
            }
        )
    return rows


def contrast_table(rows: list[dict]) -> str:
    """Markdown table of ``contrast`` rows: estimate +/- standard error, or the verdict."""

    def cell(value, std, note):
        if value is None:
            return "-"
        text = f"{value:.4g}" + (f" +/- {std:.2g}" if std is not None else "")
        return text + (f" ({note})" if note else "")

    lines = ["| parameter | static data | trajectories |", "|---|---|---|"]
    for row in rows:
        static = cell(row["static_value"], row["static_std"], row["static_note"])
        dynamic = cell(row["dynamic_value"], row["dynamic_std"], row["dynamic_note"])
        lines.append(f"| {row['name']} [{row['unit']}] | {static} | {dynamic} |")
    return "\n".join(lines)
