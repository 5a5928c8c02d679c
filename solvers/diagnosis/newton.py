"""Newton on one load case's extended equilibrium, with load continuation as fallback.

g(s) = h(s, p) + L = 0 (docs/model.md eq. 22; L the case's load, -F_B and -Q d on the
constraint rows) is solved by Newton with a backtracking line search on |g|, as
``EquilibriumSolver`` does. A stiff nonlinear base far from rest (the stiffening at the
healthy skin's longest travel, 8.4 mm) can lose Newton from rest; then the load is
applied in steps,

    g_t(s) = h(s, p) + t L = 0,     t = 1/4, 2/4, ..., 1,

each step's Newton starting from the last one's solution scaled by the load ratio, and a
step that fails is halved (at most ``HALVINGS`` times in a row) before the fallback gives
up, as ``EquilibriumSolver.solve_by_continuation`` does. F_B and the prescribed
displacements d grow together, so every intermediate problem is the experiment at a
shorter travel.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.diagnosis import splitpath
from solvers.forward.equilibrium import EquilibriumError

ITERATIONS = 40
"""Newton steps per solve."""

BACKTRACKS = 30
"""Halvings of one Newton step by the line search."""

STEPS = 4
"""Load steps of the continuation."""

HALVINGS = 3
"""How often in a row the continuation's step may be halved."""

CHORDS = 6
"""Chord steps at most with a factorisation from before (``newton``'s ``stale``)."""

CONTRACTION = 0.25
"""A chord step must shrink |g| at least this much, or full Newton takes over."""


def newton(residual, factorise, state: np.ndarray, target: float, stale=None):
    """s with |g(s)| <= ``target`` by Newton from ``state``, and the factorised dg/ds of
    its last step (exact for g linear in s, accurate to that step otherwise).

    With ``stale``, a factorisation of dg/ds from a nearby solve (the same case at the
    last p), chord steps s <- s - stale^-1 g(s) come first while each shrinks |g| by
    ``CONTRACTION`` (at most ``CHORDS``): from a start predicted to first order they
    converge without a new factorisation; then dg/ds is factorised there and one Newton
    step taken with it, as full Newton would end (the implicit-function sensitivities
    and finite differences of the solution need it to rounding, not to ``target``).

    Parameters
    ----------
    residual : callable
        s -> g(s), flat.
    factorise : callable
        s -> a ``StateJacobian`` of dg/ds at s.
    state : numpy.ndarray
        Start.
    target : float
        Tolerance on |g| [as g].
    stale : StateJacobian, optional
        A factorisation of dg/ds near ``state``.

    Raises
    ------
    EquilibriumError
        Not converged within ``ITERATIONS`` steps, or g not finite.
    """
    g = residual(state)
    if stale is not None:
        for _ in range(CHORDS):
            norm = float(np.linalg.norm(g))
            if not np.isfinite(norm) or norm <= target:
                break
            trial = state + stale.solve(-g)
            g_trial = residual(trial)
            if not np.linalg.norm(g_trial) <= CONTRACTION * norm:
                break
            state, g = trial, g_trial
        if float(np.linalg.norm(g)) <= target:  # one Newton step more: to rounding
            jacobian = factorise(state)
            return state + jacobian.solve(-g), jacobian
    jacobian = None
    for _ in range(ITERATIONS):
        norm = float(np.linalg.norm(g))
        if not np.isfinite(norm):
            break
        if norm <= target and jacobian is not None:
            return state, jacobian
        jacobian = factorise(state)
        if norm <= target:
            return state, jacobian
        step = jacobian.solve(-g)
        length = 1.0
        for _ in range(BACKTRACKS):
            trial = state + length * step
            g_trial = residual(trial)
            if np.linalg.norm(g_trial) < norm:
                break
            length *= 0.5
        state, g = trial, g_trial
    raise EquilibriumError(
        f"extended equilibrium did not converge (|g| = {np.linalg.norm(g):.2e}); "
        "the effect parameters may be unrealistic"
    )


def by_continuation(residual, factorise, load: np.ndarray, zero: np.ndarray, target: float):
    """``newton`` on g(s) - (1 - t) L for t = 1/4, ..., 1 from rest, each step started from
    the last solution scaled by the load ratio (the module docstring); a failed step is
    retried at half the size, at most ``HALVINGS`` times in a row.

    Parameters
    ----------
    load : numpy.ndarray
        L, the case's part of g (the load; g = h + L).
    zero : numpy.ndarray
        The rest state.
    """
    reached, state, size, failures = 0.0, zero, 1.0 / STEPS, 0
    while True:
        t = min(1.0, reached + size)
        start = state * (t / reached) if reached else zero
        try:
            state, jacobian = newton(
                lambda s, t=t: residual(s) - (1.0 - t) * load, factorise, start, target
            )
        except EquilibriumError as error:
            failures += 1
            if failures > HALVINGS:
                raise EquilibriumError(
                    f"extended equilibrium not reached by load continuation (at {t:.3g} of "
                    f"the load: {error})"
                ) from error
            size *= 0.5
            continue
        if t == 1.0:
            return state, jacobian
        reached, failures = t, 0


def solve_case(problem, position: int, p: np.ndarray, start, tolerance: float, continuation):
    """``ExtendedProblem.solve_state``: Newton on one case's g(s, p) = 0 from the case's
    last solve on ``problem`` predicted to first order (s + ds/dp dp, with chord steps on
    that solve's factorisation), else from ``start`` (default rest); with
    ``continuation``, load continuation from rest where Newton fails. Returns the state
    and its ``StateJacobian``. g and dg/ds are the split path's where it applies
    (``solvers.diagnosis.splitpath``), else the case's CasADi Functions."""
    residual, jacobian = splitpath.equations(problem, position, p)
    zero = np.zeros(problem.extended.n_state)

    def factorise(state):
        return problem._factorised(jacobian(state))

    target = tolerance * max(float(np.linalg.norm(residual(zero))), 1e-300)
    first = zero if start is None else np.array(start, dtype=float)
    memory = problem.cache.get(problem._memory_key(position))
    stale = None
    if memory is not None and memory[0].shape == p.shape:
        last_p, last_state, sensitivity, stale = memory
        first = last_state + sensitivity @ (p - last_p)  # ds/dp: s(p) to first order
    try:
        return newton(residual, factorise, first, target, stale)
    except EquilibriumError:
        if not continuation:
            raise
    value = problem.numeric_of(problem.extended.case_parts(position).load)(p)[0]
    load = np.ravel(value.toarray() if sp.issparse(value) else value)
    return by_continuation(residual, factorise, load, zero, target)
