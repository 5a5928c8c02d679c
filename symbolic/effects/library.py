"""The library of candidate effects: their names, classes and order.

Each effect is a named extension of the model with parameters theta that gives
back the base model exactly at theta = 0 (``symbolic.effects.base``). The
library, in the order the diagnosis prefers them on ties:

==================== ========================== ==================================
name                 theta                      module
==================== ========================== ==================================
nonlinear_stiffening k0 [1]                     ``stiffening`` (eq. 1)
heterogeneity        h_u, h_v [1]               ``stiffness`` (eq. 18)
rigid_motion         omega [rad], t [mm]/case   ``measurement`` (eq. 24)
force_direction      tau_1, tau_2 [1]           ``load`` (eq. 20)
contact_offset       delta_1, delta_2 [mm]      ``load`` (eq. 20)
measurement_scale    s [1] per case             ``measurement`` (eq. 24)
bending              beta [N/mm]                ``stiffness`` (eq. 18)
base_compliance      c = 1/k_b [mm^3/N]         ``boundary`` (section 2)
contact_patch        sigma^2 [mm^2]             ``load`` (eq. 20)
pre_tension          sigma0 [N/mm]              ``stiffness``
volumetric_coupling  lambda [N/mm^2]            ``stiffness`` (section 4)
shear_coupling       mu_L [N/mm^2]              ``stiffness`` (eq. C3)
surrounding_tissue   k_s [N/mm^3]               ``boundary`` (section 2)
layering             s_1, s_2 [1]               ``stiffness`` (skin over fat)
==================== ========================== ==================================

Each effect names the base energies it extends (``Effect.energies``); on the
linear-elastic base model the library has no bending, stiffening,
volumetric_coupling or shear_coupling (the continuum contains them or, for k0,
does not support it).

The composition of a base model with active effects is ``symbolic.effects.composition``.
"""

from __future__ import annotations

from symbolic.effects.anisotropy import Anisotropy
from symbolic.effects.base import Effect
from symbolic.effects.boundary import BaseCompliance, SurroundingTissue
from symbolic.effects.fieldeffect import StiffnessFieldEffect
from symbolic.effects.load import ContactOffset, ContactPatch, ForceDirection
from symbolic.effects.measurement import MeasurementScale, RigidMotion
from symbolic.effects.nonlinearity import ContinuumStiffening, NonlinearStiffening
from symbolic.effects.region import StiffnessRegion
from symbolic.effects.stiffness import (
    Bending,
    Heterogeneity,
    Layering,
    PreTension,
    ShearCoupling,
    VolumetricCoupling,
)

EFFECT_CLASSES: tuple[type[Effect], ...] = (
    NonlinearStiffening,
    ContinuumStiffening,
    Heterogeneity,
    RigidMotion,
    ForceDirection,
    ContactOffset,
    MeasurementScale,
    Bending,
    BaseCompliance,
    ContactPatch,
    PreTension,
    VolumetricCoupling,
    ShearCoupling,
    SurroundingTissue,
    Layering,
)
EFFECT_NAMES: tuple[str, ...] = tuple(dict.fromkeys(c.name for c in EFFECT_CLASSES))
"""The default library: every effect name of docs/effects.md ("The effects") but the
opt-in ``stiffness_field``, ``stiffer_region`` and ``anisotropy``, in order. One name may
have a class per base energy (``nonlinear_stiffening``: eq. 1 or eq. C10);
``make_effect`` picks by the energy."""

OPT_IN_CLASSES: tuple[type[Effect], ...] = (StiffnessFieldEffect, StiffnessRegion, Anisotropy)
"""Effects searched only when named (``DiagnosisSettings.candidates``)."""
ALL_EFFECT_NAMES: tuple[str, ...] = EFFECT_NAMES + tuple(c.name for c in OPT_IN_CLASSES)


def make_effect(name: str, energy: str | None = None) -> Effect:
    """A fresh effect by name: the class of that name that extends ``energy`` when one
    does, else the first of that name."""
    named = [cls for cls in EFFECT_CLASSES + OPT_IN_CLASSES if cls.name == name]
    if not named:
        known = ", ".join(ALL_EFFECT_NAMES)
        raise ValueError(f"unknown effect {name!r}; known effects: {known}")
    fitting = [cls for cls in named if energy in cls.energies]
    return (fitting or named)[0]()


def effect_library(names=None, energy: str | None = None) -> dict[str, Effect]:
    """Effects by name (all of them by default), each instantiated once.

    With ``energy``, only the effects that extend that base energy.
    """
    chosen = {
        name: make_effect(name, energy) for name in (EFFECT_NAMES if names is None else names)
    }
    if energy is None:
        return chosen
    return {name: e for name, e in chosen.items() if energy in e.energies}
