"""Candidate presses: where on the skin, in which direction and how hard the probe pushes.

A press is a point force f [N] at a material point (u, v) of the rest outer surface.
The candidates of a design search are a tensor product:

- **contacts**: an n x n grid over the marked area, in the model's (u, v), from 10 % to
  90 % of the markers' span along each direction (the probe stays inside the dots);
- **directions**: the inward normal -n, and tilts by an angle t from it towards
  ``azimuths`` evenly spaced directions of the tangent plane,

      d(t, phi) = -cos(t) n + sin(t) (cos(phi) e1 + sin(phi) e2),                  (D4)

  with e1 along V_u and e2 = n x e1 (``symbolic.effects.base.surface_frame``);
- **magnitudes**: ``levels`` forces evenly spaced over the stated safe range.

``MAX_FORCE_N`` is the largest force any design may ask for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from symbolic.effects.skinrules import surface_frame
from symbolic.loads import PointForce, ProbeForce

MAX_FORCE_N = 0.5
"""The safe limit of a press [N]: twice the paper's largest force (0.25 N). Beyond it
the forehead's skin is indented by millimetres and the model's small strains no longer
hold; every design and ``dvs simulate --design`` refuse more."""

INSET = 0.1
"""Fraction of the markers' (u, v) span kept free of contacts on each side."""


@dataclass(frozen=True)
class Press:
    """One candidate press.

    Attributes
    ----------
    uv : numpy.ndarray
        Contact (u, v) on the rest outer surface of the model, (2,).
    force : numpy.ndarray
        Force vector [N], (3,), in the dataset's frame.
    tilt_deg : float
        Angle between the force and the inward normal [deg].
    probe_radius : float
        Radius of the probe's patch [mm]; 0 for a point force (as a dataset declares it,
        ``experiments.problem.fitting.dataset_loads``).
    probe_shape : str
        The patch's shape (``symbolic.loads.PROBE_SHAPES``).
    """

    uv: np.ndarray
    force: np.ndarray
    tilt_deg: float = 0.0
    probe_radius: float = 0.0
    probe_shape: str = "gauss"

    def load(self) -> PointForce | ProbeForce:
        """The press as the model's load."""
        force, uv = np.asarray(self.force, dtype=float), np.asarray(self.uv, dtype=float)
        if self.probe_radius > 0:
            return ProbeForce(force, float(self.probe_radius), uv=uv, shape=self.probe_shape)
        return PointForce(force, uv=uv)

    @property
    def magnitude(self) -> float:
        """|f| [N]."""
        return float(np.linalg.norm(self.force))


def check_force_range(low: float, high: float) -> tuple[float, float]:
    """The safe range [low, high] [N], or ValueError saying what is wrong."""
    if not (np.isfinite(low) and np.isfinite(high) and 0 < low <= high):
        raise ValueError(f"force range must satisfy 0 < LOW <= HIGH, got {low:g} {high:g} N")
    if high > MAX_FORCE_N:
        raise ValueError(
            f"force {high:g} N is outside the safe range (at most {MAX_FORCE_N:g} N, twice "
            "the paper's 0.25 N); lower HIGH"
        )
    return float(low), float(high)


def contact_grid(marker_uv: np.ndarray, count: int) -> np.ndarray:
    """``count`` x ``count`` contacts (u, v) over the markers' span, inset by ``INSET``."""
    marker_uv = np.asarray(marker_uv, dtype=float).reshape(-1, 2)
    low, high = marker_uv.min(axis=0), marker_uv.max(axis=0)
    steps = np.linspace(INSET, 1.0 - INSET, count) if count > 1 else np.array([0.5])
    return np.array([low + np.array([a, b]) * (high - low) for a in steps for b in steps])


def candidate_presses(
    model,
    contacts: np.ndarray,
    forces=(0.17, 0.25),
    tilt_deg: float = 20.0,
    azimuths: int = 4,
    probe_radius: float = 0.0,
    probe_shape: str = "gauss",
) -> list[Press]:
    """Every press of eq. (D4): each contact x (normal + tilted) x each force magnitude.

    Parameters
    ----------
    model : TissueModel
        The model whose rest outer surface carries the contacts.
    contacts : numpy.ndarray
        Contacts (u, v), (n, 2) (``contact_grid``).
    forces : sequence of float
        Force magnitudes [N], each within ``MAX_FORCE_N``.
    tilt_deg : float
        Tilt from the normal [deg], 0 to 60 (0: the normal only).
    azimuths : int
        Number of tilt directions in the tangent plane.
    probe_radius : float
        The probe's radius [mm] (0: point forces).
    probe_shape : str
        The probe patch's shape (``symbolic.loads.PROBE_SHAPES``).
    """
    if not 0.0 <= tilt_deg <= 60.0:
        raise ValueError(f"tilt must lie in 0-60 degrees, got {tilt_deg:g}")
    for magnitude in forces:
        check_force_range(magnitude, magnitude)
    angle = np.radians(tilt_deg)
    presses = []
    for uv in np.asarray(contacts, dtype=float).reshape(-1, 2):
        _, _, e1, e2, normal = surface_frame(model, uv)
        directions = [(-normal, 0.0)]
        if tilt_deg > 0 and azimuths > 0:
            for phi in 2 * np.pi * np.arange(azimuths) / azimuths:
                lean = np.cos(phi) * e1 + np.sin(phi) * e2
                directions.append((-np.cos(angle) * normal + np.sin(angle) * lean, tilt_deg))
        for direction, tilt in directions:
            for magnitude in forces:
                force = magnitude * direction
                presses.append(Press(uv.copy(), force, tilt, probe_radius, probe_shape))
    return presses


def contact_point(model, uv: np.ndarray) -> np.ndarray:
    """The rest skin point of a contact (u, v) [mm], (3,)."""
    volume = model.volume
    return volume.evaluate(volume.outer_params(np.asarray(uv, dtype=float)[None]))[0]


def hidden_markers(rest_markers: np.ndarray, contact: np.ndarray, radius: float) -> np.ndarray:
    """Markers the probe hides: closer than ``radius`` [mm] to the contact (bool, (m,))."""
    return np.linalg.norm(np.asarray(rest_markers) - np.asarray(contact), axis=1) < radius


def occlusion_radius(rest_markers: np.ndarray, contacts: np.ndarray, seen: np.ndarray) -> float:
    """The dataset's rule for markers lost near the contact [mm].

    In every loaded capture the probe hides the markers nearer its contact than the
    nearest marker still seen; the rule kept is the smallest such distance over the
    captures (markers lost at random elsewhere do not enter it).

    Parameters
    ----------
    rest_markers : numpy.ndarray
        Rest markers, (m, 3) [mm] (NaN rows are ignored).
    contacts : numpy.ndarray
        Contacts of the loaded captures, (K, 3) [mm].
    seen : numpy.ndarray
        Which markers each capture sees, (K, m) bool.
    """
    radii = []
    for contact, mask in zip(np.asarray(contacts), np.asarray(seen, dtype=bool)):
        distance = np.linalg.norm(rest_markers - contact, axis=1)
        usable = mask & np.isfinite(distance)
        if usable.any():
            radii.append(float(distance[usable].min()))
    return min(radii) if radii else 0.0
