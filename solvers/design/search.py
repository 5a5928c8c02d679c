"""The search for the best presses under a budget: greedy, then exchange.

A design is a multiset of the pool's candidate presses (a press may be repeated), on
top of presses already made (``start``: the dataset's own). With ``Criterion.score``
to maximise:

1. **greedy**: add, ``budget`` times, the candidate that raises the score most;
2. **exchange** (Fedorov's): for every chosen press, try every candidate in its
   place; make the best swap that raises the score, and sweep again until a sweep
   changes nothing.

Were the presses' information additive, the greedy step for the D-criterion from a
non-singular start would be within (1 - 1/e) of the optimal gain (log det is monotone
submodular in added PSD terms). It is not quite additive here, since the presses share
the rest markers' noise (eq. D5), and the other criteria have no such bound; so the gap
to an exhaustive search is measured instead (``exhaustive``; docs/design.md).

Every score costs one sum and one small product (eq. D5), so a sweep over hundreds of
candidates takes milliseconds per press.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from solvers.design.criteria import Criterion
from solvers.design.pool import InformationPool, Totals


@dataclass(frozen=True)
class SearchResult:
    """A chosen design.

    Attributes
    ----------
    chosen : list of int
        Pool indices of the new presses, in the order the greedy step added them.
    score : float
        The criterion's value of ``start`` + ``chosen``.
    greedy_score : float
        Its value after the greedy step alone (before exchanges).
    swaps : int
        Exchanges made.
    evaluations : int
        Scores computed.
    """

    chosen: list
    score: float
    greedy_score: float
    swaps: int
    evaluations: int


def _best(pool: InformationPool, criterion: Criterion, base: Totals, candidates):
    """The candidate whose addition to ``base`` scores highest, and that score."""
    best, best_score = None, -np.inf
    for k in candidates:
        value = criterion.score((base + pool.blocks[k]).matrix())
        if best is None or value > best_score:
            best, best_score = k, value
    return best, best_score


def search(
    pool: InformationPool,
    criterion: Criterion,
    budget: int,
    start=(),
    candidates=None,
    max_sweeps: int = 20,
    progress=None,
) -> SearchResult:
    """Greedy then exchange: ``budget`` new presses from ``candidates`` (default all).

    Parameters
    ----------
    start : sequence of int
        Pool indices of presses already made (kept, not counted in the budget).
    progress : callable, optional
        Called with one line per greedy step and per sweep.
    """
    if budget < 1:
        raise ValueError(f"the budget must be at least 1 press, got {budget}")
    candidates = list(range(len(pool.blocks)) if candidates is None else candidates)
    fixed = pool.totals(start)
    chosen, totals, evaluations = [], fixed, 0
    for step in range(budget):
        best, greedy_score = _best(pool, criterion, totals, candidates)
        evaluations += len(candidates)
        chosen.append(best)
        totals = totals + pool.blocks[best]
        if progress:
            progress(f"greedy {step + 1}/{budget}: score {greedy_score:.4g}")
    score, swaps = greedy_score, 0
    for sweep in range(max_sweeps):
        changed = False
        for position in range(len(chosen)):
            without = totals - pool.blocks[chosen[position]]
            best, value = _best(pool, criterion, without, candidates)
            evaluations += len(candidates)
            if value > score + 1e-9 * max(abs(score), 1.0) and best != chosen[position]:
                chosen[position], totals, score = best, without + pool.blocks[best], value
                swaps += 1
                changed = True
        if progress:
            progress(f"exchange sweep {sweep + 1}: score {score:.4g}, {swaps} swaps")
        if not changed:
            break
    return SearchResult(chosen, float(score), float(greedy_score), swaps, evaluations)


def exhaustive(pool: InformationPool, criterion: Criterion, budget: int, start=(), candidates=None):
    """The best multiset of ``budget`` presses by enumeration (small cases only).

    Returns the chosen indices and the score; the cost is C(n + budget - 1, budget)
    scores for n candidates.
    """
    candidates = list(range(len(pool.blocks)) if candidates is None else candidates)
    fixed = pool.totals(start)
    best, best_score = None, -np.inf
    for design in itertools.combinations_with_replacement(candidates, budget):
        total = fixed
        for k in design:
            total = total + pool.blocks[k]
        value = criterion.score(total.matrix())
        if value > best_score:
            best, best_score = list(design), value
    return best, float(best_score)
