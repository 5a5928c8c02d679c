"""The second derivative of the hyperelastic force along a weight (docs/continuum.md).

The Hessian of the simultaneous inverse's Lagrangian needs, per load case, the
curvature of w . f(Delta) for the force f of eq. (C8) and a weight w on the free
control points (the case's equilibrium multipliers). With the first Piola-Kirchhoff
stress P of eq. (C7) [+ C11] [+ C14] at the Gauss points,

    w . f(Delta) = sum_q w_q P(F_q) : G_q,      G_q = grad w at q,

so that

    d2(w . f) / dDelta_ai dDelta_bk = sum_q w_q sum_jl dN_a/dx_j M^q_ijkl dN_b/dx_l,
    M^q = d2(P(F) : G_q) / dF dF   at F = F_q.

For the neo-Hookean stress alone, with a = F^-T, l = ln J, B = a G^T a and s = G : a,
differentiating (C9) with da_ij/dF_mn = -a_in a_mj and d(ln J)/dF_mn = a_mn gives

    M_klmn = -lambda (a_kl B_mn + B_kl a_mn) - lambda s a_kn a_ml
             - (mu_L - lambda l) (a_ml B_kn + a_kn B_ml),                           (C15)

evaluated in numpy. With the exponential or fibre terms M^q is CasADi's exact Hessian
of one point's stress (``piola_stress``, SX), mapped over the points. The sum over the
points is ``NeoHookeanTangent.assemble``: element-batched products on the tangent's
pattern. Coloured AD of the whole force instead pushes a few hundred seeds through the
sparse gradient operators.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.hyperelastic import NeoHookeanTangent, piola_stress


def stress_curvature(exponential: bool = False, fibres: bool = False) -> ca.Function:
    """(H, G, coefficients...) -> M = d2(P(H) : G)/dH2 for one point, (81,).

    H = grad u and G row-major (9,) as in ``piola_stress``, whose coefficients follow
    (mu_L, lambda[, k1, k2][, kf1, kf2, phi]); M is the (9, 9) Hessian, symmetric, so
    its row- and column-major flattenings agree.
    """
    stress = piola_stress(exponential, fibres)
    h, g = ca.SX.sym("H", 9), ca.SX.sym("G", 9)
    coefficients = [ca.SX.sym(name) for name in stress.name_in()[1:]]
    work = ca.dot(stress(h, *coefficients), g)
    curvature = ca.densify(ca.vec(ca.hessian(work, h)[0]))
    names = ["H", "G", *stress.name_in()[1:]]
    return ca.Function("M", [h, g, *coefficients], [curvature], names, ["M"])


class ForceCurvature:
    """d2(w . f)/dDelta2 of the force of eq. (C8), on ``tangent``'s pattern (numpy, CSC).

    Parameters
    ----------
    tangent : NeoHookeanTangent
        The tangent of the same force: its Gauss points grouped by element, its
        pattern on the chosen control points.
    exponential, fibres : bool
        The stress terms of eq. (C11) and (C14), as in ``NeoHookeanForce``.
    """

    def __init__(self, tangent: NeoHookeanTangent, exponential: bool = False, fibres: bool = False):
        self.tangent = tangent
        self._pointwise = None  # the neo-Hookean stress: eq. (C15) in numpy
        if exponential or fibres:
            n_points = tangent.n_elements * tangent.points_per_element
            self._pointwise = stress_curvature(exponential, fibres).map(n_points)

    def __call__(self, delta: np.ndarray, weight: np.ndarray, *coefficients) -> sp.csc_matrix:
        """The curvature at displacements ``delta`` (n, 3) [mm] along ``weight`` (n, 3)
        on every control point, (3 m, 3 m); ``coefficients`` as ``NeoHookeanForce``
        takes them after Delta [N/mm^2, 1, rad]."""
        h = self.tangent.point_gradients(delta)
        g = self.tangent.point_gradients(weight)
        if self._pointwise is None:
            return self.tangent.assemble(neo_hookean_curvature(h, g, *coefficients))
        h, g = h.reshape(-1, 9), g.reshape(-1, 9)
        moduli = self._pointwise(h.T, g.T, *coefficients).full()  # (81, n_q)
        return self.tangent.assemble(moduli.T.reshape(-1, 3, 3, 3, 3))


def neo_hookean_curvature(h: np.ndarray, g: np.ndarray, mu_l: float, lam: float) -> np.ndarray:
    """M of eq. (C15), (n_q, 3, 3, 3, 3) [N/mm^2], for displacement gradients ``h`` and
    weight gradients ``g`` (n_q, 3, 3) and the Lame pair [N/mm^2]."""
    f = np.eye(3) + h
    a = np.linalg.inv(f).transpose(0, 2, 1)
    with np.errstate(invalid="ignore"):  # an inverted element: NaN, as the CasADi force
        log_det = np.log(np.linalg.det(f))
    b = a @ g.transpose(0, 2, 1) @ a
    s = np.einsum("qij,qij->q", g, a)
    a_t, b_t = a.transpose(0, 2, 1), b.transpose(0, 2, 1)
    first = a[:, :, :, None, None] * b[:, None, None] + b[:, :, :, None, None] * a[:, None, None]
    crossed = a[:, :, None, None, :] * a_t[:, None, :, :, None]  # a_kn a_ml
    mixed = b[:, :, None, None, :] * a_t[:, None, :, :, None]  # B_kn a_ml
    mixed += a[:, :, None, None, :] * b_t[:, None, :, :, None]  # a_kn B_ml
    per_point = (-1, 1, 1, 1, 1)
    return (
        -lam * first
        - (lam * s).reshape(per_point) * crossed
        - (mu_l - lam * log_det).reshape(per_point) * mixed
    )
