"""Experiment design (docs/design.md): ``candidates`` (the presses one may make),
``pressloads`` (their forces from one patch per contact, eq. D8), ``information`` (the
Fisher information and the power of a design, eqs. D1-D3), ``pool`` (every press's
information once, eq. D5), ``shared`` (many presses on the linear path, eq. D9),
``criteria`` and ``search`` (which presses), ``discrimination`` (the sequential questions,
eqs. D6-D7)."""

from solvers.design.candidates import MAX_FORCE_N, Press, candidate_presses, contact_grid
from solvers.design.criteria import Criterion, design_figures
from solvers.design.information import EffectPower, effect_power, fisher_information
from solvers.design.pool import InformationPool
from solvers.design.search import exhaustive, search

__all__ = [
    "Criterion",
    "EffectPower",
    "InformationPool",
    "MAX_FORCE_N",
    "Press",
    "candidate_presses",
    "contact_grid",
    "design_figures",
    "effect_power",
    "exhaustive",
    "fisher_information",
    "search",
]
