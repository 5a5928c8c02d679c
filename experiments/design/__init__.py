"""Experiment design on datasets (docs/design.md): ``plan`` (dataset -> candidates -> search
-> design.json), ``command`` (``dvs design``), ``options`` (the options it shares
with ``dvs next``), ``report``, ``nextpress`` and
``nextfield`` (``dvs next``, for the effects or for a stiffness map), ``nextjson`` (next.json's
keys), ``sequential``, ``lab`` and ``pathreport`` (press, diagnose, choose again against
FE data), ``predictions`` (do a design's predictions hold?), ``bench`` and
``speed`` (benchmarks)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.design.plan": ("DesignSettings", "Plan", "plan"),
        "experiments.design.sequential": ("SequentialSettings", "step"),
        "experiments.design.lab": ("ContinuumLab",),
    },
)
