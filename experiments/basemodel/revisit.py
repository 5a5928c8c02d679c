"""Step 0 revisited: the surroundings re-estimated once the loop has added an effect.

Step 0 chooses how far the tissue goes on beyond the markers, how it is held there and
the probe's radius on data that may hold an effect the base model lacks; the choice
then absorbs what it can of that effect. On FE tissue with the contact 2 mm off the
declared point, step 0 took a probe radius of 3.6 mm for a true 2.5 mm; once the loop
added contact_offset, that radius was wrong, and a stand-in (layering) took up the
rest (docs/results/tissue-defaults.md, "Injected effects: the revisit").

So after every effect the loop accepts (and for a candidate its overfitting guard
rejects), the search of step 0 (``choice.search_surroundings``) runs again with the
effects in every member, on the search's volumes, starting from the surroundings in
use. When another member fits better by more than the data can tell from noise, the
loop's model is rebuilt with those surroundings at the loop's resolution and refitted
(``Revisit``); then the probe's shape is compared on the loop's volume
(``choice.checked_shape``); the step records the change. The settings were already
counted in step 0's BIC (k = 6), so a change costs no further parameter.
"""

from __future__ import annotations

import time

from scipy import stats

from experiments.basemodel.choice import BaseChoice, checked_shape, search_surroundings
from experiments.basemodel.family import Surroundings
from solvers.diagnosis.fit import EffectFit


class Revisit:
    """The callable the loop runs after each accepted effect (``diagnose(revisit=)``).

    Parameters
    ----------
    choice : BaseChoice
        Step 0's outcome, with the continuum chosen.
    log : callable
        Progress lines.
    level : float
        The loop's significance level: the surroundings change only when the search's
        chi^2 drops by more than the 1-dof quantile at it (6.6 at 0.01), a difference
        the data can tell (as in the resolution check).
    """

    def __init__(self, choice: BaseChoice, log, level: float = 0.01):
        self.search = choice.trials[0].family
        self.loop = choice.chosen.family
        base = choice.chosen.fit.problem.base
        self.surroundings = {id(base): (base, choice.chosen.surroundings)}
        """id -> (base problem, its surroundings), for each base fitted (a fit's effects
        share its base; the problem is held so that its id stays its own)."""
        self.log = log
        self.level, self.limit = level, float(stats.chi2.isf(level, 1))
        self.records: list[dict] = []

    def __call__(self, current: EffectFit) -> tuple[EffectFit, dict] | None:
        """The refit on better surroundings with ``current``'s effects and its record,
        or None when the surroundings in use stay the best."""
        begin = time.perf_counter()
        effects = current.problem.effects
        names = ", ".join(e.name for e in effects)
        key = self.surroundings[id(current.problem.base)][1]
        family = self.search.with_effects(
            effects, current.p, lambda line: self.log(f"with {names}: {line}")
        )
        here = family.trial_at(key)
        best = search_surroundings(family, key.margin_mm, key.support, key.radius_mm, key.shape)
        record = {
            "effects": [e.name for e in effects],
            "before": _as_dict(key),
            "after": _as_dict(best.surroundings),
            "search_chi2_before": here.chi2,
            "search_chi2_after": best.chi2,
            "trials": len(family.trials),
        }
        moved, s = None, key
        if best.surroundings != key and here.chi2 - best.chi2 > self.limit:
            loop = self.loop.with_effects(effects, best.fit.p, lambda *_: None)
            trial = loop.trial_at(best.surroundings)
            before, after = current.cost, trial.fit.cost
            record.update(chi2_before=before / family.sigma**2, chi2_after=after / family.sigma**2)
            if after < before:
                moved, s = trial.fit, best.surroundings
        # the probe's shape, on the loop's volume (``checked_shape``), also once the
        # residual is consistent with noise: the loop goes on testing effects there, and
        # a shape the data could not tell at step 0 can be clear with the effect in (FE
        # tissue with a gradient and a 2.5 mm disc: 5 chi^2 between the shapes at step 0,
        # 54 with heterogeneity; on the Gaussian, layering then stood in for the disc)
        fitted = moved or current
        loop = self.loop.with_effects(effects, fitted.p, lambda *_: None)
        kept = loop.trial_at(s, fitted.p)
        shaped, record["shapes"] = checked_shape(kept, self.level, self.log)
        shaped = None if shaped is kept else shaped
        if shaped is not None and shaped.fit.cost < fitted.cost:
            record.setdefault("chi2_before", current.cost / family.sigma**2)
            record["chi2_after"] = shaped.chi2
            record["after"] = _as_dict(shaped.surroundings)
            moved, s = shaped.fit, shaped.surroundings
        if moved is not None:
            self.surroundings[id(moved.problem.base)] = (moved.problem.base, s)
        record["changed"] = moved is not None
        record["seconds"] = time.perf_counter() - begin
        self.records.append(record)
        self.log(line(record))
        return None if moved is None else (moved, record)


def line(record: dict) -> str:
    """One log line of a revision."""
    before, after = (Surroundings(**record[k]).label() for k in ("before", "after"))
    took = f"({record['seconds']:.0f} s, {record['trials']} trials)"
    if record["changed"]:
        return (
            f"surroundings with {', '.join(record['effects'])}: {before} -> {after}, "
            f"chi2 {record['chi2_before']:.0f} -> {record['chi2_after']:.0f} {took}"
        )
    return f"surroundings with {', '.join(record['effects'])}: {before} kept {took}"


def _as_dict(s: Surroundings) -> dict:
    return {
        "margin_mm": s.margin_mm,
        "support": s.support,
        "radius_mm": s.radius_mm,
        "shape": s.shape,
    }
