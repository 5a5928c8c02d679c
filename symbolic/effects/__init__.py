"""Candidate effects: named extensions of the model, each off at theta = 0.

- ``base``: what every effect is (``Effect``) and the per-case data it sees;
  ``declaration``: how it declares its parameters and magnitude (``Parameter``,
  ``Magnitude``); ``skinrules``: the skin's frame and quadrature rules it integrates on;
- ``library``: the effects by name (``EFFECT_NAMES``, ``make_effect``) and their
  composition with the base model (``ExtendedModel``);
- one module per kind of effect: ``nonlinearity`` (k0 of eq. 1), ``stiffness`` (terms
  of eq. 18), ``load`` (eq. 20), ``measurement`` (eq. 24), ``boundary`` (section 2),
  ``fieldeffect`` (a stiffness field, docs/imaging.md); ``functions``: their shared
  CasADi pieces."""

from symbolic.effects.base import CaseData, Effect
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.library import EFFECT_NAMES, ExtendedModel, make_effect

__all__ = [
    "CaseData",
    "EFFECT_NAMES",
    "Effect",
    "ExtendedModel",
    "Magnitude",
    "Parameter",
    "make_effect",
]
