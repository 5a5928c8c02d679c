"""The silicone phantoms' compression tests (docs/experiments.md): the cylinder between
two plates (``cylinder``) and the study of every recipe (``study``)."""
