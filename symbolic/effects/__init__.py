"""Candidate effects: named extensions of the model, each off at theta = 0.

- ``base``: what every effect is (``Effect``) and the per-case data it sees;
- ``library``: the effects by name (``EFFECT_NAMES``, ``make_effect``) and their
  composition with the base model (``ExtendedModel``);
- one module per kind of effect: ``stiffening`` (k0 of eq. 1), ``stiffness`` (terms
  of eq. 18), ``load`` (eq. 20), ``measurement`` (eq. 24), ``boundary`` (section 2).
"""
