"""Stiffness imaging from a dataset: ``dvs image`` and the imaging benchmark (docs/imaging.md)."""
