"""The inverse problem, stated once: model, observations, parameters (docs/inverse.md, eq. 24).

    f(x) = 1/2 sum_k | W_k (S_k B^k(x) - Y_k) |^2,    K(B^k; x)(B^k - B0) = F_B^k,

where S_k picks the model's material points that were observed (rows of J at
the markers' (u, v, 1), or the outer control points in the paper's variant),
Y_k are the measurements and W_k optional weights. The solvers in
``solvers.inverse.simultaneous`` and ``solvers.inverse.nested`` are interchangeable strategies
over this object and must agree on it.

Parameters live in an internal coordinate z: log(x) for the positive ones
(alpha, mu, gamma), x / scale for those that may be 0 (beta, k0). That keeps
alpha away from 0 and makes the problem well scaled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.inverse.noise import rest_noise_map
from solvers.inverse.space import ParameterSpace
from symbolic.model import TissueModel


@dataclass(frozen=True)
class LoadCase:
    """One measured load case.

    Attributes
    ----------
    force : numpy.ndarray
        F_B on the free control points, (n_free, 3) [N].
    rows : scipy.sparse.csr_matrix
        S restricted to the free control points, (n_obs, n_free).
    offset : numpy.ndarray
        S B0 - Y, the residual at rest, (n_obs, 3) [mm].
    weights : numpy.ndarray
        W, one weight per observed point, (n_obs,).
    prescribed : numpy.ndarray
        d, prescribed displacements (m, 3) [mm]; empty without prescribed points.
    rest_points : numpy.ndarray
        Rest positions S B0 of the observed points, (n_obs, 3) [mm] (for plots).
    label : str
        Name for reports, e.g. "0.25 N".
    marker_index : numpy.ndarray, optional
        Which rest marker each observation is, (n_obs,); lets the uncertainty
        account for noise in the rest markers, which every load case shares.
    force_rows : scipy.sparse.csr_matrix, optional
        Rows mapping vec(lam) to measured force components, (p, 3 r)
        (``TissueModel.point_force_rows``): a force sensor on prescribed points.
    force_target : numpy.ndarray, optional
        The measured force components, (p,) [N].
    force_weight : float
        Weight of the force residual [mm/N], so that it is comparable with
        marker residuals in mm.
    """

    force: np.ndarray
    rows: sp.csr_matrix
    offset: np.ndarray
    weights: np.ndarray
    prescribed: np.ndarray
    rest_points: np.ndarray
    label: str = ""
    marker_index: np.ndarray | None = None
    force_rows: sp.csr_matrix | None = None
    force_target: np.ndarray | None = None
    force_weight: float = 1.0

    @property
    def n_observations(self) -> int:
        """Number of observed points (each has 3 coordinates)."""
        return int(self.rows.shape[0])

    def force_scale(self) -> float:
        """A force magnitude [N] used to scale this case's equilibrium constraints."""
        scale = float(np.abs(self.force).sum())
        return scale if scale > 0 else 1.0


def observation_case(
    model: TissueModel,
    load,
    observed: np.ndarray,
    material_uv: np.ndarray,
    weights: np.ndarray | None = None,
    prescribed: np.ndarray | None = None,
    label: str = "",
) -> LoadCase:
    """A load case that observes skin material points (the default objective).

    Parameters
    ----------
    model : TissueModel
        The model.
    load : PointForce, ProbeForce or numpy.ndarray
        The load (or F_B on all control points).
    observed : numpy.ndarray
        Measured positions Y, (n_markers, 3) [mm]; NaN rows are unseen and dropped.
    material_uv : numpy.ndarray
        (u, v) of every marker on the rest skin, (n_markers, 2).
    weights : numpy.ndarray, optional
        One weight per marker (default 1).
    """
    observed = np.asarray(observed, dtype=float).reshape(-1, 3)
    material_uv = np.asarray(material_uv, dtype=float).reshape(-1, 2)
    if observed.shape[0] != material_uv.shape[0]:
        raise ValueError("observed markers and their (u, v) must have the same count")
    seen = np.all(np.isfinite(observed), axis=1)
    if not seen.any():
        raise ValueError(f"load case {label or '?'} has no observed marker")
    weights = np.ones(len(observed)) if weights is None else np.asarray(weights, dtype=float)
    rows = model.volume.collocation(model.volume.outer_params(material_uv[seen]))
    rest_points = rows @ model.rest
    return LoadCase(
        force=model.generalized_force(load),
        rows=rows[:, model.free].tocsr(),
        offset=rest_points - observed[seen],
        weights=weights[seen],
        prescribed=_prescribed(model, prescribed),
        rest_points=rest_points,
        label=label,
        marker_index=np.flatnonzero(seen),
    )


