"""The large-strain energies in the volume spline: neo-Hookean and exponential (docs/continuum.md).

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

**Strain stiffening** (``exponential``: skin stiffens as its collagen is recruited). The
isotropic exponential term of Holzapfel-Gasser-Ogden type, in the isochoric invariant,
is added to eq. (C6):

    W_exp = k1 / (2 k2) (exp(k2 s^2) - 1),   s = Ibar1 - 3,   Ibar1 = J^(-2/3) tr(F^T F),  (C10)

k1 [N/mm^2] and k2 [1] (the limit k2 -> 0 is k1/2 s^2). **Choice**: the isochoric
Ibar1 - 3 is zero at rest and quadratic in the deviatoric strain, so W_exp, its stress
and its tangent all vanish at rest: the small-strain E and nu are those of eq. (C6)
alone, and the term is a pure stiffening (quartic at small strain). An exponent in
I1 - 3 instead would add a bulk stiffness at rest that trades with nu (measured on the
planar model, docs/realskin.md). With a = F^-T, e = exp(k2 s^2), W1 = k1 s e,
W11 = k1 e (1 + 2 k2 s^2) and g = dIbar1/dF = J^(-2/3) (2 F - 2/3 tr(F^T F) a),

    P_exp = W1 g,                                                                     (C11)

    A_exp = W11 g (x) g + 2 W1 J^(-2/3) [ d_ik d_jl - 2/3 (F_ij a_kl + a_ij F_kl)
            + 2/9 I1 a_ij a_kl + 1/3 I1 a_il a_kj ],         I1 = tr(F^T F).          (C12)

**A fibre family** (``fibres``: collagen along Langer's lines). One family of fibres in
the skin's plane, a0 = (cos phi, sin phi, 0), that resists only stretch (the
Gasser-Ogden-Holzapfel form):

    W_f = kf1 / (2 kf2) (exp(kf2 e^2) - 1),   e = <I4 - 1>,   I4 = |F a0|^2,            (C13)

<.> the positive part (fibres buckle in compression). With W1 = kf1 e exp(kf2 e^2) and
W11 = kf1 exp(kf2 e^2) (1 + 2 kf2 e^2) where e > 0 (both 0 elsewhere),

    P_f = 2 W1 (F a0) a0^T,    A_f = 4 W11 (F a0)_i a0_j (F a0)_k a0_l + 2 W1 d_ik a0_j a0_l.  (C14)

Zero at rest with its stress and tangent, like eq. (C10): the small-strain E and nu stay
those of eq. (C6), and kf1 = 0 is the model without fibres.

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


def piola_stress(exponential: bool = False, fibres: bool = False) -> ca.Function:
    """P(H, mu_L, lambda[, k1, k2][, kf1, kf2, phi]) of eq. (C7) [+ C11] [+ C14] for one
    point: H = grad u row-major (9,), P (9,) [N/mm^2]; ``exponential`` adds the inputs k1
    [N/mm^2], k2; ``fibres`` kf1 [N/mm^2], kf2 and the fibre angle phi [rad].

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
    inputs, names = [h, mu_l, lam], ["H", "mu_L", "lambda"]
    if exponential:
        k1, k2 = ca.SX.sym("k1"), ca.SX.sym("k2")
        first = sum(f[i][j] ** 2 for i in range(3) for j in range(3))
        scale = det ** (-2.0 / 3.0)
        s = scale * first - 3.0
        w1 = k1 * s * ca.exp(k2 * s**2)
        stress = [
            stress[3 * i + j] + w1 * scale * (2.0 * f[i][j] - 2.0 / 3.0 * first * cof[i][j] / det)
            for i in range(3)
            for j in range(3)
        ]
        inputs, names = inputs + [k1, k2], names + ["k1", "k2"]
    if fibres:
        kf1, kf2, phi = ca.SX.sym("kf1"), ca.SX.sym("kf2"), ca.SX.sym("phi")
        a0 = [ca.cos(phi), ca.sin(phi), 0.0]
        fa = [sum(f[i][j] * a0[j] for j in range(3)) for i in range(3)]  # F a0
        e = ca.fmax(sum(v**2 for v in fa) - 1.0, 0.0)
        w1 = kf1 * e * ca.exp(kf2 * e**2)
        stress = [stress[3 * i + j] + 2.0 * w1 * fa[i] * a0[j] for i in range(3) for j in range(3)]
        inputs, names = inputs + [kf1, kf2, phi], names + ["kf1", "kf2", "phi"]
    return ca.Function("P", inputs, [ca.vertcat(*stress)], names, ["P"])


