"""The dynamic inverse problem, stated once: trajectories, time grid and scheme (docs/dynamic.md).

Marker trajectories Y_k(t_j), sampled at the frames t_1 < ... < t_T of a transient
that starts at rest at t = 0, are fitted by the discretised equation of motion

    M u'' + D u' + f(u; x) = F(t),    f(u; x) = K(B; x)(B - B0),           (22)

with u = vec(B_free - B0_free) (x components, then y, then z) and
M = kron(I3, mu M_1), D = kron(I3, gamma D_1) (eq. 13, 16). In first-order form
(23), y = (u, v), one step of the trapezoidal rule from t_n to t_{n+1} = t_n + h is

    a_n := u_{n+1} - u_n - h/2 (v_n + v_{n+1}) = 0                          (T1)
    b_n := M (v_{n+1} - v_n) + h/2 [D (v_n + v_{n+1}) + f(u_n) + f(u_{n+1})
                                   - F(t_n) - F(t_{n+1})] = 0                 (T2)

from u_0 = v_0 = 0. It is Newmark's average-acceleration scheme written without
the acceleration (``solvers.transient`` with ``method="newmark"`` and a fixed
step gives the same numbers), second order, A-stable and free of numerical
damping, so the lightly damped modes keep their amplitude.

- **choice (time grid)**: the scheme steps on the data's frames, each interval cut
  into ``substeps`` equal steps, so every frame is a node of the grid; step sizes
  equal to 1e-10 relative are snapped to one value (one factorisation per size).
- **choice (load history)**: F(t) = profile(t) F_B, a step at t = 0 by default
  (the frames start at the load onset; the dataset format stores no history).

The objective is eq. (24) summed over frames,

    f(x) = 1/2 sum_k sum_j | W_k (S_kj u_k(t_j) + S_kj B0 - Y_kj) |^2,

with S_kj the rows of J at the markers seen in frame j. ``solvers.dynamic.nested``
(single shooting) and ``solvers.dynamic.simultaneous`` (one IPOPT NLP) solve this
same discrete problem and agree on it; ``solvers.dynamic.identifiability`` reports
what the trajectories can tell.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from solvers.inverse.space import ParameterSpace
from symbolic.model import TissueModel
from symbolic.unitterms import term_parameter

STEP_SNAP = 1e-10
"""Relative tolerance below which two step sizes of the grid count as one."""
LOAD_SNAP = 1e-12
"""A load component below this fraction of the largest is set to zero (see ``loads``)."""


def step_profile(t):
    """The step load: scale 1 for every t >= 0."""
    return 1.0


@dataclass(frozen=True)
class TimeGrid:
    """Nodes of the scheme: 0, the frames, and ``substeps`` equal steps per interval.

    Parameters
    ----------
    frames : numpy.ndarray
        Sample times t_1 < ... < t_T of the data, (T,) [s]; t_1 >= 0 (a frame at
        t = 0 observes the rest state).
    substeps : int
        Steps of the scheme per frame interval (>= 1).
    """

    frames: np.ndarray
    substeps: int = 1

    def __post_init__(self) -> None:
        frames = np.asarray(self.frames, dtype=float).reshape(-1)
        if frames.size == 0 or not np.all(np.isfinite(frames)):
            raise ValueError("frames must be a non-empty array of finite times [s]")
        if frames[0] < 0 or np.any(np.diff(frames) <= 0):
            raise ValueError("frames must be >= 0 and strictly increasing (sort, drop duplicates)")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps}")
        object.__setattr__(self, "frames", frames)

    @property
    def steps(self) -> np.ndarray:
        """Step sizes h_n, (N,) [s], snapped so that equal steps are bitwise equal."""
        starts = np.concatenate([[0.0], self.frames])
        intervals = np.diff(starts)
        intervals = intervals[intervals > 0]
        h = np.repeat(intervals / self.substeps, self.substeps)
        key = np.round(h / h.max() / STEP_SNAP).astype(np.int64)
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        return h[first][inverse]

    @property
    def nodes(self) -> np.ndarray:
        """t_0 = 0, t_1, ..., t_N, (N + 1,) [s]."""
        return np.concatenate([[0.0], np.cumsum(self.steps)])

    @property
    def frame_nodes(self) -> np.ndarray:
        """Index of the node of every frame, (T,); a frame at t = 0 is node 0."""
        first = 0 if self.frames[0] == 0 else 1
        return (first + np.arange(self.frames.size)) * self.substeps


@dataclass(frozen=True)
class TrajectoryCase:
    """One load case observed as marker trajectories.

    Attributes
    ----------
    force : numpy.ndarray
        F_B on the free control points at full load, (n_free, 3) [N].
    rows : scipy.sparse.csr_matrix
        S on the free points for every marker seen in some frame, (m, n_free).
    rest_points : numpy.ndarray
        S B0, the markers' rest positions in the model, (m, 3) [mm].
    observed : numpy.ndarray
        Y_kj, measured positions per frame, (T, m, 3) [mm]; NaN = not seen.
    weights : numpy.ndarray
        W, one weight per marker, (m,).
    profile : callable
        t [s] -> load scale; F(t) = profile(t) F_B (default: a step at t = 0).
    label : str
        Name for reports.
    marker_index : numpy.ndarray, optional
        Which rest marker each row is, (m,) (for the shared rest-marker noise).
    """

    force: np.ndarray
    rows: sp.csr_matrix
    rest_points: np.ndarray
    observed: np.ndarray
    weights: np.ndarray
    profile: Callable = step_profile
    label: str = ""
    marker_index: np.ndarray | None = None

    @property
    def seen(self) -> np.ndarray:
        """(T, m) boolean, True where the marker was seen in the frame."""
        return np.all(np.isfinite(self.observed), axis=-1)

    def force_scale(self) -> float:
        """|F_B|_1 [N], the scale of this case's equations of motion."""
        scale = float(np.abs(self.force).sum())
        return scale if scale > 0 else 1.0

    @property
    def loaded_components(self) -> np.ndarray:
        """Boolean (3,): which of x, y, z carry load (above LOAD_SNAP of the largest)."""
        size = np.abs(np.asarray(self.force)).max(axis=0)
        return size > LOAD_SNAP * max(size.max(), 1e-300)

    def loads(self, nodes: np.ndarray) -> np.ndarray:
        """vec F(t_n) at every node, (N + 1, 3 n_free) [N].

        **choice**: components below LOAD_SNAP of the largest (round-off, e.g. the
        1e-16 N in-plane part of a normal force) are set to zero, so that in the
        linear model they stay at rest exactly and the NLP can drop them.
        """
        scale = np.array([float(self.profile(t)) for t in nodes])
        force = np.where(self.loaded_components[None, :], np.asarray(self.force), 0.0)
        return scale[:, None] * force.T.reshape(-1)[None, :]


