"""What every candidate effect is: a named extension of the model with parameters theta.

An effect adds CasADi expressions to one or more of four places of a load case
(docs/model.md eq. 20, 22, docs/inverse.md eq. 24):

- ``internal_force``: a term added to the elastic force K(B; x)(B - B0) on the
  free control points (a stiffness effect, e.g. bending, eq. 18); an effect whose
  force is linear in Delta = B - B0 gives its matrix instead (``stiffness``), and
  the Newton Jacobian then takes it in closed form rather than by automatic
  differentiation (at 27 x 27 x 4 that took 20-40 s per load case);
- ``load``: a change of the applied force f, its contact point or its spread,
  from which the generalised force F_B of eq. (20) is recomputed;
- ``extra_points`` / ``extra_residual``: additional state (control points that
  the base model keeps fixed) with their own equilibrium rows;
- ``observe``: a map of the predicted marker positions S B before they are
  compared with the measurements Y (a measurement effect, eq. 24).

Every effect is off at theta = 0: the composed residuals are then *exactly*
those of the base model. Parameters may be shared by all load cases (a
property of the tissue or of the set-up) or repeated per case (``per_case``, a
property of each capture, like a registration error).
"""

from __future__ import annotations

import weakref

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.effects.casedata import CaseData, CaseSymbols, LoadState
from symbolic.effects.declaration import Magnitude
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


