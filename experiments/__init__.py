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
