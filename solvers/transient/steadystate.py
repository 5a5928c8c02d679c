"""The transient run to steady state, checked against the static equilibrium.

The check docs/transient.md asks for: integrate eq. (22) from rest with ``solvers.transient``
until velocity and residual vanish (the paper's forward solution), and compare the
end state with the equilibrium K(B)(B - B0) = F_B that ``solvers.forward.equilibrium``
solves directly (docs/model.md, eq. 22).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from solvers.forward.equilibrium import EquilibriumSolver
from solvers.transient.result import TransientResult
from solvers.transient.stepping import StepSettings, transient_solver
from symbolic.model import TissueModel


def run_to_steady_state(
    model: TissueModel,
    force_free,
    x=None,
    names=(),
    overrides=None,
    dt=None,
    method="generalized_alpha",
    tol=1e-10,
    t_max=1e3,
    start=None,
    settings=None,
) -> TransientResult:
    """Integrate eq. (22) from rest until it is steady: the paper-faithful forward solve.

    Parameters
    ----------
    model : TissueModel
        The model (without prescribed displacements).
    force_free : numpy.ndarray, Load or callable
        F_B on the free points, (n_free, 3) [N]; an array is a step load at t = 0.
    x, names :
        Symbolic stiffness parameters and their values, as for ``EquilibriumSolver``.
    overrides : dict, optional
        mu and gamma for M and D, e.g. the paper's ``{"mu": 1e-4, "gamma": 15.0}``.
    dt : float, optional
        Fixed step [s]; default adaptive (rtol 1e-4 of the displacement per step).
    method : str or Scheme
        ``newmark``, ``generalized_alpha`` or ``backward_euler``.
    tol : float
        Steady when |f(u) - F| <= tol |F| and sqrt(v^T M v / u^T f(u)) <= tol.
    t_max : float
        Give up (``steady`` False) after this time [s].
    start : numpy.ndarray, optional
        Initial displacement s, at rest.
    """
    settings = settings or StepSettings()
    settings = settings if dt is None else replace(settings, dt=float(dt))
    solver = transient_solver(model, names, method)
    return solver.integrate(force_free, t_max, x, overrides, settings, start, steady_tol=tol)


def compare_with_equilibrium(
    model: TissueModel,
    force_free: np.ndarray,
    x=None,
    names=(),
    overrides=None,
    method="generalized_alpha",
    tol=1e-10,
    **kwargs,
) -> dict:
    """The transient's end state against the static equilibrium (EquilibriumSolver).

    Arguments are those of ``run_to_steady_state`` (extra keywords go there too).

    Returns
    -------
    dict
        ``relative_distance_to_equilibrium`` |B_end - B_eq| / |B_eq - B0|,
        ``settling_time_s`` (all free points), ``probe_settling_time_s``,
        ``steady_time_s``, ``steady``, ``steps``, and the ``result`` and
        ``equilibrium`` objects themselves.
    """
    result = run_to_steady_state(
        model, force_free, x, names, overrides, method=method, tol=tol, **kwargs
    )
    equilibrium = EquilibriumSolver(model, names).solve(force_free, x)
    distance = np.linalg.norm(result.positions - equilibrium.positions)
    return {
        "relative_distance_to_equilibrium": float(
            distance / np.linalg.norm(equilibrium.positions - model.rest)
        ),
        "settling_time_s": result.settling_time,
        "probe_settling_time_s": result.probe_settling_time,
        "steady_time_s": result.steady_time,
        "steady": result.steady,
        "steps": result.steps,
        "result": result,
        "equilibrium": equilibrium,
    }
