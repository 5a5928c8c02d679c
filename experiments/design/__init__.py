"""Experiment design on the phantom and on datasets (issue 21; docs/design.md)."""
