"""The ``dvs`` command, its datasets and the studies (docs/cli.md, docs/formats.md).

- ``command``: the command line (``cli``, ``options``, ``isolation``);
- ``data``: the dataset and its validation (``dataset``, ``validation``, ``archive``,
  ``plausibility``, ``captures``, ``paths``);
- ``problem``: a dataset posed as an inverse problem (``fitting``, ``surroundings``);
  ``basemodel``: step 0 (base model, surroundings, resolution chosen from the data);
  ``fit``: ``dvs fit`` and step 0 in the other commands (``fitcommand``, ``stepzero``);
- ``output``: ``atomic`` (whole files or none), ``plots``, ``export`` (VTU);
- studies by subject: ``phantom``, ``demo``, ``inverse``, ``dynamics``, ``diagnosis``,
  ``imaging``, ``design``, ``realskin``, ``stereo``.
"""

import importlib


def lazy_exports(package: str, modules: dict[str, tuple[str, ...]]):
    """``__getattr__`` and ``__all__`` of a package that exports the names of ``modules``
    (module -> names), each imported on first use (PEP 562): ``from experiments.data
    import load_dataset`` works, and ``dvs --help`` still imports no solver."""
    exports = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(exports[name]), name)

    return __getattr__, sorted(exports)
