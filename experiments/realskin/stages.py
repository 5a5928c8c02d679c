"""Stages of the real-skin loop: errors, standard errors, score tests, one fitted stage.

- ``rms_errors``: RMS in-plane displacement [mm] and force [N] errors;
- ``standard_errors``: sigma (J^T J)^-1/2 at an estimate, residual-based sigma;
- ``score_test``: the score (Lagrange multiplier) statistic of a candidate parameter at
  its null value with the fitted parameters profiled out;
- ``fit_stage``: fit one parameter set and summarise it (``StageFit``);
- ``force_curve``: the model's pad force along the travel.

The fits run on the shared solvers: the planar observation is
``solvers.inverse.problem.PlanarProblem``, the nested inverse
``solvers.inverse.nested.NestedSolver`` with the loop's settings (``stage_solver``), the
equilibria ``solvers.forward.equilibrium.EquilibriumSolver``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from solvers.forward.equilibrium import EquilibriumSolver, NewtonSettings
from solvers.inverse.nested import NestedSolver
from solvers.inverse.problem import LoadCase, PlanarProblem
from solvers.inverse.space import SkinParameterSpace
from symbolic.model import PARAMETERS
from symbolic.skin_slab import ANISOTROPY, POISSON, REGION_RATIO, SkinSlabModel

NULL = {
    "k0": 0.0,
    REGION_RATIO: 1.0,
    ANISOTROPY: 1.0,
    POISSON: 0.0,
    "region_scan": 1.0,
    "k1": 0.0,
    "k2": PARAMETERS["k2"].default,
    "kf1": 0.0,
    "fibre_angle": 0.0,
}
"""Null value of every candidate parameter: the model without the effect (k2: the
exponent's default, tested once k1 is in; at k1 = 0 it has no influence; the fibre
angle: along the pull, x, tested once kf1 is in)."""
ONE_SIDED = {
    "k0": True,
    REGION_RATIO: False,
    ANISOTROPY: False,
    POISSON: True,
    "k1": True,
    "k2": False,
    "kf1": True,
    "fibre_angle": False,
}
"""Candidates that may only grow from their null value (k0 >= 0, c >= 0)."""
LABELS = {
    "k0": "stiffening k0",
    REGION_RATIO: "second material",
    ANISOTROPY: "anisotropy",
    POISSON: "Poisson coupling",
    "region_scan": "second material (scanned region)",
    "k1": "strain stiffening k1 (exponential, continuum)",
    "k2": "stiffening exponent k2",
    "kf1": "fibre family kf1 (continuum)",
    "fibre_angle": "fibre angle",
}
"""How reports name the effects."""
FIT_TOLERANCE = 1e-10
"""ftol = xtol = gtol of a stage's fit."""
MAX_EVALUATIONS = 80
"""Cap on a stage's residual evaluations (a stiffening fit sliding into a corner of
its bounds stops here; docs/realskin.md)."""


def stage_solver(problem: PlanarProblem) -> NestedSolver:
    """The nested inverse with the loop's settings: a load case without equilibrium
    during a fit shortens trf's step instead of ending the fit."""
    return NestedSolver(problem, "trf", FIT_TOLERANCE, MAX_EVALUATIONS, failures="shrink")


# ------------------------------------------------------------------- errors, statistics
def rms_errors(problem: PlanarProblem, states: list) -> tuple[float, float]:
    """RMS in-plane displacement error [mm] (per component, over all markers and DIC
    frames) and RMS force error [N] (over all fitted frames)."""
    planar = [e.reshape(-1) for e in problem.marker_errors(states) if e.size]
    forces = [e for e in problem.force_errors(states) if e is not None]
    disp = float(np.sqrt(np.mean(np.concatenate(planar) ** 2)))
    return disp, float(np.sqrt(np.mean(np.concatenate(forces) ** 2)))


