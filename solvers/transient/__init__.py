"""Transients of the forward model: M B'' + D B' + K(B)(B - B0) = F_B(t)
(docs/transient.md, eq. 22).

- ``stepping``: the integrator; ``schemes``: Newmark, generalised-alpha, backward Euler;
- ``result``: what a run returns and the settling time;
- ``profiles``: F_B(t), a step, a ramp or any callable;
- ``steadystate``: the run to steady state against the static equilibrium;
- ``modal``: modes and the damping that settles fastest;
- ``sundials``: a cross-check with CVODES or IDAS through CasADi."""

from solvers.transient.modal import modal_basis, optimal_damping
from solvers.transient.profiles import ramp_load, step_load
from solvers.transient.result import TransientResult, settling_time
from solvers.transient.schemes import generalized_alpha
from solvers.transient.steadystate import compare_with_equilibrium, run_to_steady_state
from solvers.transient.stepping import StepSettings, TransientSolver, transient_solver

__all__ = [
    "StepSettings",
    "TransientResult",
    "TransientSolver",
    "compare_with_equilibrium",
    "generalized_alpha",
    "modal_basis",
    "optimal_damping",
    "ramp_load",
    "run_to_steady_state",
    "settling_time",
    "step_load",
    "transient_solver",
]
