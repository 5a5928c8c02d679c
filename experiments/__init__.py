"""The ``dvs`` command, its datasets and the studies (docs/cli.md, docs/formats.md).

- ``command``: the command line (``cli``, ``options``, ``isolation``);
- ``data``: the dataset and its validation (``dataset``, ``validation``, ``archive``,
  ``plausibility``, ``captures``, ``paths``);
- ``fit``: dataset -> problem -> ``result.json`` (``fitting``, ``fitcommand``,
  ``stepzero``, ``surroundings``), and ``basemodel`` (step 0: base model, surroundings,
  resolution);
- ``output``: ``atomic`` (whole files or none), ``plots``, ``export`` (VTU);
- studies by subject: ``phantom``, ``demo``, ``inverse``, ``dynamics``, ``diagnosis``,
  ``imaging``, ``design``, ``realskin``, ``stereo``.
"""
