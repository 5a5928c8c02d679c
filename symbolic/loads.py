"""Generalised forces F_B (docs/model.md, eq. 20) and prescribed displacements.

- A point force f at the material point p: F_B = J(p)^T f, an (n, 3) array.
- A probe of radius r: a surface traction f g(x) / integral g dA around the contact
  point, of one of two shapes (``PROBE_SHAPES``; **choice**, the data decide between
  them in step 0 of the loop, docs/stepzero.md):
  - "gauss": a Gaussian g of standard deviation r / 2 (about 86 % of the force lies
    within the radius);
  - "disc": a uniform pressure within r, its edge a logistic of scale 0.25 mm
    (``DISC_EDGE_MM``), so that F_B is smooth in r and in the contact.
  Both have the per-axis variance r^2 / 4 of the patch.
- Prescribed displacements of outer-surface material points p_i:
  J(p_i) (B - B0) = d_i, imposed with Lagrange multipliers by the model; a frame of a
  set-up driven by them alone is a ``FrameLoad`` (f = 0, no contact).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from symbolic.basis import gauss_rule
from symbolic.volume import VolumeSpline


def _as_vector(value, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float).reshape(-1)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return vector


def _contact_uv(volume: VolumeSpline, uv, point) -> np.ndarray:
    """(u, v) of the contact: given directly, or by projecting a 3-D point."""
    if (uv is None) == (point is None):
        raise ValueError("give the contact either as uv=(u, v) or as point=(x, y, z), not both")
    if uv is not None:
        uv = np.asarray(uv, dtype=float).reshape(-1)
        if uv.shape != (2,) or np.any(uv < 0) or np.any(uv > 1):
            raise ValueError(f"contact uv must be two values in [0, 1], got {uv!r}")
        return uv
    found, _ = volume.project_to_outer(_as_vector(point, "contact point")[None])
    return found[0]


@dataclass(frozen=True)
class PointForce:
    """A force [N] at one material point of the outer surface.

    Parameters
    ----------
    force : array_like
        Force vector f, shape (3,) [N].
    uv : array_like, optional
        Contact as surface parameters (u, v).
    point : array_like, optional
        Contact as a 3-D point [mm], projected onto the rest outer surface.
    """

    force: np.ndarray
    uv: np.ndarray | None = None
    point: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "force", _as_vector(self.force, "force"))

    def generalized(self, volume: VolumeSpline) -> np.ndarray:
        """F_B = J(p)^T f, shape (n, 3) [N]."""
        uv = _contact_uv(volume, self.uv, self.point)
        row = volume.collocation(volume.outer_params(uv[None]))
        return np.asarray(row.T @ self.force[None, :])


PROBE_SHAPES = ("gauss", "disc")
"""The probe's pressure over its patch: Gaussian, or uniform within the radius."""

DISC_EDGE_MM = 0.25
"""Logistic scale of the disc's edge [mm] (10-90 % over 1.1 mm, about one knot span of
the volumes step 0 checks): the smoothing is there for the volume to resolve the load,
so it is set by the volume's scale, not the probe's. Measured on FE data with a 5 mm
disc: an edge of r / 10 (0.5 mm) left chi^2 2630 where a sharp disc fits at 2575, and
the loop added layering for the difference; an edge of r / 20 on a 2.5 mm probe made
the resolution check refine to 53x42x7 (9 GB)."""


def quadrature_spacing(radius: float, shape: str) -> float:
    """Spacing [mm] of the surface quadrature of a probe: sigma / 3 = r / 6 for the
    Gaussian, r / 10 for the disc (at most a fifth of its edge's 1.1 mm, for r <= 2.2
    mm)."""
    return radius / (6.0 if shape == "gauss" else 10.0)


