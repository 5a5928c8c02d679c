"""The command line: ``cli`` (the ``dvs`` verbs and groups, docs/cli.md), ``options``
(parsers that answer bad input in one line, the exit-code contract ``run_guarded``)
and ``isolation`` (a measurement in a fresh process, for the benchmarks)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.command.cli": ("main",),
        "experiments.command.options": ("Command", "UsageError"),
    },
)
