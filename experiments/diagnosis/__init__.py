"""Closing the loop on data: the diagnosis command and its studies (docs/diagnosis.md).

- ``diagnose``: a dataset's diagnosis, ``diagnosis.json`` and figures (``dvs diagnose``);
- ``study``: every effect alone over several seeds (``dvs study diagnosis``);
- ``detection``: how large each effect must be to meet the criteria (``dvs study detection``);
- ``outoflibrary``: data from physics outside the library, an FE slab (``dvs study outoflibrary``);
- ``continuumstudy``: the loop on scikit-fem continuum data (``dvs study continuum``);
- ``tissuedefaults``: the defaults on Q2 tissue patches of another generator
  (docs/results/tissue-defaults.md);
- ``guardstudy``: the linearised overfitting guard against exact refits, check by check.
"""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.diagnosis.diagnose": ("base_settings", "diagnose_dataset"),
    },
)
