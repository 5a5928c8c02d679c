"""What marker trajectories can tell, against static data (docs/dynamic.md, "What the data tell").

The same report as ``solvers.inverse.identifiability.analyse``, with the sensitivity matrix of
the dynamic residual, S = dr/dx, from the exact forward sensitivities of the
trapezoidal scheme (``solvers.dynamic.scheme``):

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

from solvers.dynamic.nested import DynamicNestedSolver
from solvers.dynamic.problem import DynamicProblem
from solvers.inverse.identifiability import (  # noqa: F401  (report_from_sensitivity re-exported)
    IdentifiabilityReport,
    report_from_sensitivity,
    sandwich_covariance,
)


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
