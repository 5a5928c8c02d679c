"""The D-NURBS stiffness as unit terms acting componentwise on the free points:
A(x) = I3 (x) sum_t c_t(x) K_t (docs/model.md, eqs. 11-18).

``UnitTerms`` holds the methods the linear path of the solvers calls on a model
(``linear_terms``, ``term_columns``, ``free_term``, ``stiffness_expression``);
``symbolic.model.TissueModel`` inherits them and supplies what they read: ``terms``
(name -> K_t on all control points), ``parameters``, ``symbolic_values``,
``free_block``, ``n_free`` and the ``_term_cache`` dict. The continuum models
(``symbolic.continuum_model``) override them with their own terms.
"""

from __future__ import annotations

import casadi as ca
import scipy.sparse as sp

from symbolic.sparse import combination, combined, to_casadi_sparse


def term_parameter(term: str) -> str:
    """The parameter that multiplies a stiffness term: alpha_u -> alpha_u, beta_uv -> beta."""
    return "beta" if term.startswith("beta_") else term


class UnitTerms:
    """The unit-term assembly of a model's linear stiffness (see the module docstring)."""

    def coefficient(self, term: str, values: dict):
        """c_t, the coefficient of the unit term K_t in eq. (18) [N/mm per unit K_t]: by
        default its parameter, ``values[term_parameter(term)]`` (alpha_u for alpha_u, beta
        for beta_uv); a model that ties parameters (``SkinSlabModel``'s in-plane isotropy)
        overrides it, and every reader of a term's coefficient goes through it. A number
        or a CasADi expression, as the entries of ``values`` are."""
        return values[term_parameter(term)]

    def linear_terms(self, names: tuple[str, ...]) -> tuple[ca.MX, ca.MX, list[str]]:
        """The linear model as A(x) = sum_t c_t(x) (I3 (x) K_t) on the free points (eq. 11-18).

        Returns
        -------
        x : casadi.MX
            The estimated parameters (symbols, natural units).
        coefficients : casadi.MX
            c_t(x), one per term whose coefficient is not a fixed zero.
        terms : list of str
            Those terms; ``free_term(t)`` gives I3 (x) K_t on the free points.
        """
        x, values = self.symbolic_values(names)
        # terms whose coefficient is a fixed zero (beta = 0 by default) contribute nothing
        pairs = [(t, self.coefficient(t, values)) for t in self.terms]
        pairs = [(t, c) for t, c in pairs if not (isinstance(c, float) and c == 0.0)]
        coefficients = ca.vertcat(*[c for _, c in pairs])
        return x, coefficients, [t for t, _ in pairs]

    def term_columns(self, terms: list[str], vector: ca.MX) -> ca.MX:
        """[(I3 (x) K_t) v]_t for a vector v on the free points, (3 n_free, n_terms).

        K_t acts on the (n_free, 3) matrix of v's x, y and z parts, which is
        I3 (x) K_t on vec; each column is dg/dc_t of the linear model at Delta = v.
        """
        matrix = ca.reshape(vector, self.n_free, 3)
        return ca.horzcat(*[ca.vec(ca.mtimes(self.free_term(t, "dm"), matrix)) for t in terms])

    def free_term(self, term: str, form: str = "kron"):
        """K_t restricted to the free control points, built once per model and form.

        ``form`` is "kron" for I3 (x) K_t as scipy CSC (3 n_free, 3 n_free), "dm"
        for K_t alone as a CasADi DM (n_free, n_free); apply the latter to the
        (n_free, 3) displacement matrix, which is I3 (x) K_t on its vec.
        """
        key = (term, form)
        if key not in self._term_cache:
            block = self.free_block(self.terms[term])
            if form == "kron":
                block = sp.kron(sp.identity(3), block).tocsc()
            self._term_cache[key] = block if form == "kron" else to_casadi_sparse(block)
        return self._term_cache[key]

    def stiffness_expression(self, coefficients: ca.MX, terms: list[str]) -> ca.MX:
        """A(x) = I3 (x) sum_t c_t K_t on the free points, (3 n_free, 3 n_free), assembled
        from the nonzeros of the unit terms (vec stacks the components)."""
        blocks = [self.free_block(self.terms[t]) for t in terms]
        return ca.diagcat(*[combined(combination(blocks), coefficients)] * 3)  # one x, y, z
