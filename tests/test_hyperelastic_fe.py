"""The large-strain continuum energies against independent solves (docs/continuum.md).

``NeoHookeanModel`` (eq. C6) and ``ENERGIES["exponential"]`` (C6 + C10) were checked
against themselves only (tests/test_hyperelastic.py). Here:

- **Hand formulas.** W, P = dW/dF and dP/dF of both energies are written out again in
  numpy (``energy_density``, ``first_piola``, ``piola_increment``, ``tangent_moduli``,
  ``principal_stress``), checked against each other by central differences.
- **Closed-form homogeneous states.** Uniaxial (lambda 1.2) and equibiaxial (1.15)
  stretch of the spline block, loaded faces sliding, lateral faces free: the free
  stretch from a scalar root (``brentq``) of the principal stress and the nominal
  stress from the reaction agree to round-off (measured: < 1e-14).
- **scikit-fem.** A 10 x 8 x 4 mm block, base clamped, top moved by u = (0.6, 0,
  -0.8 x / 10) mm (15 % shear, 0 to 20 % compression), sides free: the project's
  model (``PrescribedDisplacement`` on the top, ``EquilibriumSolver``) against P2
  tetrahedra of scikit-fem with a Newton iteration of its own on the weak form of the
  hand formulas. Displacements at 27 interior points and the total top reaction agree
  to < 1 % at the second of two refinement levels and the gaps shrink as both refine
  (measured: 0.5-0.6 % at the fast level, 0.2-0.45 % at the finest slow one).

A further energy is one more ``Material`` (with its parameters in ``parameters`` and
its terms in the hand formulas). Run with ``-s`` to see the measured gaps; ``-m slow``
runs the convergence study (measured 236 s; the fast tests about 12 s).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem
from scipy.optimize import brentq

from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver
from symbolic.basis import BSplineBasis
from symbolic.constraints import BoundaryConditions
from symbolic.continuum import KPA, box_volume, lame
from symbolic.continuum_model import ENERGIES
from symbolic.loads import PrescribedDisplacement

BLOCK = np.array([10.0, 8.0, 4.0])
"""The block [0, Lx] x [0, Ly] x [0, Lz] [mm]: base z = 0 clamped, top z = Lz prescribed."""

SHEAR = 0.6
"""Top-face displacement along x [mm] (15 % shear over the 4 mm thickness)."""

COMPRESSION = 0.8
"""Top-face displacement along -z at x = Lx [mm] (20 % compression there, none at x = 0)."""

SAMPLES = np.stack(
    np.meshgrid([2.0, 5.0, 8.0], [2.0, 4.0, 6.0], [1.0, 2.0, 3.0], indexing="ij"), -1
).reshape(-1, 3)
"""Interior points where the two displacements are compared [mm]."""


def top_displacement(points: np.ndarray) -> np.ndarray:
    """u = (a, 0, -b x / Lx) on the top face [mm] at points (n, 3): linear, so the top
    control points (Greville) and the P2 nodes both carry it exactly."""
    points = np.atleast_2d(points)
    return np.column_stack(
        [
            np.full(len(points), SHEAR),
            np.zeros(len(points)),
            -COMPRESSION * points[:, 0] / BLOCK[0],
        ]
    )


@dataclass(frozen=True)
class Material:
    """An energy of ``ENERGIES`` with its parameters: E [kPa], nu [1], and for the
    exponential stiffening term k1 [kPa] and k2 [1] (k1 = 0: neo-Hookean alone)."""

    energy: str
    young_kpa: float
    poisson: float
    k1_kpa: float = 0.0
    k2: float = 0.0

    @property
    def constants(self) -> tuple[float, float, float, float]:
        """(mu_L, lambda, k1) [N/mm^2] and k2 [1]."""
        mu_l, lam = lame(self.young_kpa, self.poisson)
        return mu_l, lam, KPA * self.k1_kpa, self.k2

    def parameters(self) -> dict[str, float]:
        """The model's parameters by name."""
        values = {"E": self.young_kpa, "nu": self.poisson}
        if self.energy == "exponential":
            values.update(k1=self.k1_kpa, k2=self.k2)
        return values

    def model(self, volume, **options):
        """The project's base model of this energy."""
        return ENERGIES[self.energy](volume, self.parameters(), **options)

    def __str__(self) -> str:
        extra = f"-k1={self.k1_kpa:g}-k2={self.k2:g}" if self.k1_kpa else ""
        return f"{self.energy}-E={self.young_kpa:g}-nu={self.poisson:g}{extra}"


NEO_HOOKEAN = Material("neo-hookean", 20.0, 0.4)
NEARLY_INCOMPRESSIBLE = Material("neo-hookean", 20.0, 0.45)
STIFFENING = Material("exponential", 20.0, 0.4, k1_kpa=5.0, k2=20.0)
MATERIALS = [NEO_HOOKEAN, NEARLY_INCOMPRESSIBLE, STIFFENING]
"""The materials every check runs on (the scikit-fem comparison: the first and last in the
fast tier, all three in the slow study)."""


