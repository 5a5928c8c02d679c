"""TissueModel: parameters by name, boundary conditions and the residual Function.

The steady state of eq. (22) is the residual

    R(B_free, x) = K(B; x) (B - B0) - F_B = 0          on the free control points,

with B0 the fitted, stress-free rest shape (**choice**, docs/model.md, "Dynamics").
Prescribed displacements of material points add Lagrange multipliers lam:

    R = K(B; x)(B - B0) + A^T lam - F_B,      C = A (B - B0) - d.

``x`` is any subset of the named parameters; the others are fixed numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.constraints import BoundaryConditions
from symbolic.energy import STIFFNESS_TERMS, damping_matrix, mass_matrix, stiffness_terms
from symbolic.loads import PrescribedDisplacement, independent_rows
from symbolic.parameters import PARAMETERS, check_parameters
from symbolic.sparse import to_casadi_sparse
from symbolic.stiffening import EdgeSet, StiffeningFunction, quadratic_stiffening
from symbolic.unitterms import UnitTerms, term_parameter
from symbolic.volume import VolumeSpline


@dataclass
class TissueModel(UnitTerms):
    """The dynamic volume spline model of the skin and fat layer.

    Parameters
    ----------
    volume : VolumeSpline
        The fitted rest shape; its control points are B0 [mm].
    parameters : dict, optional
        Parameter values by name (see ``PARAMETERS``); missing ones take defaults.
    boundary : BoundaryConditions
        Fixed control points.
    stiffening : callable
        s(eps, k0) of eq. (1).
    prescribed : PrescribedDisplacement, optional
        Outer-surface material points whose displacement each load case prescribes.
    fields : dict, optional
        Spatial shapes of coefficients by term name, e.g. ``{"alpha_u": f}``.
    extra_points : int
        Additional Gauss points per knot span (default rule is exact).
    """

    volume: VolumeSpline
    parameters: dict[str, float] = field(default_factory=dict)
    boundary: BoundaryConditions = field(default_factory=BoundaryConditions)
    stiffening: StiffeningFunction = quadratic_stiffening
    prescribed: PrescribedDisplacement | None = None
    fields: dict | None = None
    extra_points: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.volume, VolumeSpline):
            raise ValueError("volume must be a VolumeSpline (see VolumeSpline.fit)")
        self.parameters = check_parameters(self.parameters)
        if self.parameters["k1"] != 0.0 and not self.exponential:
            raise ValueError(
                f"the {self.energy} model has no exponential stiffening k1; leave k1 at 0 "
                "or use the exponential energy (--energy exponential)"
            )
        if self.parameters["kf1"] != 0.0 and not self.fibres:
            raise ValueError(
                f"the {self.energy} model has no fibre family kf1; leave kf1 at 0 "
                "or use the energy with fibres (--energy fibres)"
            )
        fields = dict(self.fields or {})
        self._terms: dict | None = None
        self._unit_mass = mass_matrix(self.volume.basis, fields.get("mu", 1.0), self.extra_points)
        self._unit_damping = damping_matrix(
            self.volume.basis, fields.get("gamma", 1.0), self.extra_points
        )
        fixed = self.boundary.fixed_mask(self.volume.shape).reshape(-1)
        self.free = np.flatnonzero(~fixed)
        self.fixed = np.flatnonzero(fixed)
        if self.free.size == 0:
            raise ValueError("every control point is fixed; relax the boundary conditions")
        self._setup_constraints()
        self._edges: EdgeSet | None = None
        self._term_cache: dict[tuple[str, str], object] = {}

    # ----------------------------------------------------------------- numbers
    @property
    def terms(self) -> dict:
        """The paper's unit stiffness terms (eq. 11-18), name -> (n, n) matrix, built on
        first use: the continuum models inherit them but their linear path never reads
        them (4 s of a 70 x 58 x 8 continuum's build)."""
        if self._terms is None:
            fields = dict(self.fields or {})
            self._terms = stiffness_terms(
                self.volume.basis,
                {k: v for k, v in fields.items() if k in STIFFNESS_TERMS},
                self.extra_points,
            )
        return self._terms

    @property
    def rest(self) -> np.ndarray:
        """B0, the rest control points, shape (n, 3) [mm]."""
        return self.volume.control_points

    @property
    def n_free(self) -> int:
        """Number of free control points."""
        return int(self.free.size)

    @property
    def n_constraints(self) -> int:
        """Independent prescribed-displacement rows (0 without prescribed points)."""
        return int(self._constraint_rows.shape[0])

    def values(self, overrides: dict[str, float] | None = None) -> dict[str, float]:
        """All parameter values, with optional overrides."""
        return check_parameters({**self.parameters, **(overrides or {})})

    def stiffness_matrix(self, overrides: dict[str, float] | None = None) -> sp.csr_matrix:
        """Linear K0 (eq. 18) for the current parameters, full (n, n) [N/mm]."""
        values = self.values(overrides)
        return sum(self.coefficient(t, values) * m for t, m in self.terms.items()).tocsr()

    def mass_matrix(self, overrides: dict[str, float] | None = None) -> sp.csr_matrix:
        """M = mu M_1 (eq. 13), full (n, n) [t]."""
        return (self.values(overrides)["mu"] * self._unit_mass).tocsr()

    def damping_matrix(self, overrides: dict[str, float] | None = None) -> sp.csr_matrix:
        """D = gamma D_1 (eq. 16), full (n, n) [N s/mm]."""
        return (self.values(overrides)["gamma"] * self._unit_damping).tocsr()

    def free_block(self, matrix: sp.spmatrix) -> sp.csr_matrix:
        """Rows and columns of the free control points."""
        return sp.csr_matrix(matrix)[self.free][:, self.free]

    def generalized_force(self, load) -> np.ndarray:
        """F_B of a load (PointForce, ProbeForce or an (n, 3) array) on the free points."""
        force = load if isinstance(load, np.ndarray) else load.generalized(self.volume)
        force = np.asarray(force, dtype=float)
        if force.shape != self.rest.shape:
            raise ValueError(f"generalised force must have shape {self.rest.shape}")
        return force[self.free]

    def full_positions(self, delta_free: np.ndarray) -> np.ndarray:
        """B = B0 + Delta with Delta = 0 on fixed points, shape (n, 3) [mm]."""
        positions = self.rest.copy()
        positions[self.free] += np.asarray(delta_free).reshape(self.n_free, 3)
        return positions

    # --------------------------------------------------------------- symbolic
    def _setup_constraints(self) -> None:
        if self.prescribed is None:
            self._constraint_rows = np.zeros((0, 0))
            self._constraint_free = sp.csr_matrix((0, self.n_free))
            return
        a_full = self.prescribed.constraint_matrix(self.volume)
        a_free = a_full[:, self.free].toarray()
        reduce = independent_rows(a_free)
        if reduce.shape[0] == 0:
            raise ValueError("prescribed points touch no free control point")
        self._constraint_rows = reduce
        self._constraint_free = sp.csr_matrix(reduce @ a_free)

    @property
    def is_linear_fixed(self) -> bool:
        """True when K does not depend on B for the fixed parameter values."""
        return self.parameters["k0"] == 0.0

    def is_linear(self, names: tuple[str, ...] = ()) -> bool:
        """True when K does not depend on B with ``names`` estimated (k0 fixed at 0)."""
        return "k0" not in names and self.is_linear_fixed

    energy = "dnurbs"
    """The base model's name (``dvs fit --energy``)."""

    exponential = False
    """True when the energy has the strain-stiffening term of eq. (C10) (k1, k2)."""

    fibres = False
    """True when the energy has the fibre family of eq. (C13) (kf1, kf2, fibre_angle)."""

    componentwise = True
    """The linear K acts as I3 (x) A on the free points (``solvers.forward.componentwise``);
    models that couple the components or add terms of their own set it False."""

    def influential(self, names: tuple[str, ...]) -> np.ndarray | None:
        """Which of ``names`` enter the equilibrium: stiffness terms' parameters, and k0
        when it is estimated (the nonlinear model); mu and gamma never. None when a
        subclass cannot tell without its residual (then it is read from g's sparsity)."""
        if not self.componentwise:
            return None
        touched = {term_parameter(t) for t, k in self.terms.items() if k.nnz}
        return np.array([n in touched or (n == "k0" and not self.is_linear(names)) for n in names])

    def edges(self) -> EdgeSet:
        """The coupled pairs of control points used by the nonlinear K(B) (built once)."""
        if self._edges is None:
            self._edges = EdgeSet.build(list(self.terms.values()), self.rest, self.free)
        return self._edges

    def _term_coefficients(self, values: dict) -> ca.MX:
        """Column of term coefficients (alpha_u, ..., beta_vw) as CasADi expressions."""
        return ca.vertcat(*[self.coefficient(t, values) for t in self.terms])

    def elastic_force(self, delta: ca.MX, values: dict, symbolic: tuple[str, ...]) -> ca.MX:
        """K(B; x)(B - B0) on the free points as an expression in delta and x."""
        if not self.is_linear(symbolic):
            return self.edges().elastic_force(
                delta, self._term_coefficients(values), values["k0"], self.stiffening
            )
        force = 0
        for term in self.terms:
            coefficient = self.coefficient(term, values)
            if isinstance(coefficient, float) and coefficient == 0.0:
                continue
            force = force + coefficient * ca.mtimes(self.free_term(term, "dm"), delta)
        return force

    def tangent(self, names: tuple[str, ...] = ()):
        """(vec(Delta_free), x) -> d(elastic force)/dDelta as scipy CSC, when the model
        assembles it faster than AD (``NeoHookeanModel``); None: the solvers use AD."""
        return None

    def force_curvature(self, names: tuple[str, ...] = ()):
        """(vec(Delta_free), x, vec(w)) -> d2(w . elastic force)/dDelta2 as scipy CSC, when
        the model assembles it (``NeoHookeanModel``); None: the solvers use AD."""
        return None

    def symbolic_values(self, names: tuple[str, ...]) -> tuple[ca.MX, dict]:
        """A symbol x for the named parameters and the full value dict with it inserted."""
        names = tuple(names)
        unknown = set(names) - set(PARAMETERS)
        if unknown or len(set(names)) != len(names):
            raise ValueError(f"parameter names must be distinct, from {list(PARAMETERS)}")
        x = ca.MX.sym("x", len(names))
        values: dict = dict(self.parameters)
        values.update({name: x[i] for i, name in enumerate(names)})
        return x, values

    def residual_function(self, names: tuple[str, ...] = ()) -> ca.Function:
        """The named Function R(B_free, x, F_B, lam, d) -> (R, C).

        Parameters
        ----------
        names : tuple of str
            Parameters that are symbolic inputs ``x``; the rest keep their values.

        Returns
        -------
        casadi.Function
            Inputs ``B_free`` (n_free, 3) [mm], ``x`` (len(names),), ``F_B``
            (n_free, 3) [N], ``lam`` (r, 3) [N], ``d`` (m, 3) [mm]. Outputs
            ``R`` (n_free, 3) [N] and ``C`` (r, 3) [mm].
        """
        x, values = self.symbolic_values(names)
        positions = ca.MX.sym("B_free", self.n_free, 3)
        force = ca.MX.sym("F_B", self.n_free, 3)
        rows = self._constraint_rows
        lam = ca.MX.sym("lam", rows.shape[0], 3)
        prescribed = ca.MX.sym("d", rows.shape[1], 3)
        delta = positions - ca.DM(self.rest[self.free])
        a_free = to_casadi_sparse(self._constraint_free)
        residual = self.elastic_force(delta, values, tuple(names)) - force
        residual = residual + ca.mtimes(a_free.T, lam)
        constraint = ca.mtimes(a_free, delta) - ca.mtimes(ca.DM(rows), prescribed)
        return ca.Function(
            "R",
            [positions, x, force, lam, prescribed],
            [residual, constraint],
            ["B_free", "x", "F_B", "lam", "d"],
            ["R", "C"],
        )

    def state_residual(self, names: tuple[str, ...] = ()) -> ca.Function:
        """Flat form g(s, x, F_B, d) for solvers, s = [vec(B_free - B0_free); vec(lam)].

        vec stacks columns (x components first, CasADi's convention). For the
        linear model the Function carries its exact Jacobian in closed form
        (see ``_linear_jacobian``), which is ~7x cheaper than AD colouring.
        """
        function = self._state_residual(tuple(names))
        if not self.is_linear(names):
            return function
        jacobian = self._linear_jacobian(tuple(names))
        return ca.Function(
            "g",
            function.mx_in(),
            function.call(function.mx_in()),
            ["s", "x", "F_B", "d"],
            ["g"],
            {"custom_jacobian": jacobian, "jac_penalty": 0, "never_inline": True},
        )

    def _linear_jacobian(self, names: tuple[str, ...]) -> ca.Function:
        """Closed-form Jacobian of the linear g with respect to s, x, F_B and d.

        dg/ds = [[A(x), I3 (x) C^T], [I3 (x) C, 0]] with A from ``stiffness_expression``;
        dg/dx = sum_t (K_t Delta) dc_t/dx; dg/dF_B = [-I; 0]; dg/dd = [0; -I3 (x) Q].
        """
        x, coefficients, terms = self.linear_terms(names)
        n, m_rows = 3 * self.n_free, 3 * self._constraint_rows.shape[0]
        stiffness = self.stiffness_expression(coefficients, terms)
        symbols = self._state_symbols()
        coupling = to_casadi_sparse(sp.kron(sp.identity(3), self._constraint_free))
        d_s = ca.blockcat([[stiffness, coupling.T], [coupling, ca.MX(m_rows, m_rows)]])
        columns = self.term_columns(terms, symbols[0][:n])
        d_x = ca.vertcat(ca.mtimes(columns, ca.jacobian(coefficients, x)), ca.MX(m_rows, x.numel()))
        return self._jacobian_function(symbols, x, d_s, d_x)

    def _state_symbols(self) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX]:
        """The symbols s, F_B, d and out_g of a custom Jacobian of ``state_residual``."""
        rows = self._constraint_rows
        n_state = 3 * (self.n_free + rows.shape[0])
        return (
            ca.MX.sym("s", n_state),
            ca.MX.sym("F_B", self.n_free, 3),
            ca.MX.sym("d", rows.shape[1], 3),
            ca.MX.sym("out_g", n_state),
        )

    def _jacobian_function(self, symbols, x: ca.MX, d_s: ca.MX, d_x: ca.MX) -> ca.Function:
        """The custom Jacobian Function from dg/ds and dg/dx; dg/dF_B = [-I; 0] and
        dg/dd = [0; -I3 (x) Q] are the same for every model."""
        state, force, prescribed, nominal = symbols
        rows = self._constraint_rows
        n, m_rows, m_cols = 3 * self.n_free, 3 * rows.shape[0], 3 * rows.shape[1]
        d_force = ca.vertcat(-ca.MX.eye(n), ca.MX(m_rows, n))
        reduce = to_casadi_sparse(sp.kron(sp.identity(3), sp.csr_matrix(rows)))
        d_prescribed = ca.vertcat(ca.MX(n, m_cols), -reduce)
        return ca.Function(
            "jac_g",
            [state, x, force, prescribed, nominal],
            [d_s, d_x, d_force, d_prescribed],
            ["s", "x", "F_B", "d", "out_g"],
            ["jac_g_s", "jac_g_x", "jac_g_F_B", "jac_g_d"],
        )

    def _state_residual(self, names: tuple[str, ...]) -> ca.Function:
        """g(s, x, F_B, d) by plain expressions (AD derivatives)."""
        x, values = self.symbolic_values(names)
        rows = self._constraint_rows
        n_state = 3 * (self.n_free + rows.shape[0])
        state = ca.MX.sym("s", n_state)
        force = ca.MX.sym("F_B", self.n_free, 3)
        prescribed = ca.MX.sym("d", rows.shape[1], 3)
        delta = ca.reshape(state[: 3 * self.n_free], self.n_free, 3)
        lam = ca.reshape(state[3 * self.n_free :], rows.shape[0], 3)
        a_free = to_casadi_sparse(self._constraint_free)
        residual = (
            self.elastic_force(delta, values, tuple(names)) - force + ca.mtimes(a_free.T, lam)
        )
        constraint = ca.mtimes(a_free, delta) - ca.mtimes(ca.DM(rows), prescribed)
        g = ca.vertcat(ca.vec(residual), ca.vec(constraint))
        return ca.Function("g", [state, x, force, prescribed], [g], ["s", "x", "F_B", "d"], ["g"])

    def point_force_rows(self, points: np.ndarray | None = None) -> sp.csr_matrix:
        """Rows R (3, 3 r) with R vec(lam) = force [N] exerted on the tissue by the chosen
        prescribed points (indices into ``prescribed.uv``; default all of them)."""
        rows = self._constraint_rows
        chosen = np.arange(rows.shape[1]) if points is None else np.asarray(points)
        weights = -rows[:, chosen].sum(axis=1)
        return sp.csr_matrix(sp.kron(sp.identity(3), weights[None, :]))

    def constraint_force(self, lam: np.ndarray) -> np.ndarray:
        """Total force [N] the prescribed points exert on the tissue, -1^T Q^T lam."""
        return -(self._constraint_rows.T @ np.asarray(lam).reshape(-1, 3)).sum(axis=0)
