"""What an effect is handed for one load case: its numbers, its load, its symbols.

``CaseData`` holds the numbers of a load case (its load, its observation; docs/model.md
eq. 20, docs/inverse.md eq. 24), ``LoadState`` the load as the load effects change it in
turn, ``CaseSymbols`` the CasADi symbols of the state (docs/model.md eq. 22) that the
effects' hooks (``symbolic.effects.base.Effect``) build their expressions on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class CaseData:
    """Numbers of one load case that effects may use.

    Attributes
    ----------
    index : int
        Position of the case in the dataset (names per-case parameters).
    force : numpy.ndarray
        Base generalised force F_B on the free points, (n_free, 3) [N] (eq. 20).
    force_vector : numpy.ndarray
        Applied force f, (3,) [N].
    contact_uv : numpy.ndarray or None
        Contact point (u, v) on the rest skin; None for a load without one (a frame of
        prescribed displacements, ``symbolic.loads.FrameLoad``).
    load_row : numpy.ndarray
        a with F_B = a f^T on all control points, (n,) (J(p) for a point force; 0 for
        f = 0).
    rows : scipy.sparse.csr_matrix
        S on the free points, (n_obs, n_free).
    rest_points : numpy.ndarray
        S B0, rest positions of the observed markers, (n_obs, 3) [mm].
    offset : numpy.ndarray
        S B0 - Y, (n_obs, 3) [mm].
    weights : numpy.ndarray
        W, one weight per observed marker, (n_obs,).
    probe_variance : float
        sigma_0^2 = (r / 2)^2 of the declared probe of radius r [mm^2]; 0 for a point
        force.
    probe_shape : str
        The declared probe's shape (``symbolic.loads.PROBE_SHAPES``).
    observed : tuple of int
        The components the markers are observed in (``InverseProblem.observed``).
    prescribed : numpy.ndarray, optional
        d, the displacements of the model's prescribed points, (m, 3) [mm].
    force_rows : scipy.sparse.csr_matrix, optional
        R, vec(lam) -> the measured force components, (n_F, 3 r) (``LoadCase.force_rows``).
    force_target : numpy.ndarray, optional
        The measured force components F, (n_F,) [N].
    force_weight : float
        w_f of the force rows w_f (R vec(lam) - F) [mm/N].
    """

    index: int
    force: np.ndarray
    force_vector: np.ndarray
    contact_uv: np.ndarray
    load_row: np.ndarray
    rows: sp.csr_matrix
    rest_points: np.ndarray
    offset: np.ndarray
    weights: np.ndarray
    probe_variance: float = 0.0
    probe_shape: str = "gauss"
    observed: tuple[int, ...] = (0, 1, 2)
    prescribed: np.ndarray | None = None
    force_rows: sp.csr_matrix | None = None
    force_target: np.ndarray | None = None
    force_weight: float = 1.0

    @property
    def centroid(self) -> np.ndarray:
        """Centroid of the observed rest markers, (3,) [mm] (0 for a case without
        markers: a force-only frame)."""
        return self.rest_points.mean(axis=0) if len(self.rest_points) else np.zeros(3)


@dataclass
class LoadState:
    """The load of one case as expressions, changed in turn by the load effects.

    Attributes
    ----------
    force_vector : casadi.MX or numpy.ndarray
        f, (3,) [N].
    uv_shift : casadi.MX, optional
        Shift of the contact in (u, v).
    variance : casadi.MX, optional
        Variance sigma^2 [mm^2] of a Gaussian spread of the contact.
    """

    force_vector: ca.MX | np.ndarray
    uv_shift: ca.MX | None = None
    variance: ca.MX | None = None

    @property
    def changed(self) -> bool:
        """True when some load effect is active."""
        return (
            self.uv_shift is not None
            or self.variance is not None
            or not isinstance(self.force_vector, np.ndarray)
        )


@dataclass
class CaseSymbols:
    """Symbols of one load case handed to the effects.

    Attributes
    ----------
    delta : casadi.MX
        B - B0 on the free points, (n_free, 3) [mm].
    values : dict
        Model parameter values by name (numbers, or entries of x).
    extra : dict
        Extra state by effect name, each (k, 3) [mm].
    lam : casadi.MX, optional
        The multipliers of the prescribed displacements, (r, 3) [N].
    """

    delta: ca.MX
    values: dict
    extra: dict = field(default_factory=dict)
    lam: ca.MX | None = None
