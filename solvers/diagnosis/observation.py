"""What an extended problem observes, row by row (docs/inverse.md, eq. 24).

The residual of load case k stacks the observed components of its markers, one block of
n_obs rows per component (x, then y, then z, as ``InverseProblem.observed`` lists them),
and then the case's force rows (a force sensor on prescribed points,
``LoadCase.force_rows``), as ``InverseProblem.case_residual`` does:

    r_k = [vec(W (S B - Y))_observed; w_f (R vec(lam) - F_k)],
    rows_k = len(observed) n_obs + n_F.

The noise model whitens the marker rows (``solvers.inverse.noise``) and leaves the force
rows as they are: w_f (R vec(lam) - F_k) has the variance sigma^2 of a marker coordinate
when w_f = sigma / sigma_F, so a case's force weight w_f [mm/N] states its force noise,
sigma_F = sigma / w_f [N] (``force_noise``).
"""

from __future__ import annotations

import numpy as np

from solvers.inverse.noise import Whitening, rest_noise_map
from solvers.inverse.problem import InverseProblem, LoadCase
from symbolic.effects.base import CaseData


def case_data(problem: InverseProblem, loads: list, index: int, position: int) -> CaseData:
    """The numbers of base case ``position`` (dataset case ``index``) with its load.

    A load without a contact point (``symbolic.loads.FrameLoad``: f = 0, ``uv`` None, a
    frame of a set-up driven by prescribed displacements) has no contact and a zero load
    row.
    """
    case: LoadCase = problem.cases[position]
    load = loads[index]
    full = np.asarray(load.generalized(problem.model.volume), dtype=float)
    f = np.asarray(load.force, dtype=float)
    size = float(f @ f)
    uv = getattr(load, "uv", None)
    prescribed = np.asarray(case.prescribed, dtype=float) if problem.model.n_constraints else None
    return CaseData(
        index=index,
        force=case.force,
        force_vector=f,
        contact_uv=None if uv is None else np.asarray(uv, dtype=float),
        load_row=full @ f / size if size else np.zeros(full.shape[0]),
        rows=case.rows,
        rest_points=case.rest_points,
        offset=case.offset,
        weights=case.weights,
        probe_variance=0.25 * float(getattr(load, "radius", 0.0)) ** 2,
        probe_shape=getattr(load, "shape", "gauss"),
        observed=tuple(problem.observed),
        prescribed=prescribed,
        force_rows=case.force_rows,
        force_target=None if case.force_rows is None else np.asarray(case.force_target, float),
        force_weight=float(case.force_weight),
    )


def case_rows(base: InverseProblem, case: LoadCase) -> tuple[int, int]:
    """(marker rows, force rows) of one case's residual: len(observed) n_obs and n_F."""
    forces = 0 if case.force_rows is None else int(case.force_rows.shape[0])
    return len(base.observed) * case.n_observations, forces


def row_offsets(base: InverseProblem, cases: list[LoadCase]) -> np.ndarray:
    """Where every case's rows begin in the stacked residual, and the total, (K + 1,)."""
    return np.cumsum([0] + [sum(case_rows(base, case)) for case in cases])


def noise_model(base: InverseProblem, cases: list[LoadCase]) -> Whitening:
    """The whitening of ``cases``' residual rows: rest-marker noise over the observed
    components (``rest_noise_map``), none on the force rows."""
    rows = [case_rows(base, case) for case in cases]
    markers = sum(m for m, _ in rows)
    p_map = rest_noise_map(cases, base.rest_noise, base.observed)
    return Whitening.of(p_map, markers + sum(f for _, f in rows), markers)


def point_errors(base: InverseProblem, cases: list[LoadCase], r: np.ndarray) -> list:
    """Per case, the distance of every observed marker from its prediction over the
    observed components [mm], (n_obs,)."""
    offsets, width = row_offsets(base, cases), len(base.observed)
    errors = []
    for case, start in zip(cases, offsets):
        n = case.n_observations
        block = r[start : start + width * n].reshape(width, n).T / case.weights[:, None]
        errors.append(np.linalg.norm(block, axis=1))
    return errors


def force_errors(base: InverseProblem, cases: list[LoadCase], r: np.ndarray) -> list:
    """Per case, model minus measured force components [N] (None without a sensor)."""
    errors = []
    for case, end in zip(cases, row_offsets(base, cases)[1:]):
        n_force = case_rows(base, case)[1]
        errors.append(r[end - n_force : end] / case.force_weight if n_force else None)
    return errors


def force_noise(sigma: float, case: LoadCase) -> float | None:
    """sigma_F = sigma / w_f [N], the force noise a case's force weight states (None
    without a force sensor)."""
    return None if case.force_rows is None else float(sigma / case.force_weight)
