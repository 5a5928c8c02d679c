"""The dataset and its checks (docs/formats.md): ``dataset`` (format v1, load and save),
``validation`` (every array and number checked before use), ``archive`` (.npz archives
read safely), ``plausibility`` (valid but implausible input: one-line warnings),
``captures`` (a session's presses appended on its rest capture) and ``paths`` (the real
measured data beside the checkout)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.data.dataset": (
            "Dataset",
            "load_dataset",
            "save_dataset",
            "from_arrays",
            "to_arrays",
        ),
        "experiments.data.validation": ("DatasetError", "validate"),
    },
)
