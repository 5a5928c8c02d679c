"""What the commands write: ``atomic`` (whole files or none, with a PDF twin for every
PNG), ``plots`` (the shared figures) and ``export`` (VTU for ParaView)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.output.atomic": (
            "atomic_write_json",
            "atomic_write_text",
            "atomic_savefig",
            "atomic_save_npz",
        ),
        "experiments.output.tables": ("table_lines",),
    },
)
