"""The compressible neo-Hookean energy in the volume spline (docs/continuum.md).

For strains beyond a few per cent (real skin under an extensometer: 10-15 %) the
linear energy of eq. (C1) is replaced by the compressible neo-Hookean

    W(F) = mu_L/2 (tr(F^T F) - 3) - mu_L ln J + lambda/2 (ln J)^2,                 (C6)

with F = I + grad u the deformation gradient (grad in physical rest coordinates, eq.
C2) and J = det F. Its first Piola-Kirchhoff stress is

    P = dW/dF = mu_L F + (lambda ln J - mu_L) F^-T,                                   (C7)

and the internal force on control point a, component i, is

    f_ai = integral P_ij(F) dN_a/dx_j dV          (Gauss rule of ``PhysicalGradient``). (C8)

At F = I, P linearises to mu_L (H + H^T) + lambda tr(H) I, H = grad u: the stress of
eq. (C1) with the same Lame pair, so the tangent of (C8) at rest is K(x) of eq. (C3)
(tested). The tangent elsewhere, dP/dF, is

    A_ijkl = mu_L d_ik d_jl + lambda a_ij a_kl + (mu_L - lambda ln J) a_il a_kj,  a = F^-T. (C9)

The pointwise stress is a CasADi SX Function mapped over the quadrature points; the
gradients are sparse operators on the control points, so the whole force is one MX
expression that both inverse methods differentiate.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.sparse import pattern_entries, to_casadi_sparse


def _cofactor(f: list[list]) -> list[list]:
    """cof(F) of a 3 x 3 nested list (works on numbers and CasADi expressions)."""
    return [
        [
            f[(i + 1) % 3][(j + 1) % 3] * f[(i + 2) % 3][(j + 2) % 3]
            - f[(i + 1) % 3][(j + 2) % 3] * f[(i + 2) % 3][(j + 1) % 3]
            for j in range(3)
        ]
        for i in range(3)
    ]


def piola_stress() -> ca.Function:
    """P(H, mu_L, lambda) of eq. (C7) for one point: H = grad u row-major (9,), P (9,).

    J <= 0 (an inverted element) gives NaN, which the Newton line search rejects.
    """
    h = ca.SX.sym("H", 9)
    mu_l, lam = ca.SX.sym("mu_L"), ca.SX.sym("lambda")
    f = [[h[3 * i + j] + (1.0 if i == j else 0.0) for j in range(3)] for i in range(3)]
    cof = _cofactor(f)  # J F^-T
    det = f[0][0] * cof[0][0] + f[0][1] * cof[0][1] + f[0][2] * cof[0][2]
    log_det = ca.log(det)
    stress = [
        mu_l * f[i][j] + (lam * log_det - mu_l) * cof[i][j] / det
        for i in range(3)
        for j in range(3)
    ]
    return ca.Function("P", [h, mu_l, lam], [ca.vertcat(*stress)], ["H", "mu_L", "lambda"], ["P"])


def neo_hookean_energy_density(gradient: np.ndarray, mu_l: float, lam: float) -> np.ndarray:
    """W of eq. (C6) [N/mm^2] for displacement gradients (n_q, 3, 3), numpy."""
    f = np.eye(3) + np.asarray(gradient, dtype=float)
    det = np.linalg.det(f)
    return (
        0.5 * mu_l * (np.einsum("qij,qij->q", f, f) - 3.0)
        - mu_l * np.log(det)
        + (0.5 * lam * np.log(det) ** 2)
    )


class NeoHookeanForce:
    """The internal force of eq. (C8) on a set of control points, as a CasADi expression.

    Parameters
    ----------
    operators : tuple of scipy.sparse matrices
        P_j (n_q, n): d/dx_j at the quadrature points of a scalar spline with values on
        the chosen control points (``PhysicalGradient.operators``, columns restricted).
    volume : numpy.ndarray
        Quadrature weight times |det G| at each point [mm^3].
    """

    def __init__(self, operators, volume: np.ndarray):
        self.n_points = int(operators[0].shape[0])
        self._operators = [to_casadi_sparse(sp.csr_matrix(p)) for p in operators]
        self._volume = ca.DM(np.asarray(volume, dtype=float))
        self._stress = piola_stress().map(self.n_points)

    def gradient(self, delta: ca.MX) -> ca.MX:
        """grad u at the points, (9, n_q) with rows (i, j) -> 3 i + j, i the component."""
        columns = [ca.mtimes(p, delta) for p in self._operators]  # columns[j][q, i] = du_i/dx_j
        return ca.vertcat(*[columns[j][:, i].T for i in range(3) for j in range(3)])

    def __call__(self, delta: ca.MX, mu_l, lam) -> ca.MX:
        """f (n, 3) [N] of eq. (C8) for displacements delta (n, 3) [mm], Lame pair [N/mm^2]."""
        stress = self._stress(self.gradient(delta), mu_l, lam)  # (9, n_q)
        force = 0
        for j, operator in enumerate(self._operators):
            weighted = ca.horzcat(*[stress[3 * i + j, :].T for i in range(3)]) * ca.repmat(
                self._volume, 1, 3
            )
            force = force + ca.mtimes(operator.T, weighted)
        return force


class NeoHookeanTangent:
    """The tangent stiffness d f / d Delta of eq. (C8) with (C9), assembled in numpy.

    CasADi's coloured AD of eq. (C8) costs seconds per Jacobian on a 13x13x4 grid (a
    few hundred colours); this assembly groups the Gauss points by knot-span element
    and does two batched products per element. With a = F^-T and the local gradients
    g_q = dN_a/dx at a point, d_ai = sum_j a_ij g_aj and

        K = mu_L I3 (x) integral grad N . grad N^T dV                (constant)
          + sum_q w_q lambda d_ai d_bk                               at ((a, i), (b, k))
          + sum_q w_q (mu_L - lambda ln J) d_ak d_bi                 at ((a, i), (b, k)).

    Rows and columns are the stacked unknowns of ``TissueModel.state_residual``: the x
    components of the chosen points first, then y, then z.

    Parameters
    ----------
    values : scipy.sparse matrix
        N_a at the Gauss points, (n_q, n): its pattern gives each point's support.
    operators, volume
        As ``NeoHookeanForce``, on every control point (n columns).
    chosen : numpy.ndarray
        The control points that are unknowns (the free ones).
    """

    def __init__(self, values, operators, volume: np.ndarray, chosen: np.ndarray):
        values = sp.csr_matrix(values)
        values.sort_indices()
        n_q, n = values.shape
        counts = np.diff(values.indptr)
        if np.any(counts != counts[0]):
            raise ValueError("every Gauss point must lie inside one knot span")
        support = values.indices.reshape(n_q, counts[0])
        elements, inverse = np.unique(support, axis=0, return_inverse=True)
        order = np.argsort(inverse.ravel(), kind="stable")
        self.n_elements, self.k = elements.shape
        self.points_per_element = n_q // self.n_elements
        self._support = support[order]
        rows, cols = np.repeat(np.arange(n_q), self.k), support.ravel()
        self._g = np.stack(
            [np.asarray(sp.csr_matrix(p)[rows, cols]).reshape(n_q, self.k) for p in operators],
            axis=-1,
        )[order]  # (n_q, k, 3)
        self._w = np.asarray(volume, dtype=float)[order]
        self._scatter(elements, np.asarray(chosen), n, operators, volume)

    def _scatter(self, elements, chosen, n, operators, volume) -> None:
        """The pattern on the chosen unknowns and where each local entry lands in it."""
        index = np.full(3 * n, -1)
        m = chosen.size
        for i in range(3):
            index[i * n + chosen] = i * m + np.arange(m)
        local = (np.arange(3)[None, None, :] * n + elements[:, :, None]).reshape(
            self.n_elements, -1
        )  # (e, (a, i)) -> global dof
        local = index[local]
        size = local.shape[1]
        rows = np.repeat(local, size, axis=1).ravel()
        cols = np.tile(local, (1, size)).ravel()
        self._keep = (rows >= 0) & (cols >= 0)
        keys = cols[self._keep].astype(np.int64) * (3 * m) + rows[self._keep]
        unique, self._position = np.unique(keys, return_inverse=True)
        self.shape = (3 * m, 3 * m)
        self._indices = (unique % (3 * m)).astype(np.int32)
        self._indptr = np.searchsorted(unique // (3 * m), np.arange(3 * m + 1)).astype(np.int32)
        laplace = sum(sp.csr_matrix(p).T @ sp.diags(volume) @ sp.csr_matrix(p) for p in operators)
        laplace = sp.kron(sp.identity(3), sp.csr_matrix(laplace)[chosen][:, chosen])
        pattern = sp.csc_matrix(
            (np.ones(unique.size), self._indices, self._indptr), shape=self.shape
        )
        self._laplace = pattern_entries(pattern, laplace)

    def __call__(self, delta: np.ndarray, mu_l: float, lam: float) -> sp.csc_matrix:
        """K_T at displacements delta (n, 3) [mm] on every control point, (3 m, 3 m) [N/mm]."""
        local_delta = np.asarray(delta, dtype=float)[self._support]  # (n_q, k, 3): [q, a, i]
        f = np.eye(3) + np.einsum("qai,qaj->qij", local_delta, self._g)
        det = np.linalg.det(f)
        if np.any(det <= 0):
            raise ValueError("the deformation inverts the material (det F <= 0)")
        a = np.linalg.inv(f).transpose(0, 2, 1)
        shape = (self.n_elements, self.points_per_element, 3 * self.k)
        d = np.einsum("qij,qaj->qai", a, self._g).reshape(shape)  # [e, q, (a, i)]
        c1 = (self._w * lam).reshape(shape[:2])[:, :, None]
        c2 = (self._w * (mu_l - lam * np.log(det))).reshape(shape[:2])[:, :, None]
        first = np.matmul((d * c1).transpose(0, 2, 1), d)  # [(a, i), (b, k)]
        second = np.matmul((d * c2).transpose(0, 2, 1), d)  # [(a, k), (b, i)]
        second = second.reshape(-1, self.k, 3, self.k, 3).transpose(0, 1, 4, 3, 2)
        local = (first + second.reshape(first.shape)).reshape(self.n_elements, -1)
        data = np.bincount(
            self._position, weights=local.ravel()[self._keep], minlength=self._indices.size
        )
        return sp.csc_matrix((data + mu_l * self._laplace, self._indices, self._indptr), self.shape)