def log_probe_weight(squared, radius2, shape: str, lib=np):
    """ln g of a probe patch at squared distances d^2 [mm^2] from its centre.

    gauss: -d^2 / (2 (r/2)^2); disc: ln of 1 / (1 + exp(y)), y = (d^2 - r^2) / (2 r e)
    with e = ``DISC_EDGE_MM``, which is the logistic of scale e in d - r near the edge.
    ``radius2`` is r^2 [mm^2], a number or (``lib`` casadi) an expression; the softplus
    is the stable one (finite derivatives far from the patch).
    """
    if shape == "gauss":
        return -2.0 * squared / radius2
    if shape != "disc":
        raise ValueError(f"probe shape must be one of {PROBE_SHAPES}, got {shape!r}")
    y = (squared - radius2) / (2.0 * DISC_EDGE_MM * lib.sqrt(radius2))
    return -(lib.fmax(y, 0.0) + lib.log1p(lib.exp(-lib.fabs(y))))


@dataclass(frozen=True)
class ProbeForce:
    """A force [N] spread by a probe of radius r [mm] as a normalised patch of a shape
    (``PROBE_SHAPES``: "gauss", the default, or "disc")."""

    force: np.ndarray
    radius: float
    uv: np.ndarray | None = None
    point: np.ndarray | None = None
    shape: str = "gauss"

    def __post_init__(self) -> None:
        object.__setattr__(self, "force", _as_vector(self.force, "force"))
        if not np.isfinite(self.radius) or self.radius <= 0:
            raise ValueError(f"probe radius must be > 0 mm, got {self.radius!r}")
        if self.shape not in PROBE_SHAPES:
            raise ValueError(f"probe shape must be one of {PROBE_SHAPES}, got {self.shape!r}")

    def generalized(self, volume: VolumeSpline) -> np.ndarray:
        """F_B = sum_q J(p_q)^T f g_q A_q / sum_q g_q A_q, shape (n, 3) [N].

        A patch too narrow for the surface quadrature to resolve (fewer than four
        points carry weight; the quadrature has at most 60 points per knot span) is the
        point force it tends to.
        """
        uv0 = _contact_uv(volume, self.uv, self.point)
        center = volume.evaluate(volume.outer_params(uv0[None]))[0]
        r = self.radius
        points = surface_points(volume, quadrature_spacing(r, self.shape))
        squared = np.sum((points.positions - center) ** 2, axis=1)
        log_g = log_probe_weight(squared, r**2, self.shape)
        with np.errstate(under="ignore"):
            g = np.exp(log_g - log_g.max()) * points.area
        keep = g > 1e-14 * g.max()
        if np.count_nonzero(keep) < 4:
            return PointForce(self.force, uv=uv0).generalized(volume)
        weights = g[keep] / g[keep].sum()
        collocation = points.collocation[keep]
        return np.asarray(collocation.T @ (weights[:, None] * self.force[None, :]))


@dataclass(frozen=True)
class SurfacePoints:
    """``surface_quadrature`` of a volume with its points' rest positions and rows of J."""

    params: np.ndarray
    """(u, v, 1) of the points, (q, 3)."""
    area: np.ndarray
    """Physical area weights [mm^2], (q,)."""
    positions: np.ndarray
    """Rest positions [mm], (q, 3)."""
    collocation: sp.csr_matrix
    """J at the points, (q, n)."""


_SURFACE_POINTS: dict = {}


def surface_points(volume: VolumeSpline, spacing: float) -> SurfacePoints:
    """``SurfacePoints`` at about ``spacing`` [mm], made once per volume and spacing:
    every probe of one radius on one model shares them, and so do the exact patches of
    ``symbolic.effects.load`` (the spacing is rounded to 1e-9 mm, so that sigma / 3 and
    sqrt(sigma^2) / 3 meet)."""
    key = (id(volume), round(float(spacing), 9))
    entry = _SURFACE_POINTS.get(key)
    if entry is None or entry[0]() is not volume:
        params, area = surface_quadrature(volume, spacing)
        collocation = sp.csr_matrix(volume.collocation(params))
        points = SurfacePoints(params, area, collocation @ volume.control_points, collocation)
        entry = (weakref.ref(volume), points)  # the volume held weakly: gone with it
        _SURFACE_POINTS[key] = entry
        weakref.finalize(volume, _SURFACE_POINTS.pop, key, None)
    return entry[1]