def trajectory_case(
    model: TissueModel,
    load,
    observed: np.ndarray,
    material_uv: np.ndarray,
    profile: Callable | None = None,
    weights: np.ndarray | None = None,
    label: str = "",
) -> TrajectoryCase:
    """A trajectory case that observes skin material points (the default objective).

    Parameters
    ----------
    model : TissueModel
        The model (rest shape B0).
    load : PointForce, ProbeForce or numpy.ndarray
        The load at full scale (or F_B on all control points) [N].
    observed : numpy.ndarray
        Marker positions per frame, (T, n_markers, 3) [mm]; NaN = not seen.
    material_uv : numpy.ndarray
        (u, v) of every marker on the rest skin, (n_markers, 2).
    profile : callable, optional
        Load history t -> scale (default a step at t = 0).
    weights : numpy.ndarray, optional
        One weight per marker (default 1).
    """
    observed = np.asarray(observed, dtype=float)
    material_uv = np.asarray(material_uv, dtype=float).reshape(-1, 2)
    if observed.ndim != 3 or observed.shape[1:] != (material_uv.shape[0], 3):
        raise ValueError(
            f"observed must have shape (T, {material_uv.shape[0]}, 3), got {observed.shape}"
        )
    ever = np.all(np.isfinite(observed), axis=-1).any(axis=0)
    if not ever.any():
        raise ValueError(f"trajectory case {label or '?'} has no observed marker")
    weights = np.ones(len(material_uv)) if weights is None else np.asarray(weights, dtype=float)
    rows = model.volume.collocation(model.volume.outer_params(material_uv[ever]))
    return TrajectoryCase(
        force=model.generalized_force(load),
        rows=rows[:, model.free].tocsr(),
        rest_points=rows @ model.rest,
        observed=observed[:, ever],
        weights=weights[ever],
        profile=profile or step_profile,
        label=label,
        marker_index=np.flatnonzero(ever),
    )