def control_point_case(
    model: TissueModel,
    load,
    target: np.ndarray,
    label: str = "",
    prescribed: np.ndarray | None = None,
) -> LoadCase:
    """The paper's variant: compare the free outer control points with fitted ones.

    Parameters
    ----------
    target : numpy.ndarray
        Control points of the spline fitted to the measured loaded surface, (n, 3) [mm].
    """
    outer = np.zeros(model.rest.shape[0], dtype=bool)
    outer.reshape(model.volume.shape)[:, :, -1] = True
    picked = np.flatnonzero(outer[model.free])
    selection = sp.csr_matrix(
        (np.ones(len(picked)), (np.arange(len(picked)), picked)), shape=(len(picked), model.n_free)
    )
    points = model.free[picked]
    return LoadCase(
        force=model.generalized_force(load),
        rows=selection,
        offset=model.rest[points] - np.asarray(target, dtype=float)[points],
        weights=np.ones(len(picked)),
        prescribed=_prescribed(model, prescribed),
        rest_points=model.rest[points],
        label=label,
    )


def _prescribed(model: TissueModel, prescribed) -> np.ndarray:
    rows = model._constraint_rows.shape[1]
    if prescribed is None:
        return np.zeros((rows, 3))
    prescribed = np.asarray(prescribed, dtype=float).reshape(-1, 3)
    if prescribed.shape[0] != rows:
        raise ValueError(f"prescribed displacements need {rows} rows, got {prescribed.shape[0]}")
    return prescribed


