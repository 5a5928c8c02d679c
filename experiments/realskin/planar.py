"""The authors' planar extensometer: equilibrium over the frames, sensitivities, their cost.

The body is the mesh's rectangle minus the pad holes (``experiments.realskin.mesh2d``),
the energy the compressible neo-Hookean of ``symbolic.planar_neohookean``. Conditions:
the fixed pad's hole at 0, the moving pad's hole at (u_x, 0) of each frame, the outer
edges free (theirs) or held at 0 (``fix_ring``, the project's membrane).

**Equilibrium** (``Extensometer.solve``): the frames in order, each from the last one's
state (continuation in the pad travel). A frame starts from the linear prediction of
the new pad position, then Newton with a line search that halves a step inverting a
triangle; if it fails, the frame's increment is split in 2, 4, then 8 sub-steps. In a
fit, a frame may start instead from the previous evaluation's state plus its first-order
change S dp (and falls back to the above when that fails).

**Sensitivities** (direct): at each converged frame, S = du/dp solves
K_ff S_f = -dR_f/dp (the last Newton factorisation reused), with dR/dp and the force's
derivatives in closed form (``PlanarNeoHookean.residual_derivatives``,
``edge_force_derivatives``). p = (E, nu) of every triangle, or of the keloid's (region 1)
with the skin held.

**Cost** (theirs): J = sum_t Q_t + 1/2 L_t^2 with

    Q_t = integral over the DIC box's triangles of |u_t - u_msr,t|^2 dA   [mm^4]
    L_t = F_x(u_t) - f_t                                                  [N]

u_msr the DIC displacements projected onto the box's nodes (``authors.mls_project``),
the integral exact with the P1 mass matrix M = U^T U. As least squares, J = 1/2 |r|^2
with r = [sqrt 2 U d_t (x and y), L_t]. F_x is the traction integral of (P N)_x over the
moving pad's edges (theirs, ``force="traction"``) or the sum of the internal force over
its nodes (``force="reaction"``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from experiments.realskin import mesh2d
from experiments.realskin.authors import Frames, mls_project
from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.planar_neohookean import PLANES, PlanarNeoHookean

FORCES = ("traction", "reaction")
"""How the model's pad force is measured: theirs (traction integral) or the residual's."""


class EquilibriumFailed(RuntimeError):
    """Newton found no equilibrium for a frame, even in sub-steps."""


@dataclass(frozen=True)
class Assumptions:
    """What the authors assumed, each changeable on its own.

    Attributes
    ----------
    plane : {"strain", "stress"}
        Planar reduction (theirs: strain).
    fix_ring : bool
        Outer edges held at 0 (the project's membrane) instead of free (theirs).
    force : {"traction", "reaction"}
        The model's pad force (theirs: traction).
    """

    plane: str = "strain"
    fix_ring: bool = False
    force: str = "traction"

    def __post_init__(self):
        if self.plane not in PLANES or self.force not in FORCES:
            raise ValueError(f"plane in {PLANES} and force in {FORCES}, got {self}")


@dataclass
class Solution:
    """The frames' equilibria at parameters ``p``.

    Attributes
    ----------
    p : ndarray (2,)
        (E [N/mm], nu) of the fitted material.
    u : ndarray (K, 2N)
        Nodal displacements [mm].
    force : ndarray (K,)
        Model x force on the skin at the moving pad [N].
    sensitivity : ndarray (K, 2N, 2) or None
        du/dp.
    force_derivative : ndarray (K, 2) or None
        dF_x/dp, total (through u too).
    newton : list of int
        Newton iterations per frame.
    """

    p: np.ndarray
    u: np.ndarray
    force: np.ndarray
    sensitivity: np.ndarray | None
    force_derivative: np.ndarray | None
    newton: list


def newton(model, u, prescribed, target, free, tol: float = 1e-10, maxit: int = 30):
    """Equilibrium R_free(u) = 0 with u[prescribed] = target, from u.

    The first step is the linear prediction of the new prescribed values; a step that
    inverts a triangle is halved (down to 1e-4). Converged when a Newton correction is
    below ``tol`` [mm] everywhere.

    Parameters
    ----------
    model : symbolic.planar_neohookean.PlanarNeoHookean
    u : ndarray (2N,)
        Start [mm].
    prescribed, free : ndarray
        Degrees of freedom held and free (a partition).
    target : ndarray
        Values [mm] of u[prescribed].

    Returns
    -------
    u, K, factor, iterations
        The equilibrium, the tangent there and its free block's factorisation (the last
        one, at most ``tol`` from u), the Newton iterations.

    Raises
    ------
    EquilibriumFailed
        No convergence in ``maxit`` iterations, or every step inverts a triangle.
    """
    stiffness = model.stiffness(u)
    factor = factorised(stiffness[free][:, free], symmetric_lu)
    du = np.zeros_like(u)
    du[prescribed] = target - u[prescribed]
    du[free] = -factor.solve(
        model.residual(u)[free] + stiffness[free][:, prescribed] @ du[prescribed]
    )
    for iteration in range(1, maxit + 1):
        scale = 1.0
        while True:
            trial = u + scale * du
            trial[prescribed] = target
            try:
                residual = model.residual(trial)
                break
            except FloatingPointError:
                scale *= 0.5
                if scale < 1e-4:
                    raise EquilibriumFailed("every step inverts a triangle") from None
        u = trial
        if np.max(np.abs(du[free])) * scale < tol:
            return u, stiffness, factor, iteration
        stiffness = model.stiffness(u)
        factor = factorised(stiffness[free][:, free], symmetric_lu)
        du = np.zeros_like(u)
        du[free] = -factor.solve(residual[free])
        if not np.all(np.isfinite(du)):
            raise EquilibriumFailed("the tangent is singular")
        if np.max(np.abs(du[free])) < tol:
            return u, stiffness, factor, iteration
    raise EquilibriumFailed(f"Newton did not converge in {maxit} iterations")


class Extensometer:
    """One fit's forward problem: mesh, frames and assumptions.

    Parameters
    ----------
    mesh : mesh2d.Mesh2D
    frames : authors.Frames
    assumptions : Assumptions
    fitted_region : int or None
        None: one material everywhere, p = (E, nu). 1: p = (E, nu) of the keloid's
        triangles, the others held at ``held`` = (E, nu).
    held : tuple, optional
        The skin's (E, nu) when ``fitted_region`` is set.
    """

    n_parameters = 2
    """Length of p: the first columns of the model's dR/dp, here (E, nu)."""

    def __init__(
        self, mesh, frames: Frames, assumptions=Assumptions(), fitted_region=None, held=None
    ):
        if fitted_region is not None and held is None:
            raise ValueError("a fitted region needs the held material's (E, nu)")
        self.mesh, self.frames, self.assumptions = mesh, frames, assumptions
        self.model = PlanarNeoHookean(mesh.points, mesh.triangles, assumptions.plane)
        self.held = held
        fitted = (
            np.ones(mesh.n_triangles) if fitted_region is None else mesh.region == fitted_region
        )
        self.weights = np.asarray(fitted, dtype=float)
        held_nodes = [mesh.fixed] + ([mesh.exterior] if assumptions.fix_ring else [])
        held_nodes = np.setdiff1d(np.concatenate(held_nodes), mesh.moving)
        self.moving_x = 2 * mesh.moving
        pinned = np.concatenate(
            [self.moving_x, 2 * mesh.moving + 1, 2 * held_nodes, 2 * held_nodes + 1]
        )
        self.prescribed = np.unique(pinned)
        free = np.ones(2 * mesh.n_nodes, dtype=bool)
        free[self.prescribed] = False
        self.free = np.flatnonzero(free)
        self.normals = mesh.moving_normals()
        self._observation(frames)

    def _observation(self, frames: Frames) -> None:
        """The DIC box, its mass matrix's factor and the projected DIC displacements."""
        x = frames.dic_reference_mm
        low, high = x.min(axis=0), x.max(axis=0)
        pad = 1e-9 * np.abs(high - low).max()
        self.box = (low[0] - pad, low[1] - pad, high[0] + pad, high[1] + pad)
        cells = mesh2d.cells_in_box(self.mesh, self.box)
        if not cells.any():
            raise ValueError("no triangle lies inside the DIC box; refine the mesh")
        self.box_nodes = np.unique(self.mesh.triangles[cells])
        mass = mesh2d.p1_mass(self.mesh, cells)[self.box_nodes][:, self.box_nodes]
        self.box_area = float(mass.sum())
        self.mass_factor = scipy.linalg.cholesky(mass.toarray(), lower=False)  # M = U^T U
        self.measured = mls_project(x, frames.dic_displacement_mm, self.mesh.points[self.box_nodes])
        self.interpolation = mesh2d.interpolation_matrix(self.mesh, x)

    # ------------------------------------------------------------------ parameters
    def set_parameters(self, p) -> None:
        """(E, nu) of the fitted material; the held one elsewhere."""
        young, poisson = float(p[0]), float(p[1])
        if self.held is None:
            self.model.set_parameters(young, poisson)
        else:
            fitted = self.weights > 0
            self.model.set_parameters(
                np.where(fitted, young, self.held[0]), np.where(fitted, poisson, self.held[1])
            )

    def force(self, u: np.ndarray) -> float:
        """The model's x force on the skin at the moving pad [N]."""
        if self.assumptions.force == "traction":
            return float(self.model.edge_force(u, self.normals, self.mesh.moving_owner)[0])
        return float(self.model.residual(u)[self.moving_x].sum())

    def _force_derivative(self, u, stiffness, by_p, sensitivity) -> np.ndarray:
        if self.assumptions.force == "traction":
            by_u, by_p_edge = self.model.edge_force_derivatives(
                u, self.normals, self.mesh.moving_owner, self.weights
            )
            return by_u[0] @ sensitivity + by_p_edge[0, : self.n_parameters]
        row = np.asarray(stiffness[self.moving_x].sum(axis=0)).ravel()
        return row @ sensitivity + by_p[self.moving_x].sum(axis=0)

    # ------------------------------------------------------------------ equilibrium
    def _newton(self, u, target):
        return newton(self.model, u, self.prescribed, target, self.free)

    def _frame(self, u, target):
        """One frame from state u, splitting the increment when Newton fails."""
        for pieces in (1, 2, 4, 8):
            start = u[self.prescribed]
            state, total = u, 0
            try:
                for k in range(1, pieces + 1):
                    goal = start + (target - start) * k / pieces
                    state, stiffness, factor, its = self._newton(state, goal)
                    total += its
                return state, stiffness, factor, total
            except (EquilibriumFailed, FloatingPointError):
                continue
        raise EquilibriumFailed("no equilibrium even in 8 sub-steps")

    def targets(self) -> np.ndarray:
        """The prescribed values (K, n_prescribed) of every frame."""
        u = np.zeros((len(self.frames.pad_ux_mm), 2 * self.mesh.n_nodes))
        u[:, self.moving_x] = self.frames.pad_ux_mm[:, None]
        return u[:, self.prescribed]

    def solve(self, p, sensitivities: bool = True, previous: Solution | None = None) -> Solution:
        """Every frame's equilibrium at p = (E, nu), with du/dp and dF/dp if asked.

        ``previous`` (a solution with sensitivities) gives each frame a first-order start.
        """
        p = np.asarray(p, dtype=float)
        self.set_parameters(p)
        u = np.zeros(2 * self.mesh.n_nodes)
        states, forces, sens, force_d, iterations = [], [], [], [], []
        for k, target in enumerate(self.targets()):
            result = None
            if previous is not None and previous.sensitivity is not None:
                guess = previous.u[k] + previous.sensitivity[k] @ (p - previous.p)
                try:
                    result = self._newton(guess, target)
                except (EquilibriumFailed, FloatingPointError):
                    result = None
            u, stiffness, factor, its = result if result is not None else self._frame(u, target)
            states.append(u.copy())
            forces.append(self.force(u))
            iterations.append(its)
            if sensitivities:
                by_p = self.model.residual_derivatives(u, self.weights)[:, : self.n_parameters]
                s = np.zeros((2 * self.mesh.n_nodes, self.n_parameters))
                s[self.free] = -factor.solve(by_p[self.free])
                sens.append(s)
                force_d.append(self._force_derivative(u, stiffness, by_p, s))
        return Solution(
            p, np.array(states), np.array(forces),
            np.array(sens) if sensitivities else None,
            np.array(force_d) if sensitivities else None, iterations,
        )  # fmt: skip

    # ------------------------------------------------------------------ the cost
    def _misfit(self, solution: Solution) -> np.ndarray:
        """d_t = u_t - u_msr,t at the box nodes (K, nb, 2) [mm]."""
        return solution.u.reshape(len(solution.u), -1, 2)[:, self.box_nodes] - self.measured

    def residuals(self, solution: Solution) -> np.ndarray:
        """r with J = 1/2 |r|^2: sqrt 2 U d_t (per frame, x then y) and L_t."""
        d = self._misfit(solution)
        field = np.sqrt(2.0) * np.einsum("ab,kbi->kia", self.mass_factor, d)
        return np.concatenate([field.ravel(), solution.force - self.frames.force_n])

    def jacobian(self, solution: Solution) -> np.ndarray:
        """dr/dp (len r, 2) from the sensitivities."""
        k = len(solution.u)
        s = solution.sensitivity.reshape(k, -1, 2, 2)[:, self.box_nodes]  # (K, nb, comp, p)
        field = np.sqrt(2.0) * np.einsum("ab,kbij->kiaj", self.mass_factor, s)
        return np.vstack([field.reshape(-1, 2), solution.force_derivative])

    def cost(self, solution: Solution) -> dict:
        """J, its two parts and the RMS errors of a solution."""
        d = self._misfit(solution)
        field = float(np.sum(np.einsum("ab,kbi->kia", self.mass_factor, d) ** 2))
        miss = solution.force - self.frames.force_n
        at_dic = np.stack([self.interpolation @ u.reshape(-1, 2) for u in solution.u])
        return {
            "cost": field + 0.5 * float(miss @ miss),
            "cost_displacement": field,
            "cost_force": 0.5 * float(miss @ miss),
            "rms_displacement_mm": float(
                np.sqrt(np.mean((at_dic - self.frames.dic_displacement_mm) ** 2))
            ),
            "rms_force_n": float(np.sqrt(np.mean(miss**2))),
        }