def neo_hookean_energy_density(gradient: np.ndarray, mu_l: float, lam: float) -> np.ndarray:
    """W of eq. (C6) [N/mm^2] for displacement gradients (n_q, 3, 3), numpy."""
    f = np.eye(3) + np.asarray(gradient, dtype=float)
    det = np.linalg.det(f)
    return (
        0.5 * mu_l * (np.einsum("qij,qij->q", f, f) - 3.0)
        - mu_l * np.log(det)
        + (0.5 * lam * np.log(det) ** 2)
    )


def exponential_energy_density(gradient: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """W_exp of eq. (C10) [N/mm^2] for displacement gradients (n_q, 3, 3), numpy;
    k1 [N/mm^2], k2 [1] (k2 = 0: the limit k1/2 s^2)."""
    f = np.eye(3) + np.asarray(gradient, dtype=float)
    s = np.linalg.det(f) ** (-2.0 / 3.0) * np.einsum("qij,qij->q", f, f) - 3.0
    if k2 == 0.0:
        return 0.5 * k1 * s**2
    return 0.5 * k1 / k2 * np.expm1(k2 * s**2)


def fibre_energy_density(gradient: np.ndarray, kf1: float, kf2: float, phi: float) -> np.ndarray:
    """W_f of eq. (C13) [N/mm^2] for displacement gradients (n_q, 3, 3), numpy; kf1
    [N/mm^2], kf2 [1] (0: the limit kf1/2 e^2), phi [rad]."""
    f = np.eye(3) + np.asarray(gradient, dtype=float)
    a0 = np.array([np.cos(phi), np.sin(phi), 0.0])
    e = np.maximum(np.sum((f @ a0) ** 2, axis=-1) - 1.0, 0.0)
    if kf2 == 0.0:
        return 0.5 * kf1 * e**2
    return 0.5 * kf1 / kf2 * np.expm1(kf2 * e**2)


class NeoHookeanForce:
    """The internal force of eq. (C8) on a set of control points, as a CasADi expression.

    Parameters
    ----------
    operators : tuple of scipy.sparse matrices
        P_j (n_q, n): d/dx_j at the quadrature points of a scalar spline with values on
        the chosen control points (``PhysicalGradient.operators``, columns restricted).
    volume : numpy.ndarray
        Quadrature weight times |det G| at each point [mm^3].
    exponential : bool
        Add the stiffening stress of eq. (C11); ``__call__`` then takes k1 and k2.
    fibres : bool
        Add the fibre family's stress of eq. (C14) (with ``exponential``); ``__call__``
        then also takes kf1, kf2 and phi.
    """

    def __init__(
        self, operators, volume: np.ndarray, exponential: bool = False, fibres: bool = False
    ):
        if fibres and not exponential:
            raise ValueError("the fibre family comes with the exponential energy")
        self.n_points = int(operators[0].shape[0])
        self.exponential = exponential
        self.fibres = fibres
        self._operators = [to_casadi_sparse(sp.csr_matrix(p)) for p in operators]
        self._volume = ca.DM(np.asarray(volume, dtype=float))
        self._stress = piola_stress(exponential, fibres).map(self.n_points)

    def gradient(self, delta: ca.MX) -> ca.MX:
        """grad u at the points, (9, n_q) with rows (i, j) -> 3 i + j, i the component."""
        columns = [ca.mtimes(p, delta) for p in self._operators]  # columns[j][q, i] = du_i/dx_j
        return ca.vertcat(*[columns[j][:, i].T for i in range(3) for j in range(3)])

    def __call__(self, delta: ca.MX, mu_l, lam, k1=0.0, k2=0.0, *fibres) -> ca.MX:
        """f (n, 3) [N] of eq. (C8) for displacements delta (n, 3) [mm], Lame pair and k1
        [N/mm^2], k2 [1] (k1 and k2 only with ``exponential``), then kf1 [N/mm^2], kf2 [1]
        and phi [rad] with ``fibres``."""
        arguments = (k1, k2) if self.exponential else ()
        arguments += tuple(fibres) if self.fibres else ()
        stress = self._stress(self.gradient(delta), mu_l, lam, *arguments)  # (9, n_q)
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
        self._laplace = pattern_entries(self.pattern, laplace)

    @property
    def pattern(self) -> sp.csc_matrix:
        """The tangent's nonzero pattern (ones on it), the structure of every K_T."""
        return sp.csc_matrix((np.ones(self._indices.size), self._indices, self._indptr), self.shape)

    def __call__(
        self,
        delta: np.ndarray,
        mu_l: float,
        lam: float,
        k1: float = 0.0,
        k2: float = 0.0,
        kf1: float = 0.0,
        kf2: float = 0.0,
        phi: float = 0.0,
    ) -> sp.csc_matrix:
        """K_T at displacements delta (n, 3) [mm] on every control point, (3 m, 3 m) [N/mm];
        Lame pair and k1 [N/mm^2], k2 [1] of eq. (C12) (k1 = 0: the neo-Hookean tangent);
        kf1 [N/mm^2], kf2 [1] and phi [rad] of the fibre family, eq. (C14)."""
        f = np.eye(3) + self.point_gradients(delta)
        det = np.linalg.det(f)
        if np.any(det <= 0):
            raise ValueError("the deformation inverts the material (det F <= 0)")
        a = np.linalg.inv(f).transpose(0, 2, 1)
        shape = (self.n_elements, self.points_per_element, 3 * self.k)
        d = np.einsum("qij,qaj->qai", a, self._g).reshape(shape)  # [e, q, (a, i)]
        first = self._outer(d, d, self._w * lam)  # [(a, i), (b, k)]
        swapped = self._outer(d, d, self._w * (mu_l - lam * np.log(det)))  # [(a, k), (b, i)]
        if k1 != 0.0:
            extra, extra_swapped = self._exponential(f, det, d, k1, k2)
            first, swapped = first + extra, swapped + extra_swapped
        if kf1 != 0.0:
            first = first + self._fibres(f, kf1, kf2, phi, d.shape)
        local = first + self._swap(swapped)
        return self._scattered(local, mu_l * self._laplace)

    def point_gradients(self, field: np.ndarray) -> np.ndarray:
        """grad v at the Gauss points of a field v (n, 3) on every control point, in the
        points' element order: (n_q, 3, 3), [q, i, j] = sum_a v_ai dN_a/dx_j."""
        local = np.asarray(field, dtype=float)[self._support]  # (n_q, k, 3): [q, a, i]
        return np.einsum("qai,qaj->qij", local, self._g)

    def assemble(self, moduli: np.ndarray) -> sp.csc_matrix:
        """The stiffness of pointwise fourth-order tensors M^q on this pattern,

            K_(a,i),(b,k) = sum_q w_q sum_jl dN_a/dx_j M^q_ijkl dN_b/dx_l,

        for ``moduli`` (n_q, 3, 3, 3, 3) [q, i, j, k, l] in the points' element order
        (``point_gradients``); M^q = dP/dF at F_q gives K_T, eq. (C9) (tested).
        """
        e, p, k = self.n_elements, self.points_per_element, self.k
        weighted = np.asarray(moduli, dtype=float) * self._w[:, None, None, None, None]
        # sum over l first, into [q, j, i, k, b]: the layout [e, (q, j), (i, k, b)] as is
        inner = np.matmul(
            weighted.transpose(0, 2, 1, 3, 4).reshape(-1, 27, 3),
            np.ascontiguousarray(self._g.transpose(0, 2, 1)),
        ).reshape(e, 3 * p, 9 * k)
        outer = self._g.reshape(e, p, k, 3).transpose(0, 2, 1, 3).reshape(e, k, 3 * p)
        local = np.matmul(outer, inner).reshape(e, k, 3, 3, k)  # [e, a, i, k, b]
        return self._scattered(local.transpose(0, 1, 2, 4, 3).reshape(e, 3 * k, 3 * k))

    def _scattered(self, local: np.ndarray, constant: np.ndarray | float = 0.0) -> sp.csc_matrix:
        """Element matrices [e, (a, i), (b, k)] summed into the pattern, plus ``constant``
        (entries on the pattern)."""
        data = np.bincount(
            self._position,
            weights=local.reshape(self.n_elements, -1).ravel()[self._keep],
            minlength=self._indices.size,
        )
        return sp.csc_matrix((data + constant, self._indices, self._indptr), self.shape)

    def _outer(self, left: np.ndarray, right: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """sum_q weight_q left_q (x) right_q per element: [e, (a, i), (b, k)]."""
        c = weight.reshape(self.n_elements, self.points_per_element)[:, :, None]
        return np.matmul((left * c).transpose(0, 2, 1), right)

    def _swap(self, matrix: np.ndarray) -> np.ndarray:
        """[(a, k), (b, i)] -> [(a, i), (b, k)]: the a_il a_kj terms of (C9) and (C12)."""
        k = self.k
        return matrix.reshape(-1, k, 3, k, 3).transpose(0, 1, 4, 3, 2).reshape(matrix.shape)

    def _fibres(self, f, kf1: float, kf2: float, phi: float, shape) -> np.ndarray:
        """The element matrices of A_f, eq. (C14), at [(a, i), (b, k)]."""
        a0 = np.array([np.cos(phi), np.sin(phi), 0.0])
        fa = f @ a0  # (n_q, 3): F a0
        e = np.maximum(np.sum(fa**2, axis=1) - 1.0, 0.0)
        growth = np.exp(kf2 * e * e)
        w1 = kf1 * e * growth
        w11 = np.where(e > 0.0, kf1 * growth * (1.0 + 2.0 * kf2 * e * e), 0.0)
        ga = self._g @ a0  # (n_q, k): dN_a/dx . a0
        v = (ga[:, :, None] * fa[:, None, :]).reshape(shape)  # (F a0)_i (g_a . a0)
        matrix = self._outer(v, v, 4.0 * self._w * w11)
        c = (2.0 * self._w * w1).reshape(self.n_elements, -1, 1)
        gram = np.einsum(
            "eqa,eqb->eab",
            ga.reshape(self.n_elements, -1, self.k) * c,
            ga.reshape(self.n_elements, -1, self.k),
        )
        return matrix + np.einsum("eab,ik->eaibk", gram, np.eye(3)).reshape(matrix.shape)

    def _exponential(self, f, det, d, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
        """The element matrices of A_exp, eq. (C12): (unswapped part, part to swap)."""
        shape = d.shape
        first = np.einsum("qij,qij->q", f, f)
        scale = det ** (-2.0 / 3.0)
        s = scale * first - 3.0
        growth = np.exp(k2 * s * s)
        w1, w11 = k1 * s * growth, k1 * growth * (1.0 + 2.0 * k2 * s * s)
        fg = np.einsum("qij,qaj->qai", f, self._g).reshape(shape)  # F_ij g_aj
        per_point = (shape[0], shape[1], 1)
        big_g = scale.reshape(per_point) * (2.0 * fg - 2.0 / 3.0 * first.reshape(per_point) * d)
        c = 2.0 * self._w * w1 * scale
        matrix = self._outer(big_g, big_g, self._w * w11)
        matrix += self._outer(d, d, 2.0 / 9.0 * c * first)
        matrix -= 2.0 / 3.0 * (self._outer(fg, d, c) + self._outer(d, fg, c))
        g = self._g.reshape(self.n_elements, -1, self.k, 3)  # [e, q, a, j]
        gc = g * c.reshape(self.n_elements, -1, 1, 1)
        gram = np.einsum("eqaj,eqbj->eab", gc, g)  # sum_q c g_a . g_b
        matrix += np.einsum("eab,ik->eaibk", gram, np.eye(3)).reshape(matrix.shape)
        return matrix, self._outer(d, d, c * first / 3.0)