@dataclass
class InverseProblem:
    """Model + load cases + estimated parameters: everything a solver needs.

    Parameters
    ----------
    model : TissueModel
        The forward model (fixed parameters taken from ``model.parameters``).
    cases : list of LoadCase
        The measured load cases; they share the parameters (a joint estimate).
    space : ParameterSpace
        What is estimated, from where, within which bounds.
    noise_mm : float, optional
        Standard deviation of a marker coordinate, if known [mm].
    rest_noise : bool
        True when the rest markers that define the geometry are measured with
        the same noise (datasets). The residual of a marker is then
        (loaded noise - rest noise), and the rest noise is shared by all cases.
    observed : tuple of int
        The displacement components the markers are observed in: (0, 1, 2) for
        triangulated markers, ``PLANAR`` = (0, 1) for 2D DIC of a surface in the x-y
        plane (``PlanarProblem``).
    """

    model: TissueModel
    cases: list[LoadCase]
    space: ParameterSpace
    noise_mm: float | None = None
    rest_noise: bool = False
    observed: tuple[int, ...] = (0, 1, 2)

    def __post_init__(self) -> None:
        if not self.cases:
            raise ValueError("an inverse problem needs at least one load case")
        self.n_state = 3 * (self.model.n_free + self.model.n_constraints)
        self._g = None
        self._active: np.ndarray | None = None
        self._jacobians: dict[int, sp.csr_matrix] = {}

    @property
    def g(self):
        """g(s, x, F_B, d), the CasADi residual (``TissueModel.state_residual``), built on
        first use: the componentwise path of the linear model never needs it."""
        if self._g is None:
            self._g = self.model.state_residual(self.space.names)
        return self._g

    @property
    def active(self) -> np.ndarray:
        """Which estimated parameters enter the equilibrium (mu and gamma do not)."""
        if self._active is None:
            influence = self.model.influential(self.space.names)
            if influence is None:
                pattern = self.g.jac_sparsity(0, 1)  # d g / d x
                touched = set(pattern.get_col())
                influence = [i in touched for i in range(len(self.space.names))]
            self._active = np.asarray(influence, dtype=bool)
        return self._active

    @property
    def inactive_names(self) -> tuple[str, ...]:
        """Parameters that do not enter the equilibrium (mu and gamma at steady state)."""
        return tuple(n for n, a in zip(self.space.names, self.active) if not a)

    @property
    def names(self) -> tuple[str, ...]:
        """Estimated parameter names."""
        return self.space.names

    @property
    def n_residuals(self) -> int:
        """Total number of scalar residuals: one per observed component of every marker,
        plus one per measured force component."""
        forces = sum(0 if c.force_rows is None else c.force_rows.shape[0] for c in self.cases)
        return sum(len(self.observed) * c.n_observations for c in self.cases) + forces

    def case_residual(self, case: LoadCase, state: np.ndarray) -> np.ndarray:
        """W (S B - Y) for one case over the observed components, flattened column-wise
        (all x, then y, then z) [mm], followed by the weighted force residual if the
        case measures a force."""
        return self.case_residual_jacobian(case) @ state + self.case_offset(case)

    def case_offset(self, case: LoadCase) -> np.ndarray:
        """The residual at s = 0 (rest): vec(W (S B0 - Y)) over the observed components,
        then -w_f * force target."""
        markers = (case.weights[:, None] * case.offset[:, list(self.observed)]).T.reshape(-1)
        if case.force_rows is None:
            return markers
        return np.concatenate([markers, -case.force_weight * np.asarray(case.force_target)])

    def case_residual_jacobian(self, case: LoadCase) -> sp.csr_matrix:
        """d(residual)/d(state), constant: kron(I3 restricted to the observed rows, W S) on
        Delta, w_f R on lam (cached)."""
        key = id(case)
        if key not in self._jacobians:
            self._jacobians[key] = self._residual_jacobian(case)
        return self._jacobians[key]

    def _residual_jacobian(self, case: LoadCase) -> sp.csr_matrix:
        rows = sp.csr_matrix(np.eye(3)[list(self.observed)])
        block = sp.kron(rows, sp.diags(case.weights) @ case.rows)
        extra = self.n_state - block.shape[1]
        if extra:
            block = sp.hstack([block, sp.csr_matrix((block.shape[0], extra))])
        if case.force_rows is not None:
            force = sp.hstack(
                [
                    sp.csr_matrix((case.force_rows.shape[0], 3 * self.model.n_free)),
                    case.force_weight * sp.csr_matrix(case.force_rows),
                ]
            )
            block = sp.vstack([block, force])
        return block.tocsr()

    def force_errors(self, states: list[np.ndarray]) -> list[np.ndarray | None]:
        """Per case, model minus measured force components [N] (None without a sensor)."""
        errors = []
        for case, state in zip(self.cases, states):
            if case.force_rows is None:
                errors.append(None)
                continue
            lam = state[3 * self.model.n_free :]
            errors.append(case.force_rows @ lam - np.asarray(case.force_target))
        return errors

    def rest_noise_map(self) -> sp.csr_matrix | None:
        """P, mapping rest-marker coordinate noise into every residual, or None.

        The residual covariance is sigma^2 (I + P P^T) when ``rest_noise`` holds
        (``solvers.inverse.noise``).
        """
        return rest_noise_map(self.cases, self.rest_noise, self.observed)

    def marker_errors(self, states: list[np.ndarray]) -> list[np.ndarray]:
        """Per case, model minus measured displacement of every marker in the observed
        components, (n_obs, len(observed)) [mm] (unweighted)."""
        errors = []
        for case, state in zip(self.cases, states):
            delta = state[: 3 * self.model.n_free].reshape(3, -1).T
            errors.append((case.rows @ delta + case.offset)[:, list(self.observed)])
        return errors

    def point_errors(self, states: list[np.ndarray]) -> list[np.ndarray]:
        """Per case, the distance |S B - Y| of every observed point over the observed
        components [mm] (unweighted)."""
        return [np.linalg.norm(e, axis=1) for e in self.marker_errors(states)]


PLANAR = (0, 1)
"""The components 2D DIC of a surface in the x-y plane observes."""


@dataclass
class PlanarProblem(InverseProblem):
    """An ``InverseProblem`` whose markers are observed in x and y only (2D DIC, e.g. the
    two-pad extensometer of docs/realskin.md): a marker gives two residuals."""

    observed: tuple[int, ...] = PLANAR
