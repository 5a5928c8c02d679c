"""Stand-ins: candidates that lower the residual without being its cause.

A refit that explains the residual by driving the model it extends to the edge of
its parameter space, by sitting on one of the effect's own bounds, or by a size no
tissue has, stands in for something the library lacks (model error, or another
effect); so does one that does not predict left-out data better than chance
(``solvers.diagnosis.guard``). The loop lists them in ``Diagnosis.stand_ins`` and never
selects them (docs/diagnosis.md, "The selection rule"). Also here: the BIC with the
dispersion phi of ``solvers.diagnosis.leftout``.
"""

from __future__ import annotations

import numpy as np

from solvers.diagnosis.fit import EffectFit

BOUND_MARGIN = 0.01
"""A parameter within this fraction of its internal range from a bound sits on it
(for alpha, estimated in log space over [0.01, 100] N/mm: within 10 % of a bound)."""


def on_bounds(fit: EffectFit) -> np.ndarray:
    """Entries of p on (or within ``BOUND_MARGIN`` of) a bound, in internal coordinates."""
    problem = fit.problem
    z = problem.to_internal(fit.p)
    lower, upper = problem.to_internal(problem.lower), problem.to_internal(problem.upper)
    margin = BOUND_MARGIN * (upper - lower)
    return (z - lower <= margin) | (upper - z <= margin)


def pushed_to_bounds(current: EffectFit, refit: EffectFit) -> list[str]:
    """Parameters of the current model that only the refit puts on a bound.

    An effect that explains the residual by driving the model it extends to the
    edge of its parameter space is standing in for something else (a regular
    estimate is interior, and the chi^2 gain of a fit against a bound is no
    evidence for the effect).
    """
    before = on_bounds(current)
    after = on_bounds(refit)[: before.size] & current.free
    return [label for label, b, a in zip(current.problem.labels, before, after) if a and not b]


ACTIVE = 1e-4
"""An effect's own parameter within this fraction of its natural range of a bound is on
it (trf stops within about 1e-9 of an active bound at a tight tolerance)."""


def own_bounds(refit: EffectFit, name: str) -> list[str]:
    """The added effect's parameters that end on one of their bounds other than 0: within
    ``ACTIVE`` of it, or pressing against it, the Gauss-Newton step along the parameter
    from the refit, -(J^T rho)_j / (J^T J)_jj, reaching the bound (the least squares would
    go beyond it; a refit stopped at a loose tolerance ends just inside). A margin of the
    range instead would count a modest estimate of a wide linear range (layering's -0.9
    to 300) as on its bound."""
    problem = refit.problem
    block = problem.slice_of(name)
    values, lower, upper = refit.p[block], problem.lower[block], problem.upper[block]
    columns = refit.jacobian[:, block]
    curvature = np.maximum(np.sum(columns**2, axis=0), 1e-300)
    step = -(columns.T @ refit.whitened) / curvature  # natural units
    margin = ACTIVE * (upper - lower)
    low = (values - lower <= np.maximum(margin, -step)) & (lower != 0.0)
    high = (upper - values <= np.maximum(margin, step)) & (upper != 0.0)
    return [label for label, o in zip(problem.labels[block], low | high) if o]


def implausible(refit: EffectFit, effect) -> list[str]:
    """The added effect's parameters outside the range plausible for tissue
    (``Effect.plausible``), as 'label = value'."""
    block = refit.problem.slice_of(effect.name)
    low, high = effect.plausible_range(len(refit.problem.positions))
    values = refit.p[block]
    outside = (values < low) | (values > high)
    labels = refit.problem.labels[block]
    return [f"{label} = {value:.3g}" for label, value, o in zip(labels, values, outside) if o]


def stand_in_reason(current: EffectFit, refit: EffectFit, effect) -> str | None:
    """Why a refit that lowered the residual is a stand-in rather than a cause, or None:
    it drives the current model to a bound, ends on its own bound or leaves its
    plausible range."""
    pushed = pushed_to_bounds(current, refit)
    if pushed:
        return f"refit drives {', '.join(pushed)} to a bound"
    own = own_bounds(refit, effect.name)
    if own:
        return f"ends at its bound ({', '.join(own)})"
    outside = implausible(refit, effect)
    if outside:
        return f"implausible for tissue ({', '.join(outside)})"
    return None


def bic_improves(previous, candidate, phi: float) -> bool:
    """BIC with the dispersion falls from step ``previous`` to ``candidate``
    (``solvers.diagnosis.record.Step``): chi^2 / phi + k log m, k effective dof."""
    m = np.log(candidate.fit.whitened.size)
    change = (candidate.fit.cost - previous.fit.cost) / (candidate.sigma**2 * phi)
    change += (candidate.fit.effective_dof() - previous.fit.effective_dof()) * m
    return change < 0.0
