"""The generalised forces of many presses, from one surface patch per contact.

A probe's F_B (``symbolic.loads.ProbeForce``, docs/model.md, eq. 20) is linear in its force,

    F_B(f) = sum_q J(p_q)^T f g_q A_q / sum_q g_q A_q = b f^T,
    b = sum_q J(p_q)^T g_q A_q / sum_q g_q A_q,                                    (D8)

with b (n,) the patch of the contact and the probe alone (a point force: b = J(p)^T).
The candidates of a design share few contacts (25 for 250 presses), and each press's
F_B is asked for twice (its observation case and its case data). ``press_loads`` makes
b once per contact and probe radius; every press gets a ``KnownLoad`` that returns
b f^T. It equals ``Press.load().generalized`` to rounding (the product is regrouped);
the surface quadrature and collocation of the patch, 0.2 s per call at 9x9x2 and more
at finer grids, were most of the time of the pool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.loads import PointForce, ProbeForce


@dataclass(frozen=True, eq=False)
class KnownLoad:
    """A press whose generalised force is known from its patch (eq. D8).

    Attributes
    ----------
    force : numpy.ndarray
        Force vector f [N], (3,).
    uv : numpy.ndarray
        Contact (u, v) on the rest outer surface, (2,).
    radius : float
        Probe radius [mm] (0: a point force).
    patch : numpy.ndarray
        b of eq. (D8), one weight per control point, (n,) [1].
    """

    force: np.ndarray
    uv: np.ndarray
    radius: float
    patch: np.ndarray

    def generalized(self, volume=None) -> np.ndarray:
        """F_B = b f^T, shape (n, 3) [N] (``volume`` is accepted for the loads' interface)."""
        return np.outer(self.patch, self.force)


def contact_patch(volume, uv: np.ndarray, radius: float, shape: str = "gauss") -> np.ndarray:
    """b of eq. (D8) for a contact (u, v) and a probe radius [mm] (0: a point force) of a
    shape (``symbolic.loads.PROBE_SHAPES``)."""
    unit = np.array([0.0, 0.0, 1.0])
    uv = np.asarray(uv, dtype=float)
    probe = radius > 0
    load = ProbeForce(unit, float(radius), uv=uv, shape=shape) if probe else PointForce(unit, uv=uv)
    return np.asarray(load.generalized(volume))[:, 2].copy()


def press_loads(presses, volume) -> list[KnownLoad]:
    """A ``KnownLoad`` per press (``solvers.design.candidates.Press``), one patch per
    distinct contact and probe radius."""
    patches: dict = {}
    loads = []
    for press in presses:
        uv = np.asarray(press.uv, dtype=float)
        radius, shape = float(press.probe_radius), press.probe_shape
        key = (uv.tobytes(), radius, shape)
        if key not in patches:
            patches[key] = contact_patch(volume, uv, radius, shape)
        loads.append(KnownLoad(np.asarray(press.force, dtype=float), uv, radius, patches[key]))
    return loads
