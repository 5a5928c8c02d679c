"""A dataset posed as an inverse problem: ``fitting`` (the fit's settings, the model on
the dataset's rest surfaces, the problem, its solution and ``result.json``) and
``surroundings`` (the tissue beyond the markers: rest surfaces extended by a margin)."""
