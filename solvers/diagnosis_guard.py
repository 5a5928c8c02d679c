"""The overfitting guard: does an added effect predict a left-out load case better?

For every load case h in turn, both the previous model and the model with the
new effect are fitted to the other cases, and then predict case h with their
shared parameters fixed. Per-capture nuisance parameters of case h (rigid
motion, measurement scale) cannot be predicted; they are fitted to case h
alone, and since each such parameter lowers a pure-noise chi^2 by 1 on
average, their number is charged:

    improvement = sum_h (chi^2_before,h - chi^2_after,h) - (n_after - n_before),

with chi^2_h = |W_h r_h|^2 / sigma^2 of the prediction and n the number of
nuisance parameters fitted to the left-out cases. The effect passes when the
improvement is positive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.diagnosis_fit import EffectFit, fit


@dataclass
class PredictionCheck:
    """Left-out prediction of every load case, before and after adding an effect."""

    held_out: list[int]
    chi2_before: list[float]
    chi2_after: list[float]
    nuisance_before: int
    nuisance_after: int

    @property
    def improvement(self) -> float:
        """Drop of the summed prediction chi^2, less the extra nuisance parameters."""
        drop = float(np.sum(self.chi2_before) - np.sum(self.chi2_after))
        return drop - (self.nuisance_after - self.nuisance_before)

    @property
    def improves(self) -> bool:
        """True when the new model predicts the left-out cases better."""
        return self.improvement > 0.0

    def reason(self) -> str:
        """One line for reports."""
        return (
            f"left-out prediction chi2 {np.sum(self.chi2_before):.1f} -> "
            f"{np.sum(self.chi2_after):.1f} ({self.nuisance_after - self.nuisance_before} "
            f"nuisance parameters charged): {'better' if self.improves else 'not better'}"
        )

    def record(self) -> dict:
        """As in diagnosis.json."""
        return {
            "held_out": self.held_out,
            "chi2_before": self.chi2_before,
            "chi2_after": self.chi2_after,
            "nuisance_before": self.nuisance_before,
            "nuisance_after": self.nuisance_after,
            "improvement": self.improvement,
            "improves": self.improves,
        }


def _mapped(source_labels, source_p, target) -> tuple[np.ndarray, np.ndarray]:
    """p of ``target`` from a fit with other labels; unknown entries start at 0, free."""
    known = dict(zip(source_labels, source_p))
    start = target.start()
    free = np.ones(len(target.labels), dtype=bool)
    for i, label in enumerate(target.labels):
        if label in known:
            start[i] = known[label]
            free[i] = False
    return start, free


def predict_left_out(model_fit: EffectFit, held: int, sigma: float) -> tuple[float, int]:
    """chi^2 of the prediction of base case ``held`` after fitting the other cases.

    Returns the chi^2 and the number of nuisance parameters fitted to the held case.
    """
    problem = model_fit.problem
    train = [k for k in problem.positions if k != held]
    train_problem = problem.with_effects(problem.effects, positions=train)
    start, _ = _mapped(problem.labels, model_fit.p, train_problem)
    trained = fit(train_problem, start)
    test_problem = problem.with_effects(problem.effects, positions=[held])
    start, free = _mapped(train_problem.labels, trained.p, test_problem)
    if free.any():
        predicted = fit(test_problem, start, free)
        rho = predicted.whitened
    else:
        r, _, _ = test_problem.evaluate(start)
        rho = test_problem.whiten(r)
    return float(rho @ rho) / sigma**2, int(free.sum())


def prediction_check(
    previous: EffectFit, new: EffectFit, sigma: float, cache: dict | None = None
) -> PredictionCheck:
    """Leave-one-case-out comparison of ``previous`` and ``new`` (see module docstring)."""
    cache = {} if cache is None else cache
    held_out, before, after = [], [], []
    n_before = n_after = 0
    for held in new.problem.positions:
        key = (tuple(e.name for e in previous.problem.effects), held)
        if key not in cache:
            cache[key] = predict_left_out(previous, held, sigma)
        chi2_before, nuisance = cache[key]
        chi2_after, nuisance_after = predict_left_out(new, held, sigma)
        held_out.append(int(new.problem.indices[held]))
        before.append(chi2_before)
        after.append(chi2_after)
        n_before += nuisance
        n_after += nuisance_after
    return PredictionCheck(held_out, before, after, n_before, n_after)
