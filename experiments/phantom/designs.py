"""Experiment designs on the phantom: where the probe presses, and in which direction.

- ``paper``: the paper's two loads, 0.17 N and 0.25 N, at the centre along the
  inward normal (``forehead.probe_loads``).
- ``diagnosis``: five contacts (``DIAGNOSIS_CONTACTS``), each pressed along the normal
  with the first force and tilted by ``DIAGNOSIS_TILT_DEG`` with the second; the shear
  separates effects that the paper's design confounds with alpha (docs/diagnosis.md).
"""

from __future__ import annotations

import numpy as np

from experiments.phantom.forehead import PhantomSettings, probe_loads
from symbolic.effects.skinrules import surface_frame
from symbolic.loads import PointForce

DIAGNOSIS_CONTACTS = ((0.5, 0.5), (0.3, 0.3), (0.7, 0.3), (0.3, 0.7), (0.7, 0.7))
"""Contact points (u, v) of the diagnosis design: the centre and four points 8 mm
along u and v off it on the 40 mm forehead patch (docs/diagnosis.md)."""

DIAGNOSIS_TILT_DEG = 20.0
"""Tilt of the second (0.25 N) load at every contact of the diagnosis design [deg]:
held by skin friction (coefficient 0.36 needed; skin on steel or plastic 0.2-0.8)."""

DESIGNS = ("paper", "diagnosis")
"""The named designs of ``dvs simulate --design``."""


def design_options(design: str) -> dict:
    """Keyword arguments of ``simulate_with_effects`` for a named design, or for the
    presses of a ``design.json`` file (``dvs design``)."""
    if str(design).endswith(".json"):
        from experiments.data.designfile import read_presses

        return {"presses": read_presses(design)}
    if design == "paper":
        return {}
    if design == "diagnosis":
        return {"contacts": DIAGNOSIS_CONTACTS, "tilt_deg": DIAGNOSIS_TILT_DEG}
    raise ValueError(
        f"unknown design {design!r}; choose from {', '.join(DESIGNS)} or a design.json file"
    )


CONTACT_TOLERANCE_MM = 1.0
"""How far a design's contact may lie from the phantom's rest skin [mm]."""


def press_loads(truth, presses) -> list:
    """Point loads of a design file's presses (contact [mm], force [N]) on the truth.

    Each contact is projected onto the rest skin; one farther than
    ``CONTACT_TOLERANCE_MM`` means the design was made for another tissue.
    """
    loads = []
    for k, (contact, force) in enumerate(presses, 1):
        uv, distance = truth.volume.project_to_outer(np.asarray(contact, dtype=float)[None])
        if distance[0] > CONTACT_TOLERANCE_MM:
            raise ValueError(
                f"press {k}: its contact is {distance[0]:.1f} mm from the phantom's skin; "
                "the design was made for another dataset"
            )
        loads.append(PointForce(np.asarray(force, dtype=float), uv=uv[0]))
    return loads


def design_loads(truth, phantom: PhantomSettings, contacts=None, tilt_deg: float = 0.0) -> list:
    """Point loads at every contact, one per phantom force (contact-major order).

    The first force presses along the inward normal; the others are tilted by
    ``tilt_deg`` from it, leaning away from the patch centre (along V_u at the
    centre itself), so that the loads also shear the skin. Without ``contacts``
    these are the paper's loads (``probe_loads``).
    """
    if contacts is None:
        return probe_loads(truth, phantom)
    loads = []
    for uv in contacts:
        uv = np.asarray(uv, dtype=float)
        du, dv, e1, e2, normal = surface_frame(truth, uv)
        away = (uv[0] - 0.5) * du + (uv[1] - 0.5) * dv
        away = away - (away @ normal) * normal
        lean = away / np.linalg.norm(away) if np.linalg.norm(away) > 1e-9 else e1
        angle = np.radians(tilt_deg)
        for k, f in enumerate(phantom.forces):
            direction = -normal if k == 0 else -np.cos(angle) * normal + np.sin(angle) * lean
            loads.append(PointForce(f * direction, uv=uv))
    return loads
