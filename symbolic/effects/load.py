"""Load effects: the applied force differs from the declared one (docs/model.md, eq. 20).

The declared load of a case is F_B = a f^T with a = J(p) for a point force at
the contact p = (u0, v0, 1) (or the probe's row). The effects change f, p or the
spread of the force, and F_B is recomputed as

    F_B(theta) = F_B + a(theta) f(theta)^T - a(0) f^T + (a_declared - a(0)) (f(theta) - f)^T,
    a(theta)   = (A_u (x) A_v (x) N_w(1)),   A_u = N(u) + 1/2 s_u N''(u),   s_u = sigma^2/|V_u|^2,

which equals the declared F_B at theta = 0 for point and probe loads alike.
N(u) is evaluated symbolically (``casadi.bspline``) when the contact moves.
A(u) is the expectation of N(u + eta) over eta ~ N(0, s_u) for a cubic span: a
normalised Gaussian patch of variance sigma^2 [mm^2] to that order.

- ``force_direction``: f = f0 + |f0| (tau_1 e_1 + tau_2 e_2) with unit tangents
  e_1 = V_u/|V_u|, e_2 = n x e_1 at the contact (shared by all cases).
- ``contact_offset``: p moved by delta_1 e_1 + delta_2 e_2 [mm] on the skin,
  (u, v) = (u0, v0) + [V_u V_v]^+ (delta_1 e_1 + delta_2 e_2) (shared). A declared
  probe's Gaussian patch moves whole (the exact patch below, its variance unchanged);
  before, the patch stayed and a point force moved from p0 to p, a dipole the size of
  the load: on scikit-fem data with a 2 mm offset and 4 mm probes, 27x27x4, the fit
  with it still left 67 um against 49 um of noise.
- ``contact_patch``: theta [mm^2], the variance added to the declared patch; a probe
  of radius r has sigma = r/2 (the project's **choice**). For a declared point force
  the patch is the expansion above (exact to first order in theta). For a declared
  probe of variance sigma_0^2 it is exact: the Gaussian of variance sigma_0^2 + theta,
  centred at the (moved) contact, integrated over the skin by the quadrature of
  ``symbolic.loads.ProbeForce``,

    a(theta) = sum_q N(p_q) g_q A_q / sum_q g_q A_q,
    g_q = exp(-|x_q - c(theta)|^2 / (2 (sigma_0^2 + theta))),

  so that the patch stays a normalised Gaussian at any width. A declared disc probe
  (``symbolic.loads.PROBE_SHAPES``) grows the same way, as the disc of radius
  sqrt(r_0^2 + 4 theta), whose per-axis variance is sigma_0^2 + theta. (The expansion, a
  second-order Taylor series of N, is only good for sigma^2 well below a knot span
  squared: on 2.5 mm spans it turned a 4 -> 16 mm^2 patch into a load that needed E
  twice as large, and its score test pointed to theta < 0 on data with a probe twice
  the declared radius.)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from symbolic.basis import BSplineBasis
from symbolic.effects.base import CaseData, Effect, LoadState, per_model
from symbolic.effects.declaration import Magnitude, Parameter
from symbolic.effects.skinrules import surface_frame
from symbolic.loads import (
    log_probe_weight,
    quadrature_spacing,
    surface_points,
)
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


def basis_values(basis: BSplineBasis, t, derivative: int = 0):
    """N^(d)(t) of a univariate basis: numbers for a number t, MX for an expression."""
    if isinstance(t, float | int | np.floating):
        return ca.DM(basis.evaluate_dense([float(t)], derivative)[0])
    return _basis_function(basis, derivative)(t)


def _basis_function(basis: BSplineBasis, derivative: int) -> ca.Function:
    """The Function t -> N^(d)(t) through ``casadi.bspline`` (differentiable in t)."""
    t = ca.MX.sym("t")
    identity = ca.DM(np.eye(basis.n_control).ravel(order="F"))
    value = ca.bspline(t, identity, [basis.knots.tolist()], [basis.degree], basis.n_control, {})
    for _ in range(derivative):
        value = ca.jacobian(value, t)
    return ca.Function(f"N{derivative}", [t], [value])


def _smoothed(basis: BSplineBasis, t, spread):
    """N(t) + 1/2 spread N''(t): expectation over a Gaussian of variance ``spread``."""
    values = basis_values(basis, t)
    if spread is None:
        return values
    return values + 0.5 * spread * basis_values(basis, t, 2)


def load_row(model: TissueModel, uv, variance, frame) -> ca.MX:
    """a(theta) on the free points: A_u (x) A_v (x) N_w(1), (n_free, 1)."""
    bases = model.volume.basis.bases
    du, dv = frame[0], frame[1]
    spread_u = None if variance is None else variance / float(du @ du)
    spread_v = None if variance is None else variance / float(dv @ dv)
    a_u = _smoothed(bases[0], uv[0], spread_u)
    a_v = _smoothed(bases[1], uv[1], spread_v)
    outer = ca.DM(bases[2].evaluate_dense([1.0])[0])
    full = ca.kron(ca.kron(a_u, a_v), outer)
    return full[model.free.tolist()]


def load_change(model: TissueModel, case: CaseData, load: LoadState) -> ca.MX | None:
    """F_B(theta) - F_B on the free points, (n_free, 3) [N], or None when unchanged."""
    if not load.changed:
        return None
    frame = surface_frame(model, case.contact_uv)
    f0 = ca.DM(case.force_vector).T
    f = load.force_vector if isinstance(load.force_vector, ca.MX) else ca.DM(load.force_vector)
    f = ca.reshape(f, 1, 3)
    declared = ca.DM(case.load_row[model.free])
    if case.probe_variance > 0 and (load.variance is not None or load.uv_shift is not None):
        added = 0.0 if load.variance is None else load.variance
        reference, moved = patch_rows(model, case, load.uv_shift, added, frame)
        return ca.mtimes(declared, f - f0) + ca.mtimes(moved - reference, f)
    u0, v0 = (float(t) for t in case.contact_uv)
    point = load_row(model, (u0, v0), None, frame)
    change = ca.mtimes(declared - point, f - f0)
    if load.uv_shift is None and load.variance is None:
        return change + ca.mtimes(point, f - f0)
    uv = (u0, v0) if load.uv_shift is None else (u0 + load.uv_shift[0], v0 + load.uv_shift[1])
    moved = load_row(model, uv, load.variance, frame)
    return change + ca.mtimes(moved, f) - ca.mtimes(point, f0)


def patch_rows(model: TissueModel, case: CaseData, uv_shift, variance, frame):
    """a(0) and a(theta) of the exact Gaussian patch on the free points, (n_free, 1) each.

    The centre moves with the contact to first order, c = c_0 + V_u du + V_v dv; the
    quadrature is the declared probe's (``ProbeForce``, ``quadrature_spacing``). a(0) is
    the same Function at (0, 0), so a(theta) - a(0) vanishes exactly at theta = 0.
    """
    patch = _patch_function(model, case, frame)
    shift = ca.DM.zeros(2) if uv_shift is None else uv_shift
    return patch(ca.DM.zeros(2), 0.0), patch(shift, variance)


_PATCHES: dict = {}


def _patch_function(model: TissueModel, case: CaseData, frame) -> ca.Function:
    """(uv shift, added variance) -> a on the free points, (n_free, 1) (built once per case)."""
    key = (tuple(np.asarray(case.contact_uv, float)), case.probe_variance, case.probe_shape)
    return per_model(_PATCHES, model, key, lambda: _build_patch(model, case, frame))


def _build_patch(model: TissueModel, case: CaseData, frame) -> ca.Function:
    volume = model.volume
    radius = 2.0 * np.sqrt(case.probe_variance)  # r = 2 sigma_0
    surface = surface_points(volume, quadrature_spacing(radius, case.probe_shape))
    keep = surface.area > 0
    area, points = surface.area, surface.positions[keep]
    rows = to_casadi_sparse(surface.collocation[keep][:, model.free].T)
    centre = volume.evaluate(volume.outer_params(np.asarray(case.contact_uv, float)[None]))[0]
    shift, added = ca.MX.sym("shift", 2), ca.MX.sym("variance")
    moved = ca.DM(centre) + ca.DM(frame[0]) * shift[0] + ca.DM(frame[1]) * shift[1]
    squared = ca.sum2((ca.DM(points) - ca.repmat(moved.T, points.shape[0], 1)) ** 2)
    radius2 = 4 * (case.probe_variance + added)  # the patch's variance r^2 / 4 grows
    log_g = log_probe_weight(squared, radius2, case.probe_shape, lib=ca)
    # exp(-max) scales numerator and denominator alike: finite weights at any width
    weights = ca.exp(log_g - ca.mmax(log_g)) * ca.DM(area[keep])
    row = ca.mtimes(rows, weights) / ca.sum1(weights)
    return ca.Function("patch", [shift, added], [row])


class ForceDirection(Effect):
    """Tangential force per unit force, (tau_1, tau_2) [1]: a tilted probe.

    Realistic magnitude 0.3 (a hand-held probe tilted by about 17 degrees).
    """

    name = "force_direction"
    parameters = (
        Parameter("tau_1", "1", 0.1, -1.0, 1.0),
        Parameter("tau_2", "1", 0.1, -1.0, 1.0),
    )
    magnitude = Magnitude(0.3, "1", direction=(0.8, 0.6))
    equation = "f = f0 + |f0| (tau_1 e_1 + tau_2 e_2)"

    def load(self, model: TissueModel, case: CaseData, load: LoadState, theta) -> LoadState:
        _, _, e1, e2, _ = surface_frame(model, case.contact_uv)
        size = float(np.linalg.norm(case.force_vector))
        tangential = size * (theta[0] * ca.DM(e1) + theta[1] * ca.DM(e2))
        base = load.force_vector
        base = base if isinstance(base, ca.MX) else ca.DM(np.asarray(base, dtype=float))
        return LoadState(base + tangential, load.uv_shift, load.variance)


class ContactOffset(Effect):
    """Displacement (delta_1, delta_2) [mm] of the true contact along the skin.

    Realistic magnitude 2 mm (a misplaced or mis-registered probe tip).
    """

    name = "contact_offset"
    parameters = (
        Parameter("delta_1", "mm", 1.0, -5.0, 5.0),
        Parameter("delta_2", "mm", 1.0, -5.0, 5.0),
    )
    magnitude = Magnitude(2.0, "mm", direction=(0.6, 0.8))
    equation = "p = p0 + delta_1 e_1 + delta_2 e_2 on the skin"

    def load(self, model: TissueModel, case: CaseData, load: LoadState, theta) -> LoadState:
        du, dv, e1, e2, _ = surface_frame(model, case.contact_uv)
        inverse = np.linalg.pinv(np.column_stack([du, dv]))
        shift = ca.mtimes(ca.DM(inverse @ np.column_stack([e1, e2])), theta[:2])
        if load.uv_shift is not None:
            shift = shift + load.uv_shift
        return LoadState(load.force_vector, shift, load.variance)


class ContactPatch(Effect):
    """Variance sigma^2 [mm^2] of a Gaussian contact patch (probe of radius r = 2 sigma).

    Realistic magnitude: a probe of radius 6 mm (sigma^2 = 9 mm^2); the
    magnitude of this effect is given as the radius [mm].
    """

    name = "contact_patch"
    parameters = (Parameter("sigma2", "mm^2", 1.0, 0.0, 100.0),)
    magnitude = Magnitude(6.0, "mm (probe radius)")
    equation = "F_B = E[J(p + eta)]^T f, eta ~ N(0, sigma^2 I) on the skin"

    def true_parameters(self, magnitude: float, n_cases: int) -> np.ndarray:
        return np.array([(0.5 * magnitude) ** 2])

    def magnitude_range(self, n_cases: int = 1) -> tuple[float, float]:
        """Probe radii r >= 0 with sigma^2 = (r / 2)^2 within the bounds [mm]."""
        return float(2.0 * np.sqrt(self.lower[0])), float(2.0 * np.sqrt(self.upper[0]))

    def load(self, model: TissueModel, case: CaseData, load: LoadState, theta) -> LoadState:
        variance = theta[0] if load.variance is None else load.variance + theta[0]
        return LoadState(load.force_vector, load.uv_shift, variance)
