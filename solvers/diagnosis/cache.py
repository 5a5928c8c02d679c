"""The store that problems derived from one another share, bounded by effect set (the
CasADi Functions of an effect set are large at fine grids)."""

from __future__ import annotations

from collections import OrderedDict


class SharedCache(dict):
    """The store that problems derived with ``with_effects`` share, bounded by effect set.

    Case data and noise models are small and kept. The CasADi Functions of an
    effect set and their numeric wrappers are not: at 27 x 27 x 4 they embed the
    stiffness terms, and a loop that tests nine effects, refits and holds out
    contacts builds dozens of sets (the continuum loop grew to 13-24 GB and was
    killed). Keys ``("functions", effect_set, ...)`` are grouped by their effect
    set; the ``limit`` most recently used sets are kept whole, an older one is
    dropped whole and rebuilt when it is needed again. (Counting single entries
    instead evicted the Functions of one set's ten load cases while the same
    evaluation still needed them: every evaluation rebuilt them all.) Two sets are
    what a refit and its left-out-contact guard alternate between (the current
    model and the candidate); with 4 the diagnosis design's compliant-base scenario
    at 27 x 27 x 4 was killed at 23 GB.
    """

    HEAVY = "functions"

    def __init__(self, limit: int = 2):
        super().__init__()
        self.limit = int(limit)
        self._sets: OrderedDict = OrderedDict()

    @classmethod
    def effect_set(cls, key):
        """The group of a heavy key, None for a small entry."""
        if isinstance(key, tuple) and len(key) > 1 and key[0] == cls.HEAVY:
            return key[1]
        return None

    def __getitem__(self, key):
        value = super().__getitem__(key)
        group = self.effect_set(key)
        if group in self._sets:
            self._sets.move_to_end(group)
        return value

    def __setitem__(self, key, value) -> None:
        super().__setitem__(key, value)
        group = self.effect_set(key)
        if group is None:
            return
        self._sets.setdefault(group, set()).add(key)
        self._sets.move_to_end(group)
        while len(self._sets) > self.limit:
            _, keys = self._sets.popitem(last=False)
            for old in keys:
                super().pop(old, None)