def standard_errors(solver: NestedSolver, x: np.ndarray) -> tuple[np.ndarray, float]:
    """sigma (S^T S)^-1/2 diagonals, S = dr/dx at x, sigma = sqrt(RSS / (m - p)).

    Returns
    -------
    std : numpy.ndarray
        Standard error of every parameter (natural units; NaN if S is rank deficient or
        not finite).
    sigma : float
        The residual scale [mm]. It contains the model error, and neighbouring DIC
        residuals are correlated, so these errors are lower bounds.
    """
    space = solver.problem.space
    z = space.to_internal(x)
    r, jac_z = solver.evaluate(z)  # columns d r / d z: relative (log) or scaled
    std_z, sigma, _ = internal_standard_errors(r, jac_z)
    return std_z * space.natural_derivative(z), sigma


def internal_standard_errors(
    r: np.ndarray, jac_z: np.ndarray, rank_tolerance: float = 1e-10
) -> tuple[np.ndarray, float, np.ndarray | None]:
    """sigma (S^T S)^-1/2 diagonals for S = dr/dz (internal coordinates), the residual
    scale sigma = sqrt(RSS / (m - p)) and S's singular values (None if S is not finite:
    no equilibrium, no local information). NaN errors where S is not finite or its
    smallest singular value is below ``rank_tolerance`` times the largest."""
    n = jac_z.shape[1]
    sigma = float(np.sqrt(r @ r / max(r.size - n, 1)))
    if not np.all(np.isfinite(jac_z)):
        return np.full(n, np.nan), sigma, None
    singular = np.linalg.svd(jac_z, compute_uv=False)
    if singular.min() <= rank_tolerance * singular.max():
        return np.full(n, np.nan), sigma, singular
    std_z = sigma * np.sqrt(np.diag(np.linalg.inv(jac_z.T @ jac_z)))
    return std_z, sigma, singular


@dataclass(frozen=True)
class Score:
    """Score (Lagrange multiplier) test of one candidate parameter at its null value.

    Attributes
    ----------
    name : str
        The candidate parameter.
    statistic : float
        T = g^2 / (sigma^2 i): g the cost gradient and i the Gauss-Newton information
        of the candidate with the fitted parameters profiled out; chi^2_1 under the null.
    p_value : float
        P(chi^2_1 > T), halved for a one-sided test (a candidate that may only grow).
    predicted_decrease : float
        g^2 / (2 i): the cost decrease of one Gauss-Newton step [mm^2].
    direction : float
        +1 if the candidate should grow from its null value, -1 if it should shrink.
    """

    name: str
    statistic: float
    p_value: float
    predicted_decrease: float
    direction: float


def score_test(
    model: SkinSlabModel,
    cases: list[LoadCase],
    names: tuple[str, ...],
    x: np.ndarray,
    candidate: str,
    null: float,
    bounds: dict,
    one_sided: bool,
    states: list | None = None,
) -> Score:
    """Score test of ``candidate`` = ``null`` at the estimate x of ``names`` (``states``:
    the equilibria there, if known: the fitted stage's).

    With J = [J_x, J_c] = dr/d(z_x, z_c) at (x, null) and r the residual,
    J_c' = (I - Q Q^T) J_c (Q an orthonormal basis of J_x: x profiled out),
    g = J_c'^T r, i = |J_c'|^2, sigma^2 = |r|^2 / (m - p) and T = g^2 / (sigma^2 i).
    """
    start = {**dict(zip(names, x)), candidate: null}
    space = SkinParameterSpace.build(tuple(names) + (candidate,), start, bounds)
    solver = stage_solver(PlanarProblem(model, cases, space))
    if states is not None:
        solver.seed(space.start, states)
    r, jac = solver.evaluate(space.to_internal(space.start))
    basis, _ = np.linalg.qr(jac[:, :-1])
    column = jac[:, -1] - basis @ (basis.T @ jac[:, -1])
    gradient = float(column @ r)
    information = float(column @ column)
    sigma2 = float(r @ r) / max(r.size - len(names), 1)
    statistic = gradient**2 / (sigma2 * information) if information > 0 else 0.0
    direction = float(-np.sign(gradient))
    if one_sided and direction <= 0:
        statistic = 0.0
    p_value = float(stats.chi2.sf(statistic, 1)) * (0.5 if one_sided else 1.0)
    return Score(candidate, statistic, p_value, 0.5 * statistic * sigma2, direction)


