"""What a design is worth: its figures, and the criteria a search maximises.

Everything is read from the whitened Gram matrix M(D) of eq. (D5) (``pool.Totals``):

- **D-optimal**: log det(F)^(1/p) with F = M_xx / sigma^2 (eq. D1): the volume of the
  confidence ellipsoid of the p base parameters, independent of their units.
- **A-optimal**: the sum of the squared *relative* standard errors,
  sum_i (F^-1)_ii / x_i^2. Plain tr(F^-1) would add alpha_u's and alpha_v's variances
  in different units and be ruled by the largest; the relative form asks for every
  parameter's percentage alike (choice where the literature is silent on units).
- **power** of one effect, and **maximin** over several: the probability of missing
  the effect at the stated level, beta = 1 - power (eq. D3), scored as -log beta. It
  orders designs as the power does, and goes on separating them when the power of
  both rounds to 1 (beta 1e-3 against 1e-9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from solvers.design.information import (
    EffectPower,
    effect_figures,
    projected_signal,
)
from solvers.design.pool import Layout
from solvers.diagnosis.stats import critical_value

CRITERIA = ("d", "a", "power", "maximin")
"""The criteria of ``dvs design --criterion``."""


@dataclass(frozen=True)
class DesignFigures:
    """The predicted figures of one design.

    Attributes
    ----------
    names : tuple of str
        The base parameters x.
    standard_errors : numpy.ndarray
        sigma sqrt(diag F^-1) per parameter (natural units); inf where F is singular.
    det_root : float
        det(F)^(1/p) [1 / unit^2]: the D-criterion.
    relative_variance : float
        sum_i (F^-1)_ii / x_i^2: the A-criterion (smaller is better).
    powers : tuple of EffectPower
        Per effect of the pool, eqs. (D2, D3).
    """

    names: tuple[str, ...]
    standard_errors: np.ndarray
    det_root: float
    relative_variance: float
    powers: tuple[EffectPower, ...]

    def document(self) -> dict:
        """The figures as JSON-ready numbers (``design.json``)."""
        finite = [float(v) if np.isfinite(v) else None for v in self.standard_errors]
        return {
            "standard_errors": dict(zip(self.names, finite)),
            "det_root": float(self.det_root),
            "relative_variance": _finite(self.relative_variance),
            "powers": {
                p.name: {
                    "magnitude": p.magnitude,
                    "noncentrality": p.noncentrality,
                    "dof": p.dof,
                    "one_sided": p.one_sided,
                    "power": p.power,
                }
                for p in self.powers
            },
        }


def _finite(value: float):
    return float(value) if np.isfinite(value) else None


def fisher(matrix: np.ndarray, layout: Layout, sigma: float) -> np.ndarray:
    """F = M_xx / sigma^2 (eq. D1), natural units."""
    index = layout.nuisance
    return matrix[np.ix_(index, index)] / sigma**2


def _covariance(information: np.ndarray) -> np.ndarray | None:
    """F^-1, or None when F is singular (a parameter the design does not see)."""
    if not information.size:
        return np.zeros((0, 0))
    values = np.linalg.eigvalsh(information)
    if values.min() <= 1e-12 * max(values.max(), 1e-300):
        return None
    return np.linalg.inv(information)


def log_det_root(matrix: np.ndarray, layout: Layout, sigma: float) -> float:
    """log det(F)^(1/p); -inf for a singular F."""
    information = fisher(matrix, layout, sigma)
    if not information.size:
        return 0.0
    sign, value = np.linalg.slogdet(information)
    return float(value / len(information)) if sign > 0 else -np.inf


def relative_variance(matrix: np.ndarray, layout: Layout, sigma: float) -> float:
    """sum_i (F^-1)_ii / x_i^2 (the A-criterion); inf for a singular F."""
    covariance = _covariance(fisher(matrix, layout, sigma))
    if covariance is None:
        return np.inf
    return float(np.sum(np.diag(covariance) / layout.x**2))


def design_power(matrix: np.ndarray, layout: Layout, index: int, sigma: float, level: float):
    """Eqs. (D2, D3) of the pool's effect ``index`` on the design of ``matrix``."""
    effect, magnitude = layout.effects[index]
    theta, signal = layout.blocks[index]
    projected, dof = projected_signal(
        matrix, layout.nuisance, theta, signal, np.asarray(effect.scales, dtype=float)
    )
    total = float(matrix[signal, signal])
    return effect_figures(effect, magnitude, projected, total, dof, sigma, level, len(theta))


def log_miss(figures: EffectPower) -> float:
    """-log beta, beta = 1 - power (eq. D3), computed in the tail (no rounding to 1)."""
    if figures.dof == 0:
        return 0.0
    critical = critical_value(figures.level, figures.dof, figures.one_sided)
    if figures.one_sided:
        value = -special.log_ndtr(critical - np.sqrt(figures.noncentrality))
    else:
        miss = special.chndtr(critical, figures.dof, max(figures.noncentrality, 1e-300))
        value = -np.log(miss) if miss > 0 else np.inf
    if not np.isfinite(value):  # beyond double precision: keep ordering by lambda
        value = 700.0 + np.log1p(figures.noncentrality)
    return float(value)


def design_figures(matrix: np.ndarray, layout: Layout, sigma: float, level: float):
    """Every figure of a design (``DesignFigures``)."""
    covariance = _covariance(fisher(matrix, layout, sigma))
    if covariance is None:
        errors = np.full(len(layout.names), np.inf)
    else:
        errors = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    powers = tuple(
        design_power(matrix, layout, k, sigma, level) for k in range(len(layout.effects))
    )
    return DesignFigures(
        layout.names,
        errors,
        float(np.exp(log_det_root(matrix, layout, sigma))),
        relative_variance(matrix, layout, sigma),
        powers,
    )


@dataclass(frozen=True)
class Criterion:
    """A design criterion: ``score(M)``, larger is better.

    Attributes
    ----------
    name : str
        One of ``CRITERIA``.
    layout : Layout
        The pool's columns.
    sigma : float
        Noise level [mm].
    level : float
        Significance level of the score tests (power criteria).
    """

    name: str
    layout: Layout
    sigma: float
    level: float = 0.01

    def __post_init__(self) -> None:
        if self.name not in CRITERIA:
            raise ValueError(f"unknown criterion {self.name!r}; choose from {', '.join(CRITERIA)}")
        if self.name in ("power", "maximin") and not self.layout.effects:
            raise ValueError(f"criterion {self.name} needs an effect as the target")
        if self.name == "power" and len(self.layout.effects) != 1:
            raise ValueError("criterion power takes one effect; use maximin for several")
        if self.name in ("d", "a") and not len(self.layout.names):
            raise ValueError(f"criterion {self.name} needs estimated base parameters")

    def score(self, matrix: np.ndarray) -> float:
        """The criterion's value of the design with Gram matrix ``matrix``."""
        if self.name == "d":
            return log_det_root(matrix, self.layout, self.sigma)
        if self.name == "a":
            return -relative_variance(matrix, self.layout, self.sigma)
        misses = [
            log_miss(design_power(matrix, self.layout, k, self.sigma, self.level))
            for k in range(len(self.layout.effects))
        ]
        return float(min(misses))
