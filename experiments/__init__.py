"""The ``dvs`` command, its datasets and the studies (docs/cli.md, docs/formats.md).

- the command line: ``cli`` (the subcommand table), ``options``, ``fitcommand``;
- the dataset: ``dataset`` (format v1), ``validation``, ``archive``, ``plausibility``,
  ``paths`` (the real data beside the project);
- the fit: ``fitting`` (dataset -> problem -> ``result.json``), ``stepzero`` and
  ``basemodel`` (step 0: base model, surroundings, resolution), ``surroundings``;
- outputs: ``atomic`` (whole files or none), ``plots``, ``export`` (VTK), ``isolation``;
- studies by subject: ``phantom``, ``demo``, ``inverse``, ``dynamics``, ``diagnosis``,
  ``imaging``, ``design``, ``realskin``, ``stereo``.
"""