# ----------------------------------------------------------------------------- a stage
@dataclass
class StageFit:
    """One fitted stage of the loop.

    Attributes
    ----------
    label : str
        What the stage is, e.g. "linear (alpha)" or "+ k0".
    names : tuple of str
        Estimated parameters.
    x, std : numpy.ndarray
        Estimates and standard errors (natural units; NaN where not estimable).
    cost : float
        1/2 |r|^2 [mm^2].
    rms_displacement_mm : float
        RMS of the in-plane residual components over all DIC markers and frames [mm].
    rms_force_n : float
        RMS of the force residual over all fitted frames [N].
    states : list of numpy.ndarray
        Equilibrium states per load case.
    sigma : float
        sqrt(RSS / (m - p)), the residual scale of the standard errors [mm].
    success : bool
        The least-squares solver's verdict.
    evaluations : int
        Residual evaluations.
    seconds : float
        Wall time of the fit [s].
    """

    label: str
    names: tuple
    x: np.ndarray
    std: np.ndarray
    cost: float
    rms_displacement_mm: float
    rms_force_n: float
    states: list
    sigma: float
    success: bool
    evaluations: int
    seconds: float
    problem: PlanarProblem | None = field(default=None, repr=False)

    def as_dict(self) -> dict:
        """Estimates by name."""
        return dict(zip(self.names, map(float, self.x)))

    @property
    def at_bound(self) -> np.ndarray:
        """True where an estimate lies within 1e-4 (of the internal range) of a bound."""
        space = self.problem.space
        z = space.to_internal(self.x)
        lower, upper = space.internal_bounds()
        span = upper - lower
        return (np.abs(z - lower) < 1e-4 * span) | (np.abs(upper - z) < 1e-4 * span)


def fit_stage(
    model: SkinSlabModel,
    cases: list[LoadCase],
    space: SkinParameterSpace,
    label: str,
    log=print,
) -> StageFit:
    """Fit the parameters of ``space`` and summarise errors and standard errors."""
    begin = time.perf_counter()
    problem = PlanarProblem(model, cases, space)
    solver = stage_solver(problem)
    result = solver.solve()
    std, sigma = standard_errors(solver, result.x)
    disp, force = rms_errors(problem, result.states)
    fit = StageFit(
        label,
        space.names,
        result.x,
        std,
        result.cost,
        disp,
        force,
        result.states,
        sigma,
        result.success,
        result.iterations,
        time.perf_counter() - begin,
        problem,
    )
    estimates = ", ".join(f"{n} {v:.4g}" for n, v in zip(fit.names, fit.x))
    log(
        f"  {label}: {estimates}; RMS displacement {disp:.4f} mm, force {force:.4f} N "
        f"({fit.evaluations} evaluations, {fit.seconds:.1f} s)"
    )
    return fit


def force_curve(
    model: SkinSlabModel, pads, fit: StageFit, travels: np.ndarray, drift: np.ndarray
) -> np.ndarray:
    """Model x force on the tissue [N] at pad travels (T,) [mm] with y drift (T,) [mm]."""
    solver = EquilibriumSolver(model, fit.names, NewtonSettings(reuse_lu=True))
    rows = model.point_force_rows(pads.moving_index)[:1]
    zero = np.zeros((model.n_free, 3))
    state = factor = None
    out = []
    for travel, dy in zip(travels, drift):
        # each travel starts from the last one's state and LU
        result = solver.solve(zero, fit.x, pads.displacement([-travel, dy]), state, factor)
        state, factor = result.state, result.factor
        out.append(float((rows @ result.state[3 * model.n_free :])[0]))
    return np.array(out)