# ------------------------------------------------------------ the energy, by hand
def _inverse_transpose(f: np.ndarray) -> np.ndarray:
    """F^-T of 3 x 3 tensors stored with the indices first, (3, 3, ...)."""
    moved = np.moveaxis(f, (0, 1), (-2, -1))
    return np.moveaxis(np.linalg.inv(moved), (-2, -1), (1, 0))


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The matrix product of (3, 3, ...) tensors."""
    return np.einsum("ik...,kj...->ij...", a, b)


def energy_density(f: np.ndarray, mu_l, lam, k1, k2) -> np.ndarray:
    """W(F) = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2 + k1/(2 k2) (exp(k2 s^2) - 1),
    s = J^(-2/3) tr C - 3 [N/mm^2], for F (3, 3, ...)."""
    j = np.linalg.det(np.moveaxis(f, (0, 1), (-2, -1)))
    first = np.einsum("ij...,ij...->...", f, f)
    w = 0.5 * mu_l * (first - 3.0) - mu_l * np.log(j) + 0.5 * lam * np.log(j) ** 2
    if k1:
        s = j ** (-2.0 / 3.0) * first - 3.0
        w = w + 0.5 * k1 / k2 * np.expm1(k2 * s**2)
    return w


def first_piola(f: np.ndarray, mu_l, lam, k1, k2) -> np.ndarray:
    """P = dW/dF = mu F + (lam ln J - mu) a + k1 s e^(k2 s^2) J^(-2/3) (2 F - 2/3 I1 a),
    a = F^-T, I1 = F:F, for F (3, 3, ...)."""
    a = _inverse_transpose(f)
    log_j = np.log(np.linalg.det(np.moveaxis(f, (0, 1), (-2, -1))))
    stress = mu_l * f + (lam * log_j - mu_l) * a
    if k1:
        first = np.einsum("ij...,ij...->...", f, f)
        scale = np.exp(-2.0 / 3.0 * log_j)
        s = scale * first - 3.0
        stress = stress + k1 * s * np.exp(k2 * s**2) * scale * (2.0 * f - 2.0 / 3.0 * first * a)
    return stress


def _exponential_parts(f, a, log_j, k2):
    """I1 = F:F, J^(-2/3), s = J^(-2/3) I1 - 3, e = exp(k2 s^2) and q = 2 F - 2/3 I1 a."""
    first = np.einsum("ij...,ij...->...", f, f)
    scale = np.exp(-2.0 / 3.0 * log_j)
    s = scale * first - 3.0
    return first, scale, s, np.exp(k2 * s**2), 2.0 * f - 2.0 / 3.0 * first * a


def piola_increment(f: np.ndarray, h: np.ndarray, mu_l, lam, k1, k2) -> np.ndarray:
    """dP/dF [H], the directional derivative of ``first_piola``, for F and H (3, 3, ...).

    With da[H] = -a H^T a and d(ln J)[H] = a:H,
    dP = mu H + lam (a:H) a + (mu - lam ln J) a H^T a; the exponential term adds
    W11 (g:H) g + W1 dg[H], g = J^(-2/3) q, q = 2 F - 2/3 I1 a,
    dg[H] = J^(-2/3) (-2/3 (a:H) q + 2 H - 4/3 (F:H) a + 2/3 I1 a H^T a).
    """
    a = _inverse_transpose(f)
    log_j = np.log(np.linalg.det(np.moveaxis(f, (0, 1), (-2, -1))))
    a_h = np.einsum("ij...,ij...->...", a, h)
    aha = _product(_product(a, np.einsum("ij...->ji...", h)), a)
    change = mu_l * h + lam * a_h * a + (mu_l - lam * log_j) * aha
    if k1:
        first, scale, s, e, q = _exponential_parts(f, a, log_j, k2)
        g = scale * q
        f_h = np.einsum("ij...,ij...->...", f, h)
        dg = scale * (
            -2.0 / 3.0 * a_h * q + 2.0 * h - 4.0 / 3.0 * f_h * a + 2.0 / 3.0 * first * aha
        )
        g_h = np.einsum("ij...,ij...->...", g, h)
        change = change + k1 * e * (1.0 + 2.0 * k2 * s**2) * g_h * g + k1 * s * e * dg
    return change


def tangent_moduli(f: np.ndarray, mu_l, lam, k1, k2) -> np.ndarray:
    """A_ijkl = dP_ij/dF_kl, (3, 3, 3, 3, ...): ``piola_increment`` written out as a
    tensor (A : H = dP[H], checked), with a = F^-T and c = mu - lam ln J,

        A = mu d_ik d_jl + lam a_ij a_kl + c a_il a_kj
            + W11 g_ij g_kl + W1 J^(-2/3) (-2/3 q_ij a_kl + 2 d_ik d_jl - 4/3 a_ij F_kl
                                          + 2/3 I1 a_il a_kj).
    """
    a = _inverse_transpose(f)
    log_j = np.log(np.linalg.det(np.moveaxis(f, (0, 1), (-2, -1))))
    identity = np.einsum("ik,jl->ijkl", np.eye(3), np.eye(3)).reshape(
        (3,) * 4 + (1,) * (f.ndim - 2)
    )
    crossed = np.einsum("il...,kj...->ijkl...", a, a)
    moduli = (
        mu_l * identity
        + lam * np.einsum("ij...,kl...->ijkl...", a, a)
        + (mu_l - lam * log_j) * crossed
    )
    if k1:
        first, scale, s, e, q = _exponential_parts(f, a, log_j, k2)
        change = (
            -2.0 / 3.0 * np.einsum("ij...,kl...->ijkl...", q, a)
            + 2.0 * identity
            - 4.0 / 3.0 * np.einsum("ij...,kl...->ijkl...", a, f)
            + 2.0 / 3.0 * first * crossed
        )
        moduli = (
            moduli
            + k1 * e * (1.0 + 2.0 * k2 * s**2) * scale**2 * np.einsum("ij...,kl...->ijkl...", q, q)
            + k1 * s * e * scale * change
        )
    return moduli


def principal_stress(stretches, mu_l, lam, k1, k2) -> np.ndarray:
    """P_i of a homogeneous F = diag(l1, l2, l3), written out for principal stretches:
    mu l_i + (lam ln J - mu) / l_i + k1 s e^(k2 s^2) J^(-2/3) (2 l_i - 2/3 I1 / l_i)."""
    stretches = np.asarray(stretches, dtype=float)
    j = np.prod(stretches)
    first = np.sum(stretches**2)
    stress = mu_l * stretches + (lam * np.log(j) - mu_l) / stretches
    scale = j ** (-2.0 / 3.0)
    s = scale * first - 3.0
    return stress + k1 * s * np.exp(k2 * s**2) * scale * (
        2.0 * stretches - 2.0 / 3.0 * first / stretches
    )


def test_hand_written_stress_and_tangent_are_derivatives_of_the_energy():
    """The hand formulas the checks below rest on, for each material: P = dW/dF and
    dP/dF[H] by central differences at random F (up to ~25 % strain), the tensor A of
    ``tangent_moduli`` applied to H equals dP/dF[H], and the principal form equals P at
    a diagonal F."""
    rng = np.random.default_rng(0)
    f = np.eye(3)[:, :, None] + 0.25 * rng.normal(size=(3, 3, 5))
    h = rng.normal(size=(3, 3, 5))
    step = 1e-6
    for material in MATERIALS:
        constants = material.constants
        stress = first_piola(f, *constants)
        numeric = (
            energy_density(f + step * h, *constants) - energy_density(f - step * h, *constants)
        ) / (2 * step)
        assert np.allclose(np.einsum("ijq,ijq->q", stress, h), numeric, rtol=1e-7, atol=0)
        numeric = (
            first_piola(f + step * h, *constants) - first_piola(f - step * h, *constants)
        ) / (2 * step)
        change = piola_increment(f, h, *constants)
        assert np.allclose(change, numeric, rtol=1e-6, atol=1e-12)
        moduli = np.einsum("ijklq,klq->ijq", tangent_moduli(f, *constants), h)
        assert np.allclose(moduli, change, rtol=1e-12, atol=1e-15)
        diagonal = np.diag([1.2, 0.9, 0.85])[:, :, None]
        assert np.allclose(
            np.diag(first_piola(diagonal, *constants)[:, :, 0]),
            principal_stress([1.2, 0.9, 0.85], *constants),
            rtol=1e-13,
        )


@dataclass
class Solution:
    """A solve of the block: displacement at ``SAMPLES`` (n, 3) [mm], total reaction on
    the top face (3,) [N], unknowns, Newton steps and wall time [s]."""

    displacement: np.ndarray
    reaction: np.ndarray
    dofs: int
    iterations: int
    seconds: float


class NoConvergence(RuntimeError):
    """A Newton iteration of this file did not converge."""


def continuation(step, state, smallest: float = 1.0 / 64.0):
    """Load steps from 0 to 1: ``step(state, load) -> (state, iterations)`` at the full
    load first, the remaining increment halved whenever a step fails to converge
    (``NoConvergence`` or the project's ``EquilibriumError``) and doubled again after a
    success. Returns the final state and the total iterations.
    """
    load, size, iterations = 0.0, 1.0, 0
    while load < 1.0:
        trial = min(1.0, load + size)
        try:
            state, count = step(state, trial)
        except (NoConvergence, EquilibriumError):
            size *= 0.5
            if size < smallest:
                raise
            continue
        load, size, iterations = trial, min(2.0 * size, 1.0), iterations + count
    return state, iterations


# ------------------------------------------------------------ scikit-fem side
class FeBlock:
    """The block on quadratic tetrahedra (scikit-fem's mesh, P2 element, quadrature,
    dof numbering and probes) and the weak form integral P(F) : grad v dV of the hand
    formulas above.

    The vector field is the scalar P2 space times three: dof 3 s + i is component i of
    scalar dof s, scikit-fem's own numbering of ``ElementVector(ElementTetP2())``. The
    residual and the tangent are assembled here element-batched (scikit-fem's forms call
    the integrand once per pair of the 30 local functions, 900 calls per tangent: about
    30 s per Newton step at 10 x 8 x 4 cells, against 0.5 s batched); the two assemblies agree
    to round-off (``test_batched_assembly_is_scikit_fem_assembly``).

    Parameters
    ----------
    cells : tuple of int
        Hexahedra along x, y, z, each cut into tetrahedra by ``MeshTet.init_tensor``.
    """

    def __init__(self, cells: tuple[int, int, int]):
        self.cells = tuple(cells)
        self.mesh = skfem.MeshTet.init_tensor(
            *(np.linspace(0.0, length, n + 1) for length, n in zip(BLOCK, cells))
        )
        self.scalar = skfem.Basis(self.mesh, skfem.ElementTetP2())
        self.n = self.scalar.N
        self.gradients = np.stack([phi[0].grad for phi in self.scalar.basis])  # (a, j, e, q)
        self.dofs = self.scalar.element_dofs  # (a, e)
        self.weights = self.scalar.dx  # (e, q)
        self.top = self.scalar.get_dofs(lambda x: np.isclose(x[2], BLOCK[2])).all()
        self.bottom = self.scalar.get_dofs(lambda x: np.isclose(x[2], 0.0)).all()
        fixed = np.union1d(self.top, self.bottom)
        self.fixed = (3 * fixed[:, None] + np.arange(3)).ravel()
        self.free = np.setdiff1d(np.arange(3 * self.n), self.fixed)

    def deformation(self, u: np.ndarray) -> np.ndarray:
        """F = I + grad u at the quadrature points, (3, 3, e, q), for u (n, 3)."""
        local = np.asarray(u).reshape(self.n, 3)[self.dofs]  # (a, e, i)
        return np.eye(3)[:, :, None, None] + np.einsum("aei,ajeq->ijeq", local, self.gradients)

    def residual(self, u: np.ndarray, constants) -> np.ndarray:
        """r_(s, i) = integral P_ij dN_s/dx_j dV, (3 n,) [N]; NaN where J <= 0."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            stress = first_piola(self.deformation(u), *constants)
        local = np.einsum("imeq,bmeq,eq->bei", stress, self.gradients, self.weights)
        index = 3 * self.dofs[:, :, None] + np.arange(3)
        return np.bincount(index.ravel(), local.ravel(), minlength=3 * self.n)

    def tangent(self, u: np.ndarray, constants) -> sp.csr_matrix:
        """dr/du, (3 n, 3 n) [N/mm]: integral dN_b/dx_j A_ijkl dN_a/dx_l dV with
        A_ijkl = dP_ij/dF_kl of ``tangent_moduli``."""
        f = self.deformation(u)
        moduli = tangent_moduli(f, *constants)  # [i, j, k, l, e, q]
        # batched products: [b, j] x [j, (i, k, l)] per point, then the sum over (q, l)
        e, q = f.shape[2:]
        g = self.gradients.transpose(2, 3, 0, 1)  # [e, q, a, l]
        k = g.shape[2]
        first = np.matmul(g, moduli.transpose(4, 5, 1, 0, 2, 3).reshape(e, q, 3, 27))
        first = first.reshape(e, q, k, 3, 3, 3).transpose(0, 2, 3, 4, 1, 5)  # [e, b, i, k, q, l]
        weighted = (g * self.weights[:, :, None, None]).transpose(0, 1, 3, 2)  # [e, q, l, a]
        local = np.matmul(first.reshape(e, 9 * k, 3 * q), weighted.reshape(e, 3 * q, k))
        local = local.reshape(e, k, 3, 3, k).transpose(0, 1, 2, 4, 3)  # [e, b, i, a, k]
        index = 3 * self.dofs.T[:, :, None] + np.arange(3)  # [e, a, i]
        rows = np.broadcast_to(index[:, :, :, None, None], (len(index), k, 3, k, 3))
        cols = np.broadcast_to(index[:, None, None, :, :], (len(index), k, 3, k, 3))
        shape = (3 * self.n, 3 * self.n)
        matrix = sp.coo_matrix((local.ravel(), (rows.ravel(), cols.ravel())), shape).tocsr()
        return sp.csr_matrix(0.5 * (matrix + matrix.T))  # symmetric up to round-off

    def _acceptable(self, u: np.ndarray, constants, size: float, newton: int) -> bool:
        """A trial state: no point inverted or overflowed, and after the predictor a
        residual norm below ``size`` (the current one)."""
        residual = self.residual(u, constants)
        if not np.all(np.isfinite(residual)):
            return False
        return newton == 0 or np.linalg.norm(residual[self.free]) < size

    def newton(self, u: np.ndarray, prescribed: np.ndarray, constants) -> tuple[np.ndarray, int]:
        """Equilibrium from the state u with the fixed dofs moved to ``prescribed``.

        The first step is the linear predictor (the tangent at u, the increment of the
        prescribed values), the next ones Newton steps; each is halved while a
        quadrature point inverts or overflows and, after the predictor, while the
        residual norm does not decrease. Stops at |r_free| < 1e-11 |r_fixed|.

        Raises
        ------
        NoConvergence
            When a Newton step must be cut below 1/8 (the load step is too large: give
            up early and let ``continuation`` halve it) or 25 steps do not converge.
        """
        from solvers.linalg.cholmod import factorised, symmetric_lu

        increment = np.zeros(3 * self.n)
        increment[self.fixed] = prescribed[self.fixed] - u[self.fixed]
        for newton in range(25):
            residual = self.residual(u, constants)
            size = np.linalg.norm(residual[self.free])
            if newton > 0 and size < 1e-11 * np.linalg.norm(residual[self.fixed]):
                return u, newton
            matrix = self.tangent(u, constants)
            right = -residual[self.free] - matrix[self.free][:, self.fixed] @ increment[self.fixed]
            step = increment.copy()
            system = sp.csc_matrix(matrix[self.free][:, self.free])
            step[self.free] = factorised(system, symmetric_lu).solve(right)
            length = 1.0
            while not self._acceptable(u + length * step, constants, size, newton):
                length *= 0.5
                if length < (1e-3 if newton == 0 else 0.1):
                    raise NoConvergence("no acceptable Newton step length")
            u = u + length * step
            increment = (1.0 - length) * increment
        raise NoConvergence("25 Newton steps did not converge")

    def solve(self, material: Material) -> Solution:
        """The block's equilibrium: base zero, top ``top_displacement``, by ``newton``
        in load steps (``continuation``). The reaction on the top face is the sum of r
        over the top's dofs, per component."""
        begin = time.perf_counter()
        constants = material.constants
        target = np.zeros((self.n, 3))
        target[self.top] = top_displacement(self.scalar.doflocs[:, self.top].T)
        target = target.ravel()
        u, iterations = continuation(
            lambda u, load: self.newton(u, load * target, constants), np.zeros(3 * self.n)
        )
        residual = self.residual(u, constants).reshape(self.n, 3)
        probes = self.scalar.probes(SAMPLES.T)
        return Solution(
            displacement=probes @ u.reshape(self.n, 3),
            reaction=residual[self.top].sum(axis=0),
            dofs=len(self.free),
            iterations=iterations,
            seconds=time.perf_counter() - begin,
        )


def test_batched_assembly_is_scikit_fem_assembly():
    """``FeBlock``'s residual and tangent equal scikit-fem's ``LinearForm`` and
    ``BilinearForm`` of the same integrands on ``ElementVector(ElementTetP2())``, at a
    smooth state of ~10-20 % strain, with the stiffening term on (measured: 2e-16 relative)."""
    from skfem.helpers import ddot, grad

    fe = FeBlock((2, 2, 1))
    constants = STIFFENING.constants
    vector = skfem.Basis(fe.mesh, skfem.ElementVector(skfem.ElementTetP2()))
    identity = np.eye(3)[:, :, None, None]

    @skfem.LinearForm
    def internal(v, w):
        return ddot(first_piola(identity + grad(w["u"]), *constants), grad(v))

    @skfem.BilinearForm
    def tangent(u, v, w):
        return ddot(piola_increment(identity + grad(w["u"]), grad(u), *constants), grad(v))

    x, y, z = fe.scalar.doflocs
    gradient = 0.1 * np.random.default_rng(1).normal(size=(3, 3))
    u = (gradient @ fe.scalar.doflocs + 0.01 * np.stack([x * y, y * z, z * x])).T.ravel()
    field = vector.interpolate(u)
    reference = internal.assemble(vector, u=field)
    matrix = tangent.assemble(vector, u=field).toarray()
    residual_gap = np.abs(fe.residual(u, constants) - reference).max() / np.abs(reference).max()
    tangent_gap = np.abs(fe.tangent(u, constants).toarray() - matrix).max() / np.abs(matrix).max()
    print(f"\nbatched against scikit-fem forms: {residual_gap:.1e}, {tangent_gap:.1e}")
    assert residual_gap < 1e-12
    assert tangent_gap < 1e-12


# ------------------------------------------------------------ the spline side


def spline_block(material: Material, shape: tuple[int, int, int], degrees=(2, 2, 2)) -> Solution:
    """The block as the project runs it: ``box_volume``, the base fixed by the default
    ``BoundaryConditions``, the top by ``PrescribedDisplacement`` at the top's Greville
    points (as many as top control points, so the top layer follows the linear field
    exactly), solved by ``EquilibriumSolver`` (Newton on the KKT system); the reaction
    is ``constraint_force`` of the multipliers. Load steps as ``continuation``."""
    begin = time.perf_counter()
    volume = box_volume(tuple(BLOCK), shape, degrees)
    greville = [BSplineBasis(p, n).greville() for p, n in zip(degrees[:2], shape[:2])]
    uv = np.stack(np.meshgrid(*greville, indexing="ij"), -1).reshape(-1, 2)
    model = material.model(volume, prescribed=PrescribedDisplacement(uv))
    prescribed = top_displacement(np.column_stack([uv * BLOCK[:2], np.full(len(uv), BLOCK[2])]))
    solver = EquilibriumSolver(model)
    force = np.zeros((model.n_free, 3))

    def step(previous, load):
        start = None if previous is None else previous.state
        equilibrium = solver.solve(force, prescribed=load * prescribed, start=start)
        return equilibrium, equilibrium.iterations

    equilibrium, iterations = continuation(step, None)
    delta = equilibrium.positions - model.rest
    displacement = volume.collocation(SAMPLES / BLOCK) @ delta
    reaction = model.constraint_force(equilibrium.multipliers)
    return Solution(
        displacement, reaction, 3 * model.n_free, iterations, time.perf_counter() - begin
    )


# ------------------------------------------------------------ homogeneous checks
def homogeneous_block(material: Material, stretches: dict[int, float], shape=(5, 4, 3)):
    """Stretch the spline block along the axes of ``stretches`` ({axis: lambda}) on its
    faces normal to those axes only; the rest is solved by Newton.

    The loaded faces carry u_a = (lambda - 1) x_a on the normal component alone (the
    face at x_a = 0 stays, the other moves by (lambda - 1) L_a; both slide freely
    along the face); each free axis has a symmetry plane (u_c = 0 on x_c = 0) against
    rigid motion and its far face traction-free. The force and the tangent are the
    model's own (``elastic_force``, ``tangent``) with every control point free, and the
    unknowns are single components of control points; the step starts with the linear
    predictor of the prescribed increment.

    Returns
    -------
    stress : numpy.ndarray
        For each loaded axis a, the total force on the far face over its rest area
        (the nominal stress P_aa) [N/mm^2].
    lateral : numpy.ndarray
        For each free axis c, 1 + u_c / x_c over every control point with x_c > 0
        (each the same number for a homogeneous solution).
    """
    volume = box_volume(tuple(BLOCK), shape, (2, 2, 2))
    model = material.model(volume, boundary=BoundaryConditions(fix_inner=False))
    n = volume.basis.size
    symbol = ca.MX.sym("delta", n, 3)
    force = ca.Function("f", [symbol], [model.elastic_force(symbol, model.values(), ())])
    tangent = model.tangent(())
    index = np.indices(volume.shape).reshape(3, -1).T
    rest = volume.control_points
    fixed, values = [], []
    for axis in range(3):
        face = np.flatnonzero(index[:, axis] == 0)
        fixed.append(axis * n + face)
        values.append(np.zeros(face.size))
        if axis in stretches:
            face = np.flatnonzero(index[:, axis] == volume.shape[axis] - 1)
            fixed.append(axis * n + face)
            values.append((stretches[axis] - 1.0) * rest[face, axis])
    fixed, values = np.concatenate(fixed), np.concatenate(values)
    free = np.setdiff1d(np.arange(3 * n), fixed)
    delta = np.zeros(3 * n)  # stacked: x components of every point, then y, then z
    increment = np.zeros(3 * n)
    increment[fixed] = values
    for newton in range(30):
        residual = force(delta.reshape(3, n).T).full().T.ravel()
        if newton > 0 and np.abs(residual[free]).max() < 1e-13 * np.abs(residual[fixed]).max():
            break
        matrix = sp.csr_matrix(tangent(delta, np.zeros(0)))
        right = -residual[free] - matrix[free][:, fixed] @ increment[fixed]
        step = increment.copy()
        step[free] = spla.spsolve(sp.csc_matrix(matrix[free][:, free]), right)
        delta, increment = delta + step, np.zeros(3 * n)
    else:
        raise AssertionError("Newton did not converge on the homogeneous block")
    residual = residual.reshape(3, n)
    displacement = delta.reshape(3, n)
    stress = [
        residual[a, index[:, a] == volume.shape[a] - 1].sum() * BLOCK[a] / BLOCK.prod()
        for a in stretches
    ]
    lateral = [
        1.0 + displacement[c, rest[:, c] > 0] / rest[rest[:, c] > 0, c]
        for c in range(3)
        if c not in stretches
    ]
    return np.array(stress), np.concatenate(lateral)


@pytest.mark.parametrize("material", MATERIALS, ids=str)
def test_uniaxial_stretch_matches_the_closed_form(material):
    """lambda = 1.2 along x, the y and z faces free: the lateral stretch t solves
    P_yy(1.2, t, t) = 0 (``brentq`` on ``principal_stress``), and the spline block gives
    t at every control point and P_xx(1.2, t, t) as force over area, to round-off.

    Measured: t = 0.928699, 0.920634, 0.931373 and P_xx = 3.4376, 3.4048, 3.9076 kPa
    (neo-Hookean nu 0.4, nu 0.45, exponential); gaps <= 6e-16 in t and 5e-15 relative
    in P_xx.
    """
    constants = material.constants
    stretch = 1.2
    root = brentq(lambda t: principal_stress([stretch, t, t], *constants)[1], 0.5, 1.0, xtol=1e-15)
    expected = principal_stress([stretch, root, root], *constants)[0]
    stress, lateral = homogeneous_block(material, {0: stretch})
    print(f"\n{material} uniaxial: t = {root:.6f}, P_xx = {expected / KPA:.4f} kPa; ", end="")
    print(f"gaps {np.abs(lateral - root).max():.1e}, {abs(stress[0] / expected - 1):.1e} rel")
    assert np.abs(lateral - root).max() < 1e-12
    assert stress[0] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("material", MATERIALS, ids=str)
def test_equibiaxial_stretch_matches_the_closed_form(material):
    """lambda = 1.15 along x and y, the z face free: the thickness stretch t solves
    P_zz(1.15, 1.15, t) = 0, and the spline block gives t and P_xx = P_yy as force over
    area, to round-off.

    Measured: t = 0.820508, 0.788589, 0.835431 and P_xx = 4.0327, 4.2017, 4.7812 kPa
    (neo-Hookean nu 0.4, nu 0.45, exponential); gaps <= 7e-16 in t and 3e-15 relative
    in P_xx.
    """
    constants = material.constants
    stretch = 1.15
    root = brentq(
        lambda t: principal_stress([stretch, stretch, t], *constants)[2], 0.3, 1.0, xtol=1e-15
    )
    expected = principal_stress([stretch, stretch, root], *constants)[0]
    stress, lateral = homogeneous_block(material, {0: stretch, 1: stretch})
    print(f"\n{material} equibiaxial: t = {root:.6f}, P_xx = {expected / KPA:.4f} kPa; ", end="")
    print(f"gaps {np.abs(lateral - root).max():.1e}, {np.abs(stress / expected - 1).max():.1e} rel")
    assert np.abs(lateral - root).max() < 1e-12
    assert stress == pytest.approx([expected, expected], rel=1e-12)


# ------------------------------------------------------------ spline against scikit-fem
FAST_LEVELS = (((7, 6, 4), (5, 4, 2)), ((12, 10, 6), (10, 8, 4)))
"""(spline control grid, FE cells) pairs: quadratic spline with 5 x 4 x 2 and 10 x 8 x 4
knot spans against P2 tetrahedra on 5 x 4 x 2 and 10 x 8 x 4 hexahedra (x 6)."""

SLOW_LEVELS = FAST_LEVELS + (((17, 14, 8), (15, 12, 6)), ((22, 18, 10), (20, 16, 8)))


def gaps(spline: Solution, fe: Solution) -> tuple[float, float]:
    """(max |u_spline - u_FE| over ``SAMPLES`` / max |u_FE|, |R_spline - R_FE| / |R_FE|)."""
    scale = np.abs(fe.displacement).max()
    return (
        float(np.abs(spline.displacement - fe.displacement).max() / scale),
        float(np.linalg.norm(spline.reaction - fe.reaction) / np.linalg.norm(fe.reaction)),
    )


def study(material: Material, levels) -> tuple[list[Solution], list[Solution]]:
    """Both solves at every level (the spline first: it skips an energy not there yet),
    printed with their pairwise gaps."""
    splines, fes = [], []
    for shape, cells in levels:
        splines.append(spline_block(material, shape))
        fes.append(FeBlock(cells).solve(material))
    print(f"\n{material}: top reaction R [N], gaps (displacement, reaction) relative")
    for (shape, cells), spline, fe in zip(levels, splines, fes):
        print(
            f"  spline {shape} ({spline.dofs} unknowns, {spline.iterations} Newton, "
            f"{spline.seconds:.1f} s) R = {np.round(spline.reaction, 5)}; FE {cells} "
            f"({fe.dofs} unknowns, {fe.iterations} Newton, {fe.seconds:.1f} s) "
            f"R = {np.round(fe.reaction, 5)}; gaps {gaps(spline, fe)[0]:.2e}, "
            f"{gaps(spline, fe)[1]:.2e}"
        )
    return splines, fes


@pytest.mark.parametrize("material", [NEO_HOOKEAN, STIFFENING], ids=str)
def test_block_agrees_with_scikit_fem(material):
    """The clamped block under the top's shear of 0.6 mm and compression of 0 to 0.8 mm
    (20 %): the project's spline model against scikit-fem's P2 tetrahedra at 27 interior
    points and in the total top reaction. Both gaps shrink as both sides refine, to
    below 1 % at the second level.

    Measured (displacement gap over the largest displacement, ~0.50 mm; reaction gap
    over |R|, 0.24-0.27 N), first then second level:

    - neo-Hookean nu 0.4: 2.4e-2 then 6.1e-3; 1.3e-2 then 5.2e-3;
    - exponential, k1 5 kPa, k2 20: 2.6e-2 then 5.1e-3; 1.5e-2 then 5.3e-3.
    """
    splines, fes = study(material, FAST_LEVELS)
    coarse, fine = (gaps(s, f) for s, f in zip(splines, fes))
    assert max(fine) < 1e-2
    assert fine[0] < 0.5 * coarse[0]
    assert fine[1] < 0.6 * coarse[1]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("material", "levels"),
    [
        (NEO_HOOKEAN, SLOW_LEVELS),
        (NEARLY_INCOMPRESSIBLE, SLOW_LEVELS),
        (STIFFENING, SLOW_LEVELS[:3]),  # load steps at the finer levels: 14 min with a 4th
    ],
    ids=lambda value: str(value) if isinstance(value, Material) else f"{len(value)}-levels",
)
def test_block_convergence_study(material, levels):
    """More levels of both (spline 15 x 12 x 6 and 20 x 16 x 8 knot spans, FE 15 x 12 x 6
    and 20 x 16 x 8 cells, up to 61,000 FE unknowns): the paired gaps keep shrinking,
    and each side's gap to the other's finest level shrinks with its own refinement
    until the other's error shows (the last entry).

    Measured (displacement; reaction), level by level:

    - neo-Hookean nu 0.4, paired: 2.4e-2, 6.1e-3, 3.9e-3, 2.8e-3; 1.3e-2, 5.2e-3,
      3.2e-3, 2.3e-3. Spline against the finest FE: 2.9e-2, 1.0e-2, 2.9e-3, 2.8e-3;
      4.4e-2, 1.3e-2, 3.6e-3, 2.3e-3. FE against the finest spline: 3.8e-2, 1.5e-2,
      6.2e-3, 2.8e-3; 5.4e-2, 1.8e-2, 7.2e-3, 2.3e-3;
    - neo-Hookean nu 0.45, paired: 2.7e-2, 1.1e-2, 5.4e-3, 3.9e-3; 1.2e-2, 6.0e-3,
      4.2e-3, 3.3e-3. Spline against the finest FE: 4.3e-2, 1.7e-2, 5.0e-3, 3.9e-3;
      8.5e-2, 2.8e-2, 1.0e-2, 3.3e-3. FE against the finest spline: 5.0e-2, 1.8e-2,
      7.3e-3, 3.9e-3; 8.6e-2, 2.7e-2, 9.3e-3, 3.3e-3;
    - exponential, paired: 2.6e-2, 5.1e-3, 4.5e-3; 1.5e-2, 5.3e-3, 3.0e-3. Spline
      against the finest FE: 2.1e-2, 4.3e-3, 4.5e-3; 2.8e-2, 5.0e-3, 3.0e-3. FE against
      the finest spline: 2.6e-2, 1.1e-2, 4.5e-3; 4.3e-2, 1.2e-2, 3.0e-3.

    Runtime: 69 s, 74 s and 93 s.
    """
    splines, fes = study(material, levels)
    paired = np.array([gaps(s, f) for s, f in zip(splines, fes)])
    spline_side = np.array([gaps(s, fes[-1]) for s in splines])
    fe_side = np.array([gaps(splines[-1], f) for f in fes])
    for name, values in (("paired", paired), ("spline vs finest FE", spline_side)):
        print(f"  {name}: {values.T.round(5).tolist()}")
    print(f"  FE vs finest spline: {fe_side.T.round(5).tolist()}")
    assert np.all(np.diff(paired, axis=0) < 0)
    assert np.all(np.diff(spline_side[:-1], axis=0) < 0)
    assert np.all(np.diff(fe_side[:-1], axis=0) < 0)
    assert paired[-1].max() < 6e-3