def parameter_values(model: TissueModel, names, x) -> dict:
    """All parameter values with ``names`` taken from ``x`` (numbers or CasADi symbols)."""
    values: dict = dict(model.parameters)
    values.update({name: x[i] for i, name in enumerate(names)})
    return values


def unit_matrices(model: TissueModel) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """kron(I3, M_1) and kron(I3, D_1) on the free points (eq. 13, 16 per unit)."""
    eye = sp.identity(3, format="csr")
    mass = model.free_block(model.mass_matrix({"mu": 1.0}))
    damping = model.free_block(model.damping_matrix({"gamma": 1.0}))
    return sp.kron(eye, mass).tocsr(), sp.kron(eye, damping).tocsr()


def stiffness_terms(model: TissueModel) -> dict[str, sp.csr_matrix]:
    """kron(I3, K_t) on the free points for every stiffness term t (eq. 18)."""
    eye = sp.identity(3, format="csr")
    return {term: sp.kron(eye, model.free_block(m)).tocsr() for term, m in model.terms.items()}


@dataclass
class DynamicProblem:
    """Model + trajectory cases + time grid + estimated parameters (eq. 22-24).

    Parameters
    ----------
    model : TissueModel
        The forward model; parameters not estimated keep ``model.parameters``.
    cases : list of TrajectoryCase
        Load cases sharing the parameters (a joint estimate).
    space : ParameterSpace
        Estimated parameters, start values and bounds.
    frames : numpy.ndarray
        Frame times t_1 < ... < t_T [s], common to all cases.
    substeps : int
        Scheme steps per frame interval.
    noise_mm : float, optional
        Standard deviation of a marker coordinate [mm], if known.
    rest_noise : bool
        True when the rest markers defining B0 carry the same noise (datasets):
        every residual then shares its marker's rest noise (see ``rest_noise_map``).
    """

    model: TissueModel
    cases: list[TrajectoryCase]
    space: ParameterSpace
    frames: np.ndarray
    substeps: int = 1
    noise_mm: float | None = None
    rest_noise: bool = False
    grid: TimeGrid = field(init=False)

    def __post_init__(self) -> None:
        if not self.cases:
            raise ValueError("a dynamic inverse problem needs at least one trajectory case")
        if self.model.n_constraints:
            raise ValueError("trajectories with prescribed displacements are not supported")
        self.grid = TimeGrid(self.frames, self.substeps)
        self.frames = self.grid.frames
        for case in self.cases:
            if case.observed.shape[0] != self.frames.size:
                raise ValueError(
                    f"case {case.label or '?'} has {case.observed.shape[0]} frames, "
                    f"the problem {self.frames.size}"
                )
        self.g = self.model.state_residual(self.space.names)
        self.n_state = 3 * self.model.n_free

    @property
    def names(self) -> tuple[str, ...]:
        """Estimated parameter names."""
        return self.space.names

    @property
    def linear(self) -> bool:
        """True when f(u; x) is linear in u (k0 = 0 and not estimated)."""
        return self.model.is_linear(self.names)

    @property
    def time_scale(self) -> float:
        """tau [s], the mean frame interval; velocities enter the NLP as v tau [mm]."""
        return float(self.frames[-1] / self.frames.size)

    @property
    def n_residuals(self) -> int:
        """Total number of scalar residuals (3 per seen marker and frame)."""
        return sum(3 * int(case.seen.sum()) for case in self.cases)

    def values(self, x) -> dict:
        """All parameter values with the estimated ones from ``x`` (numbers or symbols)."""
        return parameter_values(self.model, self.names, x)

    def unit_matrices(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """kron(I3, M_1) and kron(I3, D_1) on the free points (eq. 13, 16 per unit)."""
        return unit_matrices(self.model)

    def stiffness_terms(self) -> dict[str, sp.csr_matrix]:
        """kron(I3, K_t) on the free points for every stiffness term t (eq. 18)."""
        return stiffness_terms(self.model)

    def term_parameters(self) -> dict[str, str]:
        """The parameter that multiplies each stiffness term (alpha_u, ..., beta)."""
        return {term: term_parameter(term) for term in self.model.terms}

    def component_observation(self, case: TrajectoryCase) -> sp.csr_matrix:
        """O_1 for one displacement component: residual_c = O_1 vec(u_c,1..N) + offset_c.

        The same for x, y and z (the observation rows act on each component alike);
        rows run over frames, then seen markers; columns over nodes 1..N, then points.
        """
        n, steps = self.model.n_free, self.grid.steps.size
        blocks = []
        for j, node in enumerate(self.grid.frame_nodes):
            picked = (sp.diags(case.weights[case.seen[j]]) @ case.rows[case.seen[j]]).tocoo()
            column = picked.col + n * (node - 1)
            keep = np.full(picked.nnz, node > 0)
            blocks.append(
                sp.csr_matrix(
                    (picked.data[keep], (picked.row[keep], column[keep])),
                    shape=(picked.shape[0], n * steps),
                )
            )
        return sp.vstack(blocks).tocsr()

    def component_offsets(self, case: TrajectoryCase) -> np.ndarray:
        """W (S B0 - Y) per component, (3, rows of ``component_observation``) [mm]."""
        parts = []
        for j in range(self.frames.size):
            seen = case.seen[j]
            parts.append(
                case.weights[seen, None] * (case.rest_points[seen] - case.observed[j, seen])
            )
        return np.vstack(parts).T

    def case_residual(self, case: TrajectoryCase, frames: np.ndarray) -> np.ndarray:
        """W (S u(t_j) + S B0 - Y_j) for one case; ``frames`` (T, 3 n_free) at the frames [mm].

        Ordered by frame, then x, y, z, then the seen markers.
        """
        moved = self._observe(case, frames.reshape(len(frames), 3, -1, 1))[..., 0]
        offset = (case.rest_points[None] - case.observed).transpose(0, 2, 1)
        residual = case.weights[None, None, :] * (moved + np.nan_to_num(offset))
        return residual[self._seen(case)]

    def case_sensitivity(self, case: TrajectoryCase, sensitivity: np.ndarray) -> np.ndarray:
        """d(residual)/dx from du(t_j)/dx, (T, 3 n_free, p) -> (n_res_k, p)."""
        blocks = sensitivity.reshape(len(sensitivity), 3, self.model.n_free, -1)
        return (case.weights[None, None, :, None] * self._observe(case, blocks))[self._seen(case)]

    def _observe(self, case: TrajectoryCase, blocks: np.ndarray) -> np.ndarray:
        """S applied to (T, 3, n_free, q) blocks -> (T, 3, m, q)."""
        return np.matmul(case.rows.toarray(), blocks)

    def _seen(self, case: TrajectoryCase) -> np.ndarray:
        """(T, 3, m) mask of the seen markers, for every component."""
        return np.broadcast_to(case.seen[:, None, :], (case.seen.shape[0], 3, case.seen.shape[1]))

    def rest_noise_map(self) -> sp.csr_matrix | None:
        """P: rest-marker coordinate noise into every residual (covariance sigma^2 (I + P P^T)).

        Every frame of every case shares its marker's rest noise, so for T frames the
        shared part does not average out like the frame noise does.
        """
        if not self.rest_noise or any(c.marker_index is None for c in self.cases):
            return None
        n_markers = 1 + max(int(c.marker_index.max()) for c in self.cases)
        blocks = []
        for case in self.cases:
            for j in range(self.frames.size):
                seen = np.flatnonzero(case.seen[j])
                pick = sp.csr_matrix(
                    (case.weights[seen], (np.arange(seen.size), case.marker_index[seen])),
                    shape=(seen.size, n_markers),
                )
                blocks.append(sp.kron(sp.identity(3), pick))
        return sp.vstack(blocks).tocsr()
