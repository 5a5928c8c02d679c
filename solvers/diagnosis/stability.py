"""Where the material is stable: the parameters a diagnosis fit may evaluate.

The stiffness fields (heterogeneity, layering, stiffness_field; docs/effects.md,
"The extension machinery") scale the base's moduli by 1 + their sum, and their box
bounds alone allow a negative modulus: heterogeneity at h = (-0.9, -0.9) leaves
1 - 1.8 at a corner of the volume. There K(p) is indefinite and no equilibrium
exists. Each effect gives a lower bound on what it adds anywhere in the volume
(``Effect.least_modulus``); the fields add up, so

    m(p) = 1 + sum_e least_modulus_e(theta_e)

bounds the relative modulus from below, and p is admissible while m(p) exceeds
``STIFFNESS_FLOOR``. ``solvers.diagnosis.fit.fit`` returns a NaN residual outside (trf
then shrinks its step and tries again) and pulls a start outside in
(``into_admissible``).

Before this, left-out refits went there: 22 of 247 factorisations of one diagnosis (FE
tissue, a tilted force) and 12 of 210 of another (a stiffness gradient, with layering),
each a failed Cholesky and then a SuperLU solve of a model with no equilibrium.
"""

from __future__ import annotations

import numpy as np

STIFFNESS_FLOOR = 0.02
"""The least relative modulus the effects may leave anywhere in the volume."""


def least_modulus(problem, p: np.ndarray) -> float:
    """m(p): 1 + the sum of the effects' ``least_modulus`` [1] (``ExtendedProblem``)."""
    p = np.asarray(p, dtype=float)
    return 1.0 + sum(e.least_modulus(p[problem.slice_of(e.name)]) for e in problem.effects)


def admissible(problem, p: np.ndarray) -> bool:
    """True when m(p) > ``STIFFNESS_FLOOR``: K(p) is positive definite, the equilibrium
    exists."""
    return least_modulus(problem, p) > STIFFNESS_FLOOR


def into_admissible(problem, p: np.ndarray) -> np.ndarray:
    """p with the parameters of the effects that soften the material somewhere halved
    together until admissible (zero, those effects switched off, always is): a start."""
    p = np.array(p, dtype=float)
    blocks = [problem.slice_of(e.name) for e in problem.effects]
    softening = [b for e, b in zip(problem.effects, blocks) if e.least_modulus(p[b]) < 0.0]
    for _ in range(60):
        if admissible(problem, p):
            break
        for block in softening:
            p[block] *= 0.5
    return p
