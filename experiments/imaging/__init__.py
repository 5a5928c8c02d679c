"""Stiffness imaging from a dataset (docs/imaging.md): ``mapping`` (dataset -> homogeneous
fit -> field, weight, uncertainty), ``imagemodel`` (the continuum it images on),
``outputs`` (image.json, PNG, VTU), ``imagecommand`` (``dvs image``), ``imagebench`` (``dvs
bench image``), ``weightstudy`` and ``adaptive`` (``dvs study imageweights``,
``imageadaptive``)."""
