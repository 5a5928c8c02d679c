"""Stiffness imaging from a dataset (docs/imaging.md): ``mapping`` (dataset -> homogeneous
fit -> field, weight, uncertainty), ``continuum`` (the continuum it images on),
``fieldchoice`` (the field's nodes when ``--field`` is not given),
``outputs`` (image.json, PNG, VTU), ``command`` (``dvs image``), ``bench`` (``dvs
bench image``), ``weightstudy`` and ``adaptive`` (``dvs study imageweights``,
``imageadaptive``)."""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.imaging.mapping": ("Image", "ImageSettings", "image_dataset"),
    },
)
