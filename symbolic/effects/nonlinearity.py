"""``nonlinear_stiffening``: strain stiffening, the one effect of that name for every base
energy that can carry it (docs/effects.md, "The effects").

- On the paper's energy (and the real skin's slab), k0 of eq. (1) (``NonlinearStiffening``).
- On the large-strain continuum (``--energy neo-hookean``), k1 of the isochoric exponential
  term of eq. (C10) at the exponent k2 of the model's parameters (default 10)
  (``ContinuumStiffening``): the stiffening that the real skin's continuum needs, and that
  a small-strain continuum cannot carry (it is not offered there).

Both are zero at theta = 0 for every state, with a null value of 0 and a one-sided test.

**Eq. (1).** On top of the model's own k0 (default 0), the effect adds to K(B; x)(B - B0)

    F = -G^T (w * (G Delta)),    w = k_s (s(eps; k0_model + k0) - s(eps; k0_model)),
    eps = (|r0 + G Delta| - L) / L,   k_s = (negative part of K_t[a, b]) . c,

with the signed incidence matrix G of ``symbolic.stiffening.EdgeSet``, rest
edge vectors r0 and lengths L, and the term coefficients c (alpha_u, ...,
beta): the spring-only split of eq. (1) (**choice**, docs/model.md). F = 0 at
k0 = 0 for every Delta.

Differentiating F through CasADi's automatic differentiation costs ~35 ms per
Jacobian on the default grid (thousands of edges, a colouring of ~100
directions), so the Function carries its Jacobian in closed form: with
a = r0 + G Delta, q = k_s (s_eps(k0_model + k0) - s_eps(k0_model)) / (L |a|),

    dF_i / dDelta_j = -G^T diag(delta_ij w + q rel_i a_j) G,    rel = G Delta,

and dF/dc, dF/dk0 likewise (``tests/test_effects.py`` checks them against
finite differences).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.continuum import KPA
from symbolic.effects.base import CaseSymbols, Effect, linear_coefficient
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.numericforce import NumericStiffening, gram_layout
from symbolic.hyperelastic import NeoHookeanForce
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


def _stiffening_parts(stiffening, n_edges: int) -> ca.Function:
    """(eps, k) -> (s, ds/deps, ds/dk) elementwise over the edges."""
    strain = ca.MX.sym("eps", n_edges)
    k = ca.MX.sym("k")
    value = stiffening(strain, k)
    slope = ca.diag(ca.jacobian(value, strain))
    return ca.Function("s_parts", [strain, k], [value, slope, ca.jacobian(value, k)])


def _gram_map(incidence: sp.csr_matrix) -> tuple[ca.Sparsity, ca.DM]:
    """Pattern of G^T diag(c) G and the matrix M with nonzeros(G^T diag(c) G) = M c."""
    pattern, mapping = gram_layout(incidence)
    sparsity = ca.Sparsity(
        pattern.shape[0], pattern.shape[1], pattern.indptr.tolist(), pattern.indices.tolist()
    )
    return sparsity, to_casadi_sparse(mapping)


def stiffening_force(model: TissueModel) -> ca.Function:
    """F(delta, c, k, kb) of the module docstring, with a custom closed-form Jacobian."""
    return _stiffening(model)[0]


def _stiffening(model: TissueModel) -> tuple[ca.Function, ca.Function]:
    """``stiffening_force`` and its tangent dF/dDelta(delta, c, k, kb) alone,
    (3 n_free, 3 n_free): what Newton needs, without the parameter columns the custom
    Jacobian also computes."""
    edges = model.edges()
    n_free, n_terms = model.n_free, edges.values.shape[1]
    incidence = to_casadi_sparse(edges.incidence)
    springs_of = ca.DM(np.minimum(edges.values, 0.0))
    rest = ca.DM(edges.rest_vectors)
    rest_length = ca.DM(np.linalg.norm(edges.rest_vectors, axis=1))
    parts = _stiffening_parts(model.stiffening, edges.values.shape[0])
    gram_sparsity, gram_map = _gram_map(sp.csr_matrix(edges.incidence))

    def pieces(delta, c, k, kb):
        relative = ca.mtimes(incidence, delta)
        vectors = rest + relative
        length = ca.sqrt(ca.sum2(vectors**2))
        strain = (length - rest_length) / rest_length
        s1, s1_eps, s1_k = parts(strain, kb + k)
        s0, s0_eps, s0_k = parts(strain, kb)
        springs = ca.mtimes(springs_of, c)
        return relative, vectors, length, springs, (s1, s1_eps, s1_k), (s0, s0_eps, s0_k)

    def edge_sum(weights, relative):
        return -ca.mtimes(incidence.T, ca.repmat(weights, 1, 3) * relative)

    inputs = [
        ca.MX.sym("delta", n_free, 3),
        ca.MX.sym("c", n_terms),
        ca.MX.sym("k"),
        ca.MX.sym("kb"),
    ]
    relative, vectors, length, springs, new, old = pieces(*inputs)
    force = edge_sum(springs * (new[0] - old[0]), relative)
    weight = springs * (new[0] - old[0])
    q = springs * (new[1] - old[1]) / (rest_length * length)
    blocks = []
    for i in range(3):
        row = []
        for j in range(3):
            diagonal = q * relative[:, i] * vectors[:, j] + (weight if i == j else 0)
            row.append(-ca.MX(gram_sparsity, ca.mtimes(gram_map, diagonal)))
        blocks.append(row)
    d_delta = ca.blockcat(blocks)
    change = new[0] - old[0]
    d_c = ca.vertcat(
        *[
            -ca.mtimes(incidence.T, ca.repmat(relative[:, i] * change, 1, n_terms) * springs_of)
            for i in range(3)
        ]
    )
    d_k = ca.vec(edge_sum(springs * new[2], relative))
    d_kb = ca.vec(edge_sum(springs * (new[2] - old[2]), relative))
    names = ["delta", "c", "k", "kb"]
    jacobian = ca.Function(
        "jac_stiffening_force",
        inputs + [ca.MX.sym("out_F", n_free, 3)],
        [d_delta, d_c, d_k, d_kb],
        names + ["out_F"],
        [f"jac_F_{n}" for n in names],
    )
    force = ca.Function(
        "stiffening_force",
        inputs,
        [force],
        names,
        ["F"],
        {"custom_jacobian": jacobian, "jac_penalty": 0, "never_inline": True},
    )
    return force, ca.Function("stiffening_tangent", inputs, [d_delta], names, ["dF_ddelta"])


class NonlinearStiffening(Effect):
    """k0 [1] of eq. (1): K_ab(B) = K0_ab s(eps_ab) on spring-like pairs, s = 1 + k0 eps^2.

    Realistic magnitude 200: the edge stiffness doubles at about 7 % strain
    (skin's stress-strain curve is J-shaped; its tangent stiffness grows
    tenfold or more over the first 30 % of strain).
    """

    name = "nonlinear_stiffening"
    parameters = (Parameter("k0", "1", 10.0, 0.0, 1000.0),)
    magnitude = Magnitude(200.0, "1")
    equation = "K_ab(B) = K0_ab (1 + k0 eps_ab^2) on spring-like pairs (eq. 1)"
    energies = ("dnurbs",)

    def internal_force(self, model: TissueModel, symbols: CaseSymbols, theta):
        return self._call(model, symbols, theta, 0)

    def internal_tangent(self, model: TissueModel, symbols: CaseSymbols, theta):
        return self._call(model, symbols, theta, 1)

    def numeric_force(self, model: TissueModel, values: dict, theta):
        """q = (c, k0, the model's k0) and ``NumericStiffening``."""
        coefficients = [linear_coefficient(model, values, t) for t in model.terms]

        def build():
            parts = _stiffening_parts(model.stiffening, model.edges().values.shape[0])
            return NumericStiffening(model, parts)

        arguments = ca.vertcat(*coefficients, theta[0], values["k0"])
        return arguments, self.cached(model, "numeric", build)

    def _call(self, model: TissueModel, symbols: CaseSymbols, theta, which: int):
        """The force (0) or its tangent (1) at the case's Delta and coefficients."""
        function = self.cached(model, "stiffening", lambda: _stiffening(model))[which]
        coefficients = ca.vertcat(
            *[linear_coefficient(model, symbols.values, t) for t in model.terms]
        )
        return function(symbols.delta, coefficients, theta[0], symbols.values["k0"])


class ContinuumStiffening(Effect):
    """k1 [kPa] of eq. (C10) on the neo-Hookean continuum: the internal force gains the
    exponential term's, eq. (C8) with the stress of eq. (C11) alone (mu_L = lambda = 0),

        f_exp = integral P_exp(F; k1, k2) dN/dx dV,

    at the model's exponent k2 [1] (``symbolic.parameters``, default 10). Zero at k1 = 0
    for every state, and its stress and tangent vanish at rest, so the small-strain E and
    nu stay the base model's. Realistic magnitude 20 kPa: at k2 = 10 a tissue of E = 20
    kPa doubles its tangent modulus at about 10 % stretch.
    """

    name = "nonlinear_stiffening"
    parameters = (Parameter("k1", "kPa", 10.0, 0.0, 1000.0),)
    magnitude = Magnitude(20.0, "kPa")
    equation = "W += k1 / (2 k2) (exp(k2 (Ibar1 - 3)^2) - 1) (eq. C10)"
    energies = ("neo-hookean",)

    def internal_force(self, model: TissueModel, symbols: CaseSymbols, theta):
        def build():
            operators = [p[:, model.free] for p in model.gradient.operators]
            return NeoHookeanForce(operators, model.gradient.volume, exponential=True)

        force = self.cached(model, "exponential", build)
        return force(symbols.delta, 0.0, 0.0, KPA * theta[0], symbols.values["k2"])
