"""Left-out predictions: a model's (its dispersion, the model error) and a comparison's.

A real model misses more than the measurement noise. Each fold h of the data (a
contact, a load, a frame) is predicted by the model fitted to the others
(``solvers.diagnosis.guard``); the predictions' chi^2_h = |W_h r_h|^2 / sigma^2 scatter
with the dispersion

    phi = max(1, sum_h chi^2_h / m),                                        (G2)

m the residuals predicted (each once). With a single fold nothing can be left out, and
the in-sample chi^2 / (m - k) stands in for it (k the parameters fitted). phi = 1 when
the model predicts to the noise. Otherwise phi sigma^2 is the variance of what the model
cannot predict, and

    model error = noise RMS x sqrt(phi - 1)                                 (G4)

its RMS marker distance [mm] beside the noise's (the RMS a pure-noise residual has,
``ExtendedProblem.noise_rms``). The loop's statistics divide by phi (quasi-likelihood):
an effect must explain more than chance allows at the scatter the data actually have,
not at the noise alone (docs/diagnosis.md, "The selection rule").

``LeftOut`` records one model's left-out prediction, ``PredictionCheck`` the comparison of
two (G1, G3 of ``solvers.diagnosis.guard``, which computes both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

LEVEL = 0.01
"""The chance level of (G3): the probability that an effect with no predictive value
passes it (under noise of the estimated dispersion)."""


def dispersion(chi2: float, rows: int, fitted: int = 0) -> float:
    """phi of eq. (G2): the chi^2 per residual not fitted, at least 1."""
    return max(1.0, float(chi2) / max(int(rows) - int(fitted), 1))


def chance(level: float, dof: float) -> float:
    """The improvement (G3) that chance exceeds with probability ``level``: the upper
    ``level`` quantile of chi^2 with ``dof`` (at least 1) degrees of freedom."""
    return float(stats.chi2.isf(level, max(float(dof), 1.0)))


@dataclass
class LeftOut:
    """The left-out prediction of one model (every fold predicted from the others).

    Attributes
    ----------
    chi2 : float
        sum_h chi^2_h (dimensionless; sigma the noise).
    rows : int
        Residuals predicted (each left out once).
    fitted : int
        Parameters fitted to these residuals themselves (0 when left out; k in-sample).
    source : str
        ``"left-out"``, or ``"in-sample"`` with a single fold (chi^2 over m - k).
    """

    chi2: float
    rows: int
    fitted: int = 0
    source: str = "left-out"

    @property
    def dispersion(self) -> float:
        """phi, eq. (G2)."""
        return dispersion(self.chi2, self.rows, self.fitted)

    def rms_mm(self, noise_rms: float) -> float:
        """The left-out RMS marker distance [mm]: the noise's, ``noise_rms``, times
        sqrt(chi^2 / (m - fitted))."""
        return float(noise_rms * np.sqrt(self.chi2 / max(self.rows - self.fitted, 1)))

    def model_error_mm(self, noise_rms: float) -> float:
        """noise RMS x sqrt(phi - 1): the model error's RMS marker distance [mm]."""
        return float(noise_rms * np.sqrt(self.dispersion - 1.0))

    def record(self, noise_rms: float) -> dict:
        """As in diagnosis.json (each step's ``left_out``)."""
        return {
            "chi2": self.chi2,
            "rows": self.rows,
            "fitted": self.fitted,
            "source": self.source,
            "dispersion": self.dispersion,
            "rms_mm": self.rms_mm(noise_rms),
            "model_error_mm": self.model_error_mm(noise_rms),
        }


@dataclass
class PredictionCheck:
    """Left-out prediction of every load case, before and after adding an effect.

    ``improvement`` is G of eq. (G1), ``dispersion_after`` phi of (G2) for the model with
    the effect, ``threshold`` chi^2_k(1 - level) of (G3) for its ``added_dof`` k.
    """

    held_out: list[list[int]]
    chi2_before: list[float]
    chi2_after: list[float]
    nuisance_before: int
    nuisance_after: int
    method: str = "exact"
    linearised_improvement: float | None = None
    rows: int = 0
    added_dof: float = 1.0
    level: float = LEVEL

    @property
    def improvement(self) -> float:
        """G: the drop of the summed prediction chi^2 (G1)."""
        return float(np.sum(self.chi2_before) - np.sum(self.chi2_after))

    @property
    def before(self) -> LeftOut:
        """The previous model's left-out prediction."""
        return LeftOut(float(np.sum(self.chi2_before)), self.rows)

    @property
    def after(self) -> LeftOut:
        """The new model's left-out prediction."""
        return LeftOut(float(np.sum(self.chi2_after)), self.rows)

    @property
    def threshold(self) -> float:
        """chi^2_k(1 - level): what chance alone exceeds (G3)."""
        return chance(self.level, self.added_dof)

    @property
    def scaled_improvement(self) -> float:
        """G / phi_after."""
        return self.improvement / self.after.dispersion

    @property
    def distance(self) -> float:
        """G - phi_after chi^2_k(1 - level): how far (chi^2 units) G lies beyond (G3)'s
        boundary; the effect predicts better than chance where it is positive."""
        return self.improvement - self.after.dispersion * self.threshold

    @property
    def improves(self) -> bool:
        """True when the new model predicts the left-out cases better than chance (G3)."""
        return self.distance > 0.0

    def reason(self) -> str:
        """One line for reports."""
        return (
            f"left-out prediction chi2 {np.sum(self.chi2_before):.1f} -> "
            f"{np.sum(self.chi2_after):.1f} (dispersion {self.after.dispersion:.3g}): "
            f"improvement {self.scaled_improvement:.1f} against chance "
            f"{self.threshold:.1f}, {'better' if self.improves else 'not better than chance'}"
        )

    def record(self, noise_rms: float | None = None) -> dict:
        """As in diagnosis.json (each step's ``prediction``); with the noise RMS [mm], the
        left-out RMS marker distance before and after [mm]."""
        out = {
            "held_out": self.held_out,
            "chi2_before": self.chi2_before,
            "chi2_after": self.chi2_after,
            "nuisance_before": self.nuisance_before,
            "nuisance_after": self.nuisance_after,
            "rows": self.rows,
            "improvement": self.improvement,
            "dispersion_after": self.after.dispersion,
            "scaled_improvement": self.scaled_improvement,
            "added_dof": self.added_dof,
            "chance": self.threshold,
            "improves": self.improves,
            "method": self.method,
            "linearised_improvement": self.linearised_improvement,
        }
        if noise_rms is not None:
            out["rms_before_mm"] = self.before.rms_mm(noise_rms)
            out["rms_after_mm"] = self.after.rms_mm(noise_rms)
        return out
