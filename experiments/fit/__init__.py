"""The fit of a dataset: ``fitting`` (dataset -> inverse problem -> ``result.json``),
``fitcommand`` (``dvs fit``), ``stepzero`` (step 0 in the commands beyond fit and
diagnose) and ``surroundings`` (the tissue beyond the markers: rest surfaces extended
by a margin). Step 0's choices themselves are ``experiments.basemodel``."""