class Effect:
    """Base class of a candidate effect; every hook defaults to "no contribution".

    Class attributes
    ----------------
    name : str
        Effect name (docs/effects.md, "The effects").
    parameters : tuple of Parameter
        theta's parameters (one case's block for a per-case effect): name, unit, scale
        and bounds. ``parameter_names``, ``units``, ``scales``, ``lower`` and ``upper``
        are their columns, set from it for every subclass.
    per_case : bool
        One block of theta per load case instead of one shared block.
    magnitude : Magnitude
        A realistic magnitude for synthetic data, its unit and direction
        (``true_parameters``); ``default_magnitude`` and ``magnitude_unit`` are set
        from it.
    equation : str
        The added term, for reports.
    energies : tuple of str
        The base energies (``symbolic.continuum_model.ENERGIES``) the effect extends;
        a continuum already contains bending and the volumetric term, say.
    linear : bool
        The internal force is ``stiffness(...)`` vec(Delta): set by the effects that
        implement ``stiffness`` (never per case).
    unit_terms : bool
        All the effect adds to h is sum_t c_t K_t of ``stiffness_terms`` and
        ``stiffness_coefficients`` (every ``linear`` effect, and base_compliance with
        its extra state): the numeric linear path applies.
    """

    name = ""
    parameter_names: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    scales: tuple[float, ...] = ()
    lower: tuple[float, ...] = ()
    upper: tuple[float, ...] = ()
    per_case = False
    magnitude = Magnitude(0.0, "")
    default_magnitude = 0.0
    magnitude_unit = ""
    equation = ""
    energies: tuple[str, ...] = ("dnurbs", "linear-elastic", "neo-hookean")
    linear = False

    @property
    def unit_terms(self) -> bool:
        """True for every ``linear`` effect (see the class attributes)."""
        return self.linear

    def __init__(self) -> None:
        self._cache: dict = {}

    def __init_subclass__(cls, **kwargs):
        """The columns of ``parameters`` and ``magnitude`` as class attributes."""
        super().__init_subclass__(**kwargs)
        if "parameters" in cls.__dict__:
            columns = zip(*[(p.name, p.unit, p.scale, p.lower, p.upper) for p in cls.parameters])
            cls.parameter_names, cls.units, cls.scales, cls.lower, cls.upper = map(tuple, columns)
        if "magnitude" in cls.__dict__:
            cls.default_magnitude, cls.magnitude_unit = cls.magnitude.value, cls.magnitude.unit

    # ----------------------------------------------------------------- layout
    @property
    def dim(self) -> int:
        """Number of parameters of one block."""
        return len(self.parameter_names)

    def labels(self, case_indices: list[int]) -> list[str]:
        """Parameter labels; per-case ones carry the dataset case index, ``omega_x[1]``."""
        if not self.per_case:
            return list(self.parameter_names)
        return [f"{n}[{k}]" for k in case_indices for n in self.parameter_names]

    def block(self, theta: ca.MX, position: int) -> ca.MX:
        """This case's block of theta (position of the case among the problem's cases)."""
        if not self.per_case:
            return theta
        return theta[position * self.dim : (position + 1) * self.dim]

    def true_parameters(self, magnitude: float, n_cases: int) -> np.ndarray:
        """theta for synthetic data of the given magnitude (all blocks)."""
        direction = np.asarray(self.direction(), dtype=float)
        blocks = [magnitude * direction * self.case_factor(k) for k in range(n_cases)]
        return np.concatenate(blocks if self.per_case else blocks[:1])

    def plausible_range(self, n_cases: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The plausible lower and upper values of every entry of theta (all blocks;
        ``Parameter.plausible``)."""
        rows = getattr(self, "parameters", None)  # an effect of its own layout: the bounds
        ranges = (
            np.array([p.plausible_range for p in rows], dtype=float).reshape(-1, 2)
            if rows is not None
            else np.column_stack([self.lower, self.upper]).astype(float).reshape(-1, 2)
        )
        blocks = n_cases if self.per_case else 1
        return np.tile(ranges[:, 0], blocks), np.tile(ranges[:, 1], blocks)

    def magnitude_range(self, n_cases: int = 1) -> tuple[float, float]:
        """Magnitudes whose ``true_parameters`` stay within ``lower`` and ``upper``.

        theta is linear in the magnitude (``true_parameters(1)`` is its slope), so each
        component bounds the magnitude on one side or both.
        """
        slope = self.true_parameters(1.0, n_cases)
        lower = np.resize(np.asarray(self.lower, dtype=float), slope.size)
        upper = np.resize(np.asarray(self.upper, dtype=float), slope.size)
        low, high = -np.inf, np.inf
        for d, lo, hi in zip(slope, lower, upper):
            if d > 0:
                low, high = max(low, lo / d), min(high, hi / d)
            elif d < 0:
                low, high = max(low, hi / d), min(high, lo / d)
        return float(low), float(high)

    def direction(self) -> tuple[float, ...]:
        """Unit pattern of theta that a scalar magnitude scales (``Magnitude.direction``)."""
        given = self.magnitude.direction
        return (1.0,) * self.dim if given is None else given

    def case_factor(self, k: int) -> float:
        """Per-case variation of synthetic values (per-case effects only)."""
        return 1.0

    # ------------------------------------------------------------------ hooks
    def extra_points(self, model: TissueModel) -> int:
        """Number of extra state points (3 unknowns each)."""
        return 0

    def least_modulus(self, theta: np.ndarray) -> float:
        """A lower bound on what this effect adds to the relative modulus anywhere in the
        volume (the stiffness fields scale the base's moduli by 1 + their sum; 0 for an
        effect that does not scale them).

        The fields add up, so the material is stable only while 1 + the sum of these
        bounds stays positive: ``solvers.diagnosis.stability``.
        """
        return 0.0

    def extra_row_scale(self, theta: np.ndarray) -> float | None:
        """A factor for this effect's extra rows of dg/ds that makes the whole matrix
        symmetric (None: none needed, or none exists at this theta)."""
        return None

    def internal_force(self, model: TissueModel, symbols: CaseSymbols, theta) -> ca.MX | None:
        """Term added to K(B; x)(B - B0) on the free points, (n_free, 3) [N].

        A ``linear`` effect gives ``stiffness`` instead; the builder applies it.
        """
        return None

    def internal_tangent(self, model: TissueModel, symbols: CaseSymbols, theta) -> ca.MX | None:
        """d vec(internal_force) / d vec(Delta) in closed form, (3 n_free, 3 n_free) [N/mm],
        or None: the builder then differentiates ``internal_force`` by AD."""
        return None

    def numeric_force(self, model: TissueModel, values: dict, theta) -> tuple | None:
        """``internal_force`` in numbers, for the split path (``solvers.diagnosis.splitpath``):
        (q, evaluator), q a CasADi column of the force's arguments in ``values`` and theta,
        and an object whose ``force(delta, q)``, ``tangent(delta, q)`` and
        ``slope(delta, q)`` give vec(F) on the free points, d vec(F) / d vec(Delta)
        (sparse) and d vec(F) / dq, for Delta (n_free, 3); None (the default): none."""
        return None

    def stiffness(self, model: TissueModel, values: dict, theta) -> ca.MX:
        """K_theta of a ``linear`` effect: (3 n_free)-square, stacked order [N/mm].

        ``values`` maps parameter names to their (symbolic) values.
        """
        raise NotImplementedError(f"{self.name} is not linear in the state")

    def stiffness_terms(self, model: TissueModel) -> list[sp.spmatrix]:
        """The unit matrices K_t of a ``unit_terms`` effect, with ``stiffness`` = sum_t
        c_t K_t for the coefficients c of ``stiffness_coefficients``: the numeric form
        of the linear path (``solvers.forward.linearpath``), which never builds K_theta in
        CasADi. On the free points, stacked, (3 n_free)-square; an effect with extra
        state gives them on [free points; its extra points]."""
        raise NotImplementedError(f"{self.name} gives no unit stiffness terms")

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        """c_t(x, theta), one per ``stiffness_terms`` entry, (T, 1) [as K_theta / K_t]."""
        raise NotImplementedError(f"{self.name} gives no unit stiffness terms")

    def extra_residual(self, model: TissueModel, symbols: CaseSymbols, theta) -> ca.MX | None:
        """Equilibrium rows of the extra state, (k, 3)."""
        return None

    def load(self, model: TissueModel, case: CaseData, load: LoadState, theta) -> LoadState:
        """The load after this effect."""
        return load

    def observe(self, model: TissueModel, case: CaseData, predicted: ca.MX, theta) -> ca.MX:
        """Predicted marker positions after this effect, (n_obs, 3) [mm]."""
        return predicted

    def prior(self, model: TissueModel) -> np.ndarray | None:
        """R of a Gaussian prior theta ~ N(0, (R^T R)^-1): the fit adds |R theta|^2 to chi^2.

        None (the default): theta is free, and counts one degree of freedom per entry.
        """
        return None

    # ---------------------------------------------------------------- helpers
    def cached(self, model: TissueModel, key: str, build):
        """A numeric object built once per model instance (held with the model: the
        values may refer to it, and the store goes with the effect)."""
        return per_model(self._cache, model, key, build, weak=False)


class OneTermStiffness:
    """A mixin of ``Effect`` for K_theta = theta_0 K_1: the effect gives its one unit
    matrix (``stiffness_terms``); the coefficient and the CasADi K_theta follow."""

    linear = True

    def stiffness_coefficients(self, model: TissueModel, values: dict, theta) -> ca.MX:
        return theta[0]

    def stiffness(self, model: TissueModel, values: dict, theta) -> ca.MX:
        block = self.cached(model, "term", lambda: to_casadi_sparse(self.stiffness_terms(model)[0]))
        return theta[0] * block


def per_model(store: dict, model: TissueModel, key, build, weak: bool = True):
    """``build()`` once per (model instance, key) in ``store``; an id reused by a later
    model is not mistaken for it.

    With ``weak`` (the module-level stores, whose values do not refer to the model) an
    entry holds its model weakly and goes when the model is collected. Entries that
    held their model kept every model of every diagnosis alive in one process. A store
    that lives no longer than its owner (``Effect.cached``) holds the model instead: a
    weak entry there would be kept by its finalizer while its value holds the model.
    """
    slot = (id(model), key)
    entry = store.get(slot)
    held = None if entry is None else (entry[0]() if weak else entry[0])
    if held is not model:
        entry = (weakref.ref(model) if weak else model, build())
        store[slot] = entry
        if weak:
            weakref.finalize(model, store.pop, slot, None)
    return entry[1]


def linear_coefficient(model: TissueModel, values: dict, term: str):
    """The coefficient c_t of a unit stiffness term K_t (alpha_u, ..., beta for beta_uv) as
    the model reads it (``TissueModel.coefficient``: the slab's tied alpha_v)."""
    return model.coefficient(term, values)


def free_matrix(model: TissueModel, matrix: sp.spmatrix) -> ca.DM:
    """The free rows and columns of an (n, n) matrix as a CasADi sparse constant."""
    return to_casadi_sparse(model.free_block(matrix))


def apply_stacked(matrix: ca.DM, delta: ca.MX) -> ca.MX:
    """A (3 n_free)-square matrix acting on vec(delta) (columns stacked), as (n_free, 3)."""
    return ca.reshape(ca.mtimes(matrix, ca.vec(delta)), delta.shape[0], 3)


def componentwise(matrix: sp.spmatrix) -> sp.csr_matrix:
    """An (n, n) matrix acting on each of x, y, z alike, (3n, 3n) in stacked order."""
    return sp.csr_matrix(sp.kron(sp.identity(3), matrix))


def stacked_free_block(model: TissueModel, matrix: sp.spmatrix) -> sp.csr_matrix:
    """Rows and columns of the free points of a (3n)-square matrix in stacked order."""
    n = model.rest.shape[0]
    index = np.concatenate([model.free + k * n for k in range(3)])
    return sp.csr_matrix(matrix)[index][:, index]


def enters_model_part(effect: Effect) -> bool:
    """True when the effect changes h (internal force, stiffness or extra state)."""
    kind = type(effect)
    hooks = ("internal_force", "extra_residual", "extra_points")
    return effect.linear or any(getattr(kind, h) is not getattr(Effect, h) for h in hooks)


def changes_case(effect: Effect) -> bool:
    """True when the effect changes a case's load or its observation."""
    kind = type(effect)
    return any(getattr(kind, h) is not getattr(Effect, h) for h in ("load", "observe"))


def adds_rows(effect: Effect) -> bool:
    """True when the effect adds equilibrium rows of its own (``extra_residual``)."""
    return type(effect).extra_residual is not Effect.extra_residual
