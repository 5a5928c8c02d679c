"""Experiment design (issue 21): the information of a design, from exact sensitivities."""
