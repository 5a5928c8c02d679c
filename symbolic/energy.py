"""Mass, damping and stiffness matrices by Gauss quadrature (docs/model.md, eq. 11-18).

All integrals are over the parameter cube [0, 1]^3:

- (13) M = integral mu(u,v,w) J^T J,
- (16) D = integral gamma(u,v,w) J^T J,
- (18) K = integral sum_i alpha_i J_i^T J_i + sum_{i<=j} beta_ij J_ij^T J_ij.

K is linear in the material parameters, so it is stored as named unit terms
``K = sum_t value_t * K_t``. A spatially varying coefficient is a known shape
field times a scalar parameter: ``alpha_u(u,v,w) = alpha_u * field(u,v,w)``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from symbolic.basis import (
    FIRST_DERIVATIVES,
    SECOND_DERIVATIVES,
    BSplineBasis,
    VolumeBasis,
    gauss_rule,
)

Field = Callable[[np.ndarray], np.ndarray]
"""A coefficient field: (n, 3) parameter points -> (n,) values."""

STIFFNESS_TERMS = tuple(f"alpha_{d}" for d in FIRST_DERIVATIVES) + tuple(
    f"beta_{d}" for d in SECOND_DERIVATIVES
)


def quadrature(basis: VolumeBasis, extra_points: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss rule over [0, 1]^3 with (degree + 1 + extra) points per knot span.

    Returns
    -------
    points, weights : numpy.ndarray
        Shape (n_q, 3) and (n_q,); weights sum to 1 (the cube's volume).
    """
    if extra_points < 0:
        raise ValueError(f"extra_points must be >= 0, got {extra_points}")
    rules = [gauss_rule(b, b.degree + 1 + extra_points) for b in basis.bases]
    points = basis.grid_points(*(r[0] for r in rules))
    wu, wv, ww = (r[1] for r in rules)
    weights = (wu[:, None, None] * wv[None, :, None] * ww[None, None, :]).ravel()
    return points, weights


def _field_values(field: float | Field | None, points: np.ndarray, name: str) -> np.ndarray:
    """Evaluate a constant or callable coefficient at quadrature points."""
    if field is None:
        return np.ones(len(points))
    values = field(points) if callable(field) else np.full(len(points), float(field))
    values = np.asarray(values, dtype=float).reshape(-1)
    if values.shape != (len(points),) or not np.all(np.isfinite(values)):
        raise ValueError(f"coefficient field {name!r} must give one finite value per point")
    return values


def gram_1d(basis: BSplineBasis, derivative: int, extra_points: int = 0) -> sp.csr_matrix:
    """integral_0^1 N^(d)(t) N^(d)(t)^T dt by Gauss quadrature, exact for polynomials."""
    points, weights = gauss_rule(basis, basis.degree + 1 + extra_points)
    values = basis.evaluate(points, derivative)
    return (values.T @ sp.diags(weights) @ values).tocsr()


def weighted_gram(
    basis: VolumeBasis,
    derivative: tuple[int, int, int] = (0, 0, 0),
    field: float | Field | None = None,
    extra_points: int = 0,
    name: str = "coefficient",
) -> sp.csr_matrix:
    """integral c(u,v,w) J_d^T J_d over [0, 1]^3, a sparse symmetric (n, n) matrix.

    A constant coefficient on a polynomial basis factorises: the integral is
    the Kronecker product of three exact 1-D Gram matrices, which costs
    O(n) instead of a 3-D quadrature.
    """
    if basis.weights is None and (field is None or not callable(field)):
        scale = 1.0 if field is None else float(field)
        if not np.isfinite(scale):
            raise ValueError(f"coefficient {name!r} must be finite")
        factors = [gram_1d(b, d, extra_points) for b, d in zip(basis.bases, derivative)]
        return (scale * sp.kron(factors[0], sp.kron(factors[1], factors[2]))).tocsr()
    points, weights = quadrature(basis, extra_points)
    collocation = basis.collocation(points, derivative)
    scale = sp.diags(weights * _field_values(field, points, name))
    gram = (collocation.T @ scale @ collocation).tocsr()
    return (0.5 * (gram + gram.T)).tocsr()


def mass_matrix(basis: VolumeBasis, density: float | Field = 1.0, extra_points: int = 0):
    """M of eq. (13) for mass density mu [t per unit parameter volume]."""
    return weighted_gram(basis, (0, 0, 0), density, extra_points, "mu")


def damping_matrix(basis: VolumeBasis, damping: float | Field = 1.0, extra_points: int = 0):
    """D of eq. (16) for damping density gamma [N s/mm per unit parameter volume]."""
    return weighted_gram(basis, (0, 0, 0), damping, extra_points, "gamma")


def stiffness_terms(
    basis: VolumeBasis,
    fields: dict[str, float | Field] | None = None,
    extra_points: int = 0,
) -> dict[str, sp.csr_matrix]:
    """Unit stiffness terms K_t of eq. (18), one per tension/rigidity coefficient.

    Parameters
    ----------
    basis : VolumeBasis
        The volume's basis.
    fields : dict, optional
        Spatial shape of a coefficient, by term name (``"alpha_u"``,
        ``"beta_uv"``, ...); missing terms are constant 1.
    extra_points : int
        Gauss points per span beyond degree + 1 (for convergence checks).

    Returns
    -------
    dict
        ``{"alpha_u": K_u, ..., "beta_vw": K_vw}``, each [mm^-0 per unit
        coefficient], so that K = sum_t coefficient_t K_t is in N/mm.
    """
    fields = dict(fields or {})
    unknown = set(fields) - set(STIFFNESS_TERMS)
    if unknown:
        raise ValueError(f"unknown stiffness fields {sorted(unknown)}; use {STIFFNESS_TERMS}")
    derivatives = {f"alpha_{k}": d for k, d in FIRST_DERIVATIVES.items()}
    derivatives.update({f"beta_{k}": d for k, d in SECOND_DERIVATIVES.items()})
    return {
        name: weighted_gram(basis, d, fields.get(name), extra_points, name)
        for name, d in derivatives.items()
    }


def assemble(terms: dict[str, sp.spmatrix], values: dict[str, float]) -> sp.csr_matrix:
    """K = sum_t values[t] * K_t for numeric coefficient values."""
    total = None
    for name, matrix in terms.items():
        value = float(values.get(name, 0.0))
        if value != 0.0:
            total = value * matrix if total is None else total + value * matrix
    if total is None:
        size = next(iter(terms.values())).shape[0]
        return sp.csr_matrix((size, size))
    return total.tocsr()
