"""What the design could have missed: the blind spots behind an "explained" verdict.

A residual consistent with noise rules out only what the design could have seen. The
last round of score tests is taken on the final model, so each test's profiled
information I (``ScoreTest.information``: A^T A / sigma^2 after the fitted parameters
are refitted) gives the non-centrality of that test against an effect of size theta_1,

    lambda(theta_1) = theta_1^T I theta_1                      (eq. D2, linearised),

and with it the power of the round's test (eq. D3 at the round's Bonferroni level,
one-sided for an effect bounded below by 0). An effect whose power at its realistic
magnitude (``Effect.default_magnitude``, in the library's standard pattern
``Effect.true_parameters``) stays below ``GOAL`` is a blind spot: the data do not rule
it out, and the verdict names it with the smallest magnitude the design would detect.

This is what docs/diagnosis.md ("What the verdict does not rule out") asks of a verdict on
a weak design: on the paper's two loads at one contact, a stiffness gradient and a
compliant base leave the residual at the noise, so "explained" must say that they were
not tested with any power.
The linearisation holds while the effect's signal is linear in theta; it is checked
against the nonlinear signal of ``solvers.design.information.effect_power`` in the tests.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from solvers.diagnosis.stats import ScoreTest, needed_noncentrality, power
from symbolic.effects.library import make_effect

GOAL = 0.8
"""Power below which an effect of realistic size counts as not ruled out."""


def noncentrality(test: ScoreTest, theta: np.ndarray) -> float:
    """lambda of ``test`` against theta (natural units), eq. (D2) linearised."""
    theta = np.asarray(theta, dtype=float)
    return float(theta @ test.information @ theta)


def _one_sided(effect, size: int) -> bool:
    return size == 1 and float(np.asarray(effect.lower, dtype=float)[0]) == 0.0


def detectable_magnitude(test: ScoreTest, effect, n_cases: int, level: float, goal=GOAL):
    """The smallest magnitude (``effect.magnitude_unit``) at which ``test`` reaches power
    ``goal`` at ``level``, or None when none within the effect's bounds does."""
    if test.information is None or test.dof == 0:
        return None
    one_sided = _one_sided(effect, test.information.shape[0])
    needed = needed_noncentrality(test.dof, level, one_sided, goal)
    _, high = effect.magnitude_range(n_cases)
    high = min(high, 1e3 * effect.default_magnitude)

    def gap(magnitude):
        return noncentrality(test, effect.true_parameters(magnitude, n_cases)) - needed

    if not np.isfinite(high) or gap(high) < 0:
        return None
    return float(optimize.brentq(gap, 0.0, high, xtol=1e-6 * high))


def blind_spots(
    scores: list[ScoreTest], n_cases: int, level: float, goal=GOAL, energy: str | None = None
) -> list[dict]:
    """The effects of a round of score tests that the design would miss at their
    realistic magnitude (power < ``goal`` at the round's level ``level / len(scores)``).

    Returns
    -------
    list of dict
        ``effect``, ``realistic`` (magnitude), ``power`` there, ``detectable`` (the
        magnitude at power ``goal``; None when no magnitude within the effect's bounds
        reaches it) and ``unit``, weakest power first.
    """
    spots = []
    each = level / max(len(scores), 1)
    for test in scores:
        effect = make_effect(test.effect, energy)
        realistic = float(effect.default_magnitude)
        if realistic <= 0.0 or test.information is None:
            continue
        theta = effect.true_parameters(realistic, n_cases)
        one_sided = _one_sided(effect, theta.size)
        chance = power(noncentrality(test, theta), test.dof, each, one_sided) if test.dof else 0.0
        if chance >= goal:
            continue
        spots.append(
            {
                "effect": test.effect,
                "realistic": realistic,
                "power": chance,
                "detectable": detectable_magnitude(test, effect, n_cases, each, goal),
                "unit": effect.magnitude_unit,
            }
        )
    return sorted(spots, key=lambda s: s["power"])


def sentence(spots: list[dict], goal=GOAL) -> str:
    """The blind spots in one clause, for the verdict ("" when there are none); the
    sizes the design would detect are in report.md."""
    if not spots:
        return ""
    return (
        "not ruled out: " + ", ".join(s["effect"] for s in spots) + f" (this design's power "
        f"against each at a realistic size is below {goal:g}; report.md lists the sizes it "
        "would detect)"
    )
