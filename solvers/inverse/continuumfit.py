"""The homogeneous linear-elastic fit's forward map: every case from one factorisation.

For the linear-elastic model (``symbolic.continuum_model.ContinuumModel``) the
stiffness on the free points is K(x) = mu_L(E, nu) K_mu + lambda(E, nu) K_lambda with
the two matrices fixed (eq. C3), so each evaluation of the nested fit needs one sparse
factorisation of the saddle system

    M(x) s_k = [[K(x), C^T], [C, 0]] [Delta_k; lam_k] = [F_k; Q d_k]

for all load cases, and the sensitivities ds_k/dx_j = -M^-1 [dK/dx_j Delta_k; 0] one
more solve with 2 columns per case. ``EquilibriumSolver`` solved each case by Newton on
CasADi Functions and formed dg/dx by CasADi per case: the homogeneous fit took about
a minute at 27 x 27 x 4 that way, this path a few factorisations' worth. The states
are the same to rounding (the same linear systems, solved directly). Without probe
constraints M is K, symmetric positive definite, and CHOLMOD factorises it
(``solvers.forward.linearpath.factorise``); the saddle matrix goes to SuperLU.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.forward.linearpath import factorise
from solvers.linalg.blas import one_thread
from symbolic.continuum import KPA


def lame_derivatives(young_kpa: float, poisson: float) -> np.ndarray:
    """d(mu_L, lambda)/d(E, nu), (2, 2) [N/mm^2 per kPa; N/mm^2]."""
    young = KPA * young_kpa
    stretch = (1.0 + poisson) * (1.0 - 2.0 * poisson)
    return np.array(
        [
            [KPA / (2.0 * (1.0 + poisson)), -young / (2.0 * (1.0 + poisson) ** 2)],
            [KPA * poisson / stretch, young * (1.0 + 2.0 * poisson**2) / stretch**2],
        ]
    )


class ContinuumSystem:
    """States and ds/dx of every load case of a linear-elastic problem at x.

    Parameters
    ----------
    problem : InverseProblem
        Its model is a ``ContinuumModel``; its names the estimated parameters (E and
        nu enter K, the others do not move the equilibrium).
    """

    def __init__(self, problem):
        model = problem.model
        self.model, self.names = model, tuple(problem.names)
        self.coupling = sp.kron(sp.identity(3), model._constraint_free).tocsr()
        self.n_displacement = 3 * model.n_free
        self.right_hand_sides = np.column_stack([self._rhs(case) for case in problem.cases])

    @staticmethod
    def applies(problem) -> bool:
        """True for the linear-elastic model (its K is mu_L K_mu + lambda K_lambda)."""
        model = problem.model
        return getattr(model, "energy", None) == "linear-elastic" and hasattr(model, "continuum")

    def _rhs(self, case) -> np.ndarray:
        force = np.ravel(case.force, order="F")
        if self.coupling.shape[0] == 0:
            return force
        prescribed = self.model._constraint_rows @ case.prescribed
        return np.concatenate([force, np.ravel(prescribed, order="F")])

    def _saddle(self, stiffness: sp.spmatrix) -> sp.csc_matrix:
        if self.coupling.shape[0] == 0:
            return sp.csc_matrix(stiffness)
        return sp.bmat([[stiffness, self.coupling.T], [self.coupling, None]], "csc")

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (n_state, n_cases) and their sensitivities (n_state, n_cases, n_x)."""
        values = self.model.values(dict(zip(self.names, np.asarray(x, dtype=float))))
        young, poisson = float(values["E"]), float(values["nu"])
        terms = self.model.continuum
        mu_l, lam = self.model.coefficients(values)
        stiffness = float(mu_l) * terms["shear"] + float(lam) * terms["volumetric"]
        factor = factorise(self._saddle(stiffness), definite=self.coupling.shape[0] == 0)
        with one_thread():  # thin BLAS calls (solvers/linalg/blas.py)
            states = factor.solve(self.right_hand_sides)
        n, n_cases = self.n_displacement, states.shape[1]
        slopes = lame_derivatives(young, poisson)
        sensitivities = np.zeros(states.shape + (len(self.names),))
        moved = [(j, ("E", "nu").index(n)) for j, n in enumerate(self.names) if n in ("E", "nu")]
        if moved:
            shear, volumetric = terms["shear"] @ states[:n], terms["volumetric"] @ states[:n]
            forces = np.zeros((states.shape[0], n_cases * len(moved)))
            for i, (_, which) in enumerate(moved):
                block = slopes[0, which] * shear + slopes[1, which] * volumetric
                forces[:n, i * n_cases : (i + 1) * n_cases] = block
            with one_thread():
                solved = -factor.solve(forces)
            for i, (j, _) in enumerate(moved):
                sensitivities[:, :, j] = solved[:, i * n_cases : (i + 1) * n_cases]
        return states, sensitivities