def surface_quadrature(volume: VolumeSpline, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss points on the outer surface w = 1 with physical area weights [mm^2].

    The number of points per knot span is chosen so that neighbouring points
    are at most about ``spacing`` [mm] apart.
    """
    rules = []
    for axis, basis in enumerate(volume.basis.bases[:2]):
        ends = basis.breakpoints
        mid = np.column_stack([0.5 * np.ones(3), 0.5 * np.ones(3), np.ones(3)])
        mid[:, axis] = [0.0, 0.5, 1.0]
        length = np.linalg.norm(np.diff(volume.evaluate(mid), axis=0), axis=1).sum()
        span = length / (len(ends) - 1)
        per_span = int(np.clip(np.ceil(span / max(spacing, 1e-9 * span)), basis.degree + 1, 60))
        rules.append(gauss_rule(basis, per_span))
    (u, wu), (v, wv) = rules
    uu, vv = np.meshgrid(u, v, indexing="ij")
    params = np.column_stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    jacobian = np.linalg.norm(
        np.cross(volume.evaluate(params, (1, 0, 0)), volume.evaluate(params, (0, 1, 0))), axis=1
    )
    return params, np.outer(wu, wv).ravel() * jacobian


@dataclass(frozen=True)
class PrescribedDisplacement:
    """Material points on the outer surface whose displacement is prescribed.

    Parameters
    ----------
    uv : array_like
        Surface parameters (u, v) of the points, shape (m, 2).
    """

    uv: np.ndarray

    def __post_init__(self) -> None:
        uv = np.atleast_2d(np.asarray(self.uv, dtype=float))
        if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] == 0:
            raise ValueError(f"prescribed uv must have shape (m, 2) with m >= 1, got {uv.shape}")
        if np.any(~np.isfinite(uv)) or np.any(uv < 0) or np.any(uv > 1):
            raise ValueError("prescribed uv must be finite and lie in [0, 1]")
        object.__setattr__(self, "uv", uv)

    def constraint_matrix(self, volume: VolumeSpline) -> sp.csr_matrix:
        """A with rows J(p_i), so that A (B - B0) = d, shape (m, n)."""
        return volume.collocation(volume.outer_params(self.uv)).tocsr()


@dataclass(frozen=True)
class FrameLoad:
    """One frame of a set-up driven by prescribed displacements alone (the two-pad
    extensometer, docs/realskin.md): no applied force, f = 0 and F_B = 0, and no contact
    point (``uv`` None); the frame's displacements d and its observations are its load
    case's (``LoadCase.prescribed``, ``force_rows``).

    Parameters
    ----------
    label : str
        The frame's name for reports, e.g. "frame 49".
    """

    label: str = ""
    uv = None
    radius = 0.0

    @property
    def force(self) -> np.ndarray:
        """f = 0, (3,) [N]."""
        return np.zeros(3)

    def generalized(self, volume: VolumeSpline) -> np.ndarray:
        """F_B = 0, shape (n, 3) [N]."""
        return np.zeros(volume.control_points.shape)


def independent_rows(matrix: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """Orthonormal combination Q (r, m) of the rows of A with Q A of full row rank.

    Prescribing many points on a patch covered by few control points gives
    dependent rows; the reduced constraint Q A (B - B0) = Q d keeps the
    same solution set whenever d is consistent, and the KKT system stays
    non-singular.
    """
    left, singular, _ = np.linalg.svd(np.asarray(matrix, dtype=float), full_matrices=False)
    rank = int(np.sum(singular > tol * singular[0])) if singular.size else 0
    return left[:, :rank].T
