"""A flat skin slab with glued pads as a volume spline model (the two-pad extensometer).

The slab's volume and pads are set up in ``experiments.realskin`` (docs/realskin.md).
A second material (``region``): every tension coefficient alpha_i is multiplied by
1 + theta chi(x, y), and ``region_ratio`` = 1 + theta is a parameter that the inverse
can estimate.

``SkinSlabModel`` is a ``TissueModel`` with in-plane isotropy (alpha_v tied to alpha_u,
optionally anisotropic), the region terms, and closed-form Jacobians of the linear and
the nonlinear residual (eq. 1), about 8x cheaper than CasADi's coloured AD Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.basis import FIRST_DERIVATIVES
from symbolic.energy import Field, quadrature, weighted_gram
from symbolic.model import PARAMETERS, TissueModel, check_parameters
from symbolic.sparse import to_casadi_sparse
from symbolic.unitterms import term_parameter

REGION_RATIO = "region_ratio"
"""Name of the stiffness ratio 1 + theta of the second material (inside / outside) [1]."""
ANISOTROPY = "anisotropy"
"""Name of the in-plane anisotropy a = T_y / T_x of an isotropic-by-default model [1]."""
POISSON = "poisson"
"""Name of the in-plane volumetric coupling c = C / T [1] (lateral contraction, Poisson)."""
EXTRA_PARAMETERS = {
    REGION_RATIO: "1 + theta: stiffness inside the region / outside [1]",
    ANISOTROPY: "T_y / T_x, membrane tension across / along the pull [1]",
    POISSON: "C / T: areal (div u)^2 stiffness over the membrane tension [1]",
}
LOG_EXTRA = frozenset({REGION_RATIO, ANISOTROPY})
"""Extra parameters estimated in log space (the others, with null value 0, linearly)."""
COUPLING = "div"
"""Name of the volumetric coupling term integral (div_xy u)^2 (a 3n x 3n matrix)."""
REGION_SUFFIX = "@region"
ALPHA_TERMS = tuple(f"alpha_{d}" for d in FIRST_DERIVATIVES)


# ------------------------------------------------------------------------------ the model
@dataclass
class SkinSlabModel(TissueModel):
    """``TissueModel`` with in-plane isotropy, a second material and fast Jacobians.

    Parameters
    ----------
    isotropic : bool
        Tie alpha_v to alpha_u so that the skin is isotropic in the plane: with
        u = (x - x0) / L_x and v = (y - y0) / L_y, eq. (18) gives the membrane tensions
        T_x = alpha_u L_x / L_y and T_y = alpha_v L_y / L_x [N/mm], so
        alpha_v = alpha_u (L_x / L_y)^2 a, with the anisotropy a = T_y / T_x.
    anisotropy : float
        a [1] when not estimated (1: isotropic).
    region : callable, optional
        chi(params (n, 3)) in [0, 1]: where the second material is.
    region_ratio : float
        Its stiffness ratio 1 + theta [1] when not estimated.
    region_extra_points : int
        Extra Gauss points per span for the region terms (chi is not polynomial).
    poisson : float
        c = C / T [1] when not estimated (0: the paper's energy, no lateral coupling).

    Notes
    -----
    K = sum_t c_t K_t over the usual unit terms plus, for alpha_u, alpha_v, alpha_w, the
    region terms K_t^chi = integral chi J_t^T J_t with coefficient c_t (ratio - 1).

    The volumetric (Poisson) coupling adds the energy C/2 integral (du_x/dx + du_y/dy)^2
    over the slab, C = c T_x [N/mm] (times the ratio inside the region). Unlike eq. (18)
    it couples the x and y components: a membrane with it contracts across a uniaxial
    stretch with nu = c / (1 + c). Its 3n x 3n matrices (``couplings``) are linear (k0
    does not stiffen them). ``anisotropy``, ``region_ratio`` and ``poisson`` can be
    estimated like the model's own parameters.
    """

    isotropic: bool = False
    anisotropy: float = 1.0
    region: Field | None = None
    region_ratio: float = 1.0
    region_extra_points: int = 2
    poisson: float = 0.0
    _fast: dict = field(default_factory=dict, repr=False)
    componentwise = False  # isotropy, region and Poisson terms: not TissueModel's terms

    def __post_init__(self) -> None:
        super().__post_init__()
        extent = np.ptp(self.rest, axis=0)
        self.aspect = float(extent[0] / extent[1])
        self.lengths = (float(extent[0]), float(extent[1]))
        self.couplings = {COUPLING: coupling_matrix(self.volume.basis, self.lengths)}
        if self.region is not None:
            for name in ALPHA_TERMS:
                derivative = FIRST_DERIVATIVES[name[-1]]
                self.terms[name + REGION_SUFFIX] = weighted_gram(
                    self.volume.basis, derivative, self.region, self.region_extra_points, name
                )
            self.couplings[COUPLING + REGION_SUFFIX] = coupling_matrix(
                self.volume.basis, self.lengths, self.region, self.region_extra_points
            )
        index = np.concatenate([self.free + k * self.rest.shape[0] for k in range(3)])
        self._coupling_free = {
            name: sp.csr_matrix(m)[index][:, index].tocsr() for name, m in self.couplings.items()
        }

    def volumetric_matrix(self) -> sp.csr_matrix:
        """K_lambda of ``volumetric_coupling`` here: integral (du_x/dx + du_y/dy)^2 dV,
        (3n, 3n) stacked [mm]. In-plane: a thin slab contracts freely through its
        thickness, so the 3D divergence would not couple u_x and u_y (lambda t = C)."""
        thickness = float(np.ptp(self.rest[:, 2]))
        volume = self.lengths[0] * self.lengths[1] * thickness
        return (volume * self.couplings[COUPLING]).tocsr()

    # ------------------------------------------------------------ coefficients
    def values(self, overrides: dict[str, float] | None = None) -> dict[str, float]:
        """Parameter values with the extra ones; overrides may include them."""
        overrides = dict(overrides or {})
        extra = {name: float(overrides.pop(name, default)) for name, default in self._extra()}
        return {**check_parameters({**self.parameters, **overrides}), **extra}

    def _extra(self) -> list[tuple[str, float]]:
        return [
            (ANISOTROPY, self.anisotropy),
            (REGION_RATIO, self.region_ratio),
            (POISSON, self.poisson),
        ]

    def coupling_coefficients(self, values: dict) -> list:
        """Coefficient of every coupling matrix (``couplings`` order): C L_x L_y, with
        C = c T_x, times (ratio - 1) for the region's."""
        base = values[POISSON] * self.coefficient("alpha_u", values) * self.aspect
        base = base * self.lengths[0] * self.lengths[1]
        return [
            base * (values[REGION_RATIO] - 1.0) if name.endswith(REGION_SUFFIX) else base
            for name in self.couplings
        ]

    def coupling_force(self, delta: ca.MX, values: dict):
        """The coupling's force on the free points (n_free, 3), or 0 when c is a fixed 0."""
        force = 0
        flat = ca.vec(delta)
        matrices = self._coupling_free.values()
        for c, matrix in zip(self.coupling_coefficients(values), matrices):
            if isinstance(c, float) and c == 0.0:
                continue
            force = force + c * ca.reshape(
                ca.mtimes(to_casadi_sparse(matrix), flat), self.n_free, 3
            )
        return force

    def coefficient(self, term: str, values: dict):
        """c_t of one term (a number or a CasADi expression): alpha_v tied to alpha_u when
        ``isotropic``, and a region term's c_t (ratio - 1) of its base term."""
        if term.endswith(REGION_SUFFIX):
            base = term[: -len(REGION_SUFFIX)]
            return self.coefficient(base, values) * (values[REGION_RATIO] - 1.0)
        if term == "alpha_v" and self.isotropic:
            return values["alpha_u"] * self.aspect**2 * values[ANISOTROPY]
        return values[term_parameter(term)]

    def coefficient_list(self, values: dict) -> list:
        """Coefficient of every term (numbers or CasADi expressions), in ``terms`` order."""
        return [self.coefficient(term, values) for term in self.terms]

    def membrane_tension(self, values: dict) -> tuple[float, float]:
        """(T_x, T_y) [N/mm] outside the region: alpha_u L_x / L_y, alpha_v L_y / L_x."""
        return (
            float(self.coefficient("alpha_u", values)) * self.aspect,
            float(self.coefficient("alpha_v", values)) / self.aspect,
        )

    def linear_terms(self, names: tuple[str, ...]) -> tuple[ca.MX, ca.MX, list[str]]:
        """As ``UnitTerms.linear_terms`` (the isotropy tie and the region terms through
        ``coefficient``); refused while the volumetric coupling is on, which no unit term
        of ``terms`` carries."""
        if POISSON in names or self.poisson != 0.0:
            raise NotImplementedError(
                "the slab's volumetric coupling (poisson) is not a unit term of eq. (18)"
            )
        return super().linear_terms(names)

    def symbolic_values(self, names: tuple[str, ...]) -> tuple[ca.MX, dict]:
        """As ``TissueModel.symbolic_values``; the extra parameters may be among the names."""
        names = tuple(names)
        known = set(PARAMETERS) | set(EXTRA_PARAMETERS)
        if set(names) - known or len(set(names)) != len(names):
            raise ValueError(f"parameter names must be distinct, from {sorted(known)}")
        x = ca.MX.sym("x", len(names))
        values: dict = {**self.parameters, **dict(self._extra())}
        values.update({name: x[i] for i, name in enumerate(names)})
        return x, values

    def elastic_force(self, delta: ca.MX, values: dict, symbolic: tuple[str, ...]) -> ca.MX:
        """K(B; x)(B - B0) on the free points (region terms included)."""
        coefficients = self.coefficient_list(values)
        coupling = self.coupling_force(delta, values)
        if not self.is_linear(symbolic):
            return coupling + self.edges().elastic_force(
                delta, ca.vertcat(*coefficients), values["k0"], self.stiffening
            )
        force = coupling
        for coefficient, matrix in zip(coefficients, self.terms.values()):
            if isinstance(coefficient, float) and coefficient == 0.0:
                continue
            block = to_casadi_sparse(self.free_block(matrix))
            force = force + coefficient * ca.mtimes(block, delta)
        return force

    # --------------------------------------------------------------- residual
    def _residual(self, names: tuple[str, ...]) -> ca.Function:
        """g(s, x, F_B, d) = [vec(K(B; x) Delta - F_B + C^T lam); vec(C Delta - Q d)]."""
        x, values = self.symbolic_values(names)
        rows = self._constraint_rows
        state = ca.MX.sym("s", 3 * (self.n_free + rows.shape[0]))
        force = ca.MX.sym("F_B", self.n_free, 3)
        prescribed = ca.MX.sym("d", rows.shape[1], 3)
        delta = ca.reshape(state[: 3 * self.n_free], self.n_free, 3)
        lam = ca.reshape(state[3 * self.n_free :], rows.shape[0], 3)
        coupling = to_casadi_sparse(self._constraint_free)
        elastic = self.elastic_force(delta, values, names)
        residual = elastic - force + ca.mtimes(coupling.T, lam)
        constraint = ca.mtimes(coupling, delta) - ca.mtimes(ca.DM(rows), prescribed)
        g = ca.vertcat(ca.vec(residual), ca.vec(constraint))
        return ca.Function("g", [state, x, force, prescribed], [g], ["s", "x", "F_B", "d"], ["g"])

    def state_residual(self, names: tuple[str, ...] = ()) -> ca.Function:
        """g(s, x, F_B, d), s = [vec(Delta_free); vec(lam)], with its Jacobian in closed form
        (built once per model and names: every stage and scan of the study reuses it)."""
        names = tuple(names)
        key = ("residual", names)
        if key not in self._fast:
            function = self._residual(names)
            self._fast[key] = ca.Function(
                "g",
                function.mx_in(),
                function.call(function.mx_in()),
                ["s", "x", "F_B", "d"],
                ["g"],
                {"custom_jacobian": self._jacobian(names), "jac_penalty": 0, "never_inline": True},
            )
        return self._fast[key]

    def jacobian_function(self, names: tuple[str, ...]) -> ca.Function:
        """(s, x, F_B, d) -> (dg/ds, dg/dx) in closed form, for a solver's own Newton loop."""
        names = tuple(names)
        key = ("jacobian", names)
        if key not in self._fast:
            full = self._jacobian(names)
            inputs = full.mx_in()
            outputs = full(*inputs[:4], ca.MX(full.size1_in(4), 1))
            self._fast[key] = ca.Function(
                "dg", inputs[:4], outputs[:2], ["s", "x", "F_B", "d"], ["dg_ds", "dg_dx"]
            )
        return self._fast[key]

    def _jacobian(self, names: tuple[str, ...]) -> ca.Function:
        """The custom Jacobian (s, x, F_B, d, out_g) -> dg/ds, dg/dx, dg/dF_B, dg/dd,
        built once per model and names.

        dg/ds = [[A, I3 (x) C^T], [I3 (x) C, 0]]; A = I3 (x) sum_t c_t K_t for the linear
        model, else -(I3 (x) G)^T W (I3 (x) G) over the edges (``_edge_weights``); its
        nonzeros are a fixed sparse map of [weights; 1]. dg/dx by forward AD (few columns).
        """
        key = ("custom jacobian", tuple(names))
        if key not in self._fast:
            self._fast[key] = self._build_jacobian(tuple(names))
        return self._fast[key]

    def _build_jacobian(self, names: tuple[str, ...]) -> ca.Function:
        x, values = self.symbolic_values(names)
        symbols = self._state_symbols()
        state, force, prescribed, _ = symbols
        n = 3 * self.n_free
        coupling = ca.vertcat(*self.coupling_coefficients(values))
        if self.is_linear(names):
            sparsity, mapping = self._pattern("linear")
            weights = ca.vertcat(*self.coefficient_list(values), coupling, ca.DM.ones(1))
        else:
            sparsity, mapping = self._pattern("edges")
            delta = ca.reshape(state[:n], self.n_free, 3)
            weights = ca.vertcat(self._edge_weights(delta, values), coupling, ca.DM.ones(1))
        d_s = ca.MX(sparsity, ca.mtimes(to_casadi_sparse(mapping), weights))
        d_x = ca.jacobian(self._residual(names)(state, x, force, prescribed), x)
        return self._jacobian_function(symbols, x, d_s, d_x)

    def _edge_weights(self, delta: ca.MX, values: dict) -> ca.MX:
        """The nine diagonals w_ij of d(tension)/d(relative displacement), stacked.

        With r = G Delta, q = rest + r, l = |q|, eps = l / L - 1 and the edge stiffness
        k = k_springs s(eps) + k_others, the tension is k r, so
        w_ij = d(tension_i)/d(r_j) = k delta_ij + r_i k_springs s'(eps) q_j / (L l).
        """
        edges = self.edges()
        n_edges = edges.incidence.shape[0]
        relative = ca.mtimes(to_casadi_sparse(edges.incidence), delta)
        current = ca.DM(edges.rest_vectors) + relative
        length = ca.sqrt(ca.sum2(current**2))
        rest_length = ca.DM(np.linalg.norm(edges.rest_vectors, axis=1))
        strain = (length - rest_length) / rest_length
        coefficients = ca.vertcat(*self.coefficient_list(values))
        springs = ca.mtimes(ca.DM(np.minimum(edges.values, 0.0)), coefficients)
        others = ca.mtimes(ca.DM(np.maximum(edges.values, 0.0)), coefficients)
        eps, k0 = ca.MX.sym("eps", n_edges), ca.MX.sym("k0")
        slope = ca.Function(
            "ds", [eps, k0], [ca.jtimes(self.stiffening(eps, k0), eps, ca.DM.ones(n_edges))]
        )
        stiffness = springs * self.stiffening(strain, values["k0"]) + others
        gain = springs * slope(strain, values["k0"]) / (rest_length * length)
        blocks = []
        for i in range(3):
            for j in range(3):
                w = gain * relative[:, i] * current[:, j]
                blocks.append(w + stiffness if i == j else w)
        return ca.vertcat(*blocks)

    def _pattern(self, kind: str) -> tuple[ca.Sparsity, sp.csr_matrix]:
        """Sparsity of dg/ds and the map P with nonzeros(dg/ds) = P [weights; c; 1].

        ``kind`` "linear": weights are the term coefficients c_t; "edges": the nine edge
        diagonals w_ij of ``_edge_weights``; c the coupling coefficients.
        """
        if kind in self._fast:
            return self._fast[kind]
        n_free = self.n_free
        if kind == "linear":
            entries = []
            for t, matrix in enumerate(self.terms.values()):
                block = sp.kron(sp.identity(3), self.free_block(matrix)).tocoo()
                entries.append((block.row, block.col, np.full(block.nnz, t), block.data))
            n_sources = len(self.terms)
        else:
            entries = self._edge_entries()
            n_sources = 9 * self.edges().incidence.shape[0]
        for matrix in self._coupling_free.values():
            block = matrix.tocoo()
            entries.append((block.row, block.col, np.full(block.nnz, n_sources), block.data))
            n_sources += 1
        coupling = sp.kron(sp.identity(3), self._constraint_free).tocoo()
        n = 3 * n_free
        constant = np.full(coupling.nnz, n_sources)
        entries.append((n + coupling.row, coupling.col, constant, coupling.data))
        entries.append((coupling.col, n + coupling.row, constant, coupling.data))
        rows, cols, sources, coefs = (np.concatenate(p) for p in zip(*entries))
        size = n + coupling.shape[0]
        linear_index = cols.astype(np.int64) * size + rows
        unique, position = np.unique(linear_index, return_inverse=True)
        mapping = sp.csr_matrix((coefs, (position, sources)), shape=(unique.size, n_sources + 1))
        pattern = sp.csc_matrix(
            (np.ones(unique.size), (unique % size, unique // size)), shape=(size, size)
        )
        pattern.sort_indices()
        sparsity = ca.Sparsity(size, size, pattern.indptr.tolist(), pattern.indices.tolist())
        self._fast[kind] = (sparsity, mapping)
        return self._fast[kind]

    def _edge_entries(self) -> list[tuple]:
        """(row, col, source, coefficient) of -(I3 (x) G)^T W (I3 (x) G) per block (i, j)."""
        incidence = self.edges().incidence.tocoo()
        n_edges, n_free = incidence.shape
        order = np.argsort(incidence.row, kind="stable")
        edge, node, sign = incidence.row[order], incidence.col[order], incidence.data[order]
        starts = np.searchsorted(edge, np.arange(n_edges))
        counts = np.bincount(edge, minlength=n_edges)
        pairs = []  # every ordered pair of free ends of one edge
        for i in range(2):
            for j in range(2):
                e = np.flatnonzero(counts > max(i, j))
                a, b = starts[e] + i, starts[e] + j
                pairs.append((e, node[a], node[b], -sign[a] * sign[b]))
        e, a, b, s = (np.concatenate(p) for p in zip(*pairs))
        return [
            (i * n_free + a, j * n_free + b, (3 * i + j) * n_edges + e, s)
            for i in range(3)
            for j in range(3)
        ]


def coupling_matrix(
    basis, lengths: tuple[float, float], weight: Field | None = None, extra_points: int = 0
) -> sp.csr_matrix:
    """integral chi D^T D over [0, 1]^3 with D vec(Delta) = du_x/dx + du_y/dy, (3n, 3n).

    D = [J_u / L_x, J_v / L_y, 0] (the map (u, v) -> (x, y) is linear); chi = 1 by
    default, else a field such as the region's indicator.
    """
    points, weights = quadrature(basis, extra_points)
    if weight is not None:
        weights = weights * np.asarray(weight(points), dtype=float).reshape(-1)
    d_x = basis.collocation(points, (1, 0, 0)) / lengths[0]
    d_y = basis.collocation(points, (0, 1, 0)) / lengths[1]
    n = d_x.shape[1]
    d = sp.hstack([d_x, d_y, sp.csr_matrix((len(points), n))]).tocsr()
    gram = (d.T @ sp.diags(weights) @ d).tocsr()
    return (0.5 * (gram + gram.T)).tocsr()
