"""The fit as the commands run it: ``command`` (``dvs fit``) and ``stepzero`` (step 0
in the commands beyond fit and diagnose). The problem they pose is
``experiments.problem``; step 0's choices are ``experiments.basemodel``."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.fit.stepzero": ("add_model_arguments", "chosen_base"),
    },
)
