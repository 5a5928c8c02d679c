"""Transients of the forward model: M B'' + D B' + K(B)(B - B0) = F_B(t)
(docs/transient.md, eq. 22).

- ``stepping``: the integrator (``TransientSolver``, ``transient_solver``, ``StepSettings``);
- ``schemes``: Newmark, generalised-alpha and backward Euler;
- ``result``: ``TransientResult`` and the settling time;
- ``loads``: F_B(t), step, ramp or any callable;
- ``steadystate``: the run to steady state against the static equilibrium;
- ``modal``: modes and the damping that settles fastest;
- ``sundials``: a cross-check with CVODES or IDAS through CasADi.
"""
