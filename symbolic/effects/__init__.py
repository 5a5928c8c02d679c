"""Candidate effects: named extensions of the model, each off at theta = 0.

- ``base``: what every effect is (``Effect``); ``casedata``: the per-case data and
  symbols it sees; ``declaration``: how it declares its parameters and magnitude
  (``Parameter``, ``Magnitude``); ``skinrules``: the skin's frame and quadrature rules;
- ``library``: the effects by name (``EFFECT_NAMES``, ``make_effect``);
  ``composition``: a base model with active effects (``ExtendedModel``), ``functions``
  its CasADi pieces, ``prescribed`` the multipliers of prescribed displacements;
- one module per kind of effect: ``nonlinearity`` (strain stiffening, eq. 1 and C10),
  ``stiffness`` (terms of eq. 18), ``load`` (eq. 20), ``measurement`` (eq. 24),
  ``boundary`` (section 2), ``fieldeffect`` (a stiffness field, docs/imaging.md)."""

from symbolic.effects.base import CaseData, Effect
from symbolic.effects.composition import ExtendedModel
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.library import EFFECT_NAMES, make_effect

__all__ = [
    "CaseData",
    "EFFECT_NAMES",
    "Effect",
    "ExtendedModel",
    "Magnitude",
    "Parameter",
    "make_effect",
]
