"""A dataset posed as an inverse problem: ``fitting`` (the fit's settings, the model on
the dataset's rest surfaces, the problem, its solution and ``result.json``) and
``surroundings`` (the tissue beyond the markers: rest surfaces extended by a margin)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.problem.fitting": (
            "FitSettings",
            "build_problem",
            "build_model",
            "solve",
            "fit_dataset",
            "result_document",
        ),
    },
)
