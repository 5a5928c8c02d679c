"""Does a fit explain the data? The residual against the dataset's noise level.

With the noise model of ``solvers.inverse.noise`` (every marker coordinate, rest and loaded,
with standard deviation sigma), the whitened residual rho = W r of a correct model
at its least-squares fit gives

    T = |rho|^2 / sigma^2 ~ chi^2(m - k),

m residuals, k parameters that move them (mu and gamma do not, at equilibrium). The
fit explains the data when P(chi^2 > T) >= the level (default 0.01). Far above the
noise (RMS over 3 times what noise alone gives) the verdict says so in words: the
model misses something, or the data are not what they claim (surfaces swapped, forces
in the wrong unit). The control-point objective of the paper compares fitted splines,
not markers, and has no noise model: it gets no verdict.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.diagnosis.stats import log_chi2_sf
from solvers.inverse.noise import Whitening

LEVEL = 0.01
"""Significance level of the residual test."""

FAR_ABOVE = 3.0
"""An RMS this many times the noise-only RMS is reported as far above the noise."""


@dataclass(frozen=True)
class Verdict:
    """The residual test of one fit.

    Attributes
    ----------
    explains : bool or None
        True when the residual is consistent with noise; None without a noise model.
    rms_mm, noise_rms_mm : float
        RMS marker distance of the fit, and what noise alone would give [mm].
    statistic : float
        T = |W r|^2 / sigma^2.
    dof : int
        m - k.
    p_value, log10_p : float
        P(chi^2_dof > T) and its base-10 logarithm (finite where p underflows).
    level : float
        Significance level used.
    line : str
        One sentence for people.
    """

    explains: bool | None
    rms_mm: float
    noise_rms_mm: float | None
    statistic: float | None
    dof: int | None
    p_value: float | None
    log10_p: float | None
    level: float
    line: str

    @property
    def far_above_noise(self) -> bool:
        """True when the RMS is over ``FAR_ABOVE`` times the noise-only RMS."""
        return bool(self.noise_rms_mm and self.rms_mm > FAR_ABOVE * self.noise_rms_mm)

    def warnings(self) -> list[str]:
        """One line when the residual is far above the noise, else none."""
        if not self.far_above_noise:
            return []
        ratio = self.rms_mm / self.noise_rms_mm
        return [f"the RMS residual is {ratio:.3g}x what noise alone gives; see the verdict"]

    def document(self) -> dict:
        """The ``verdict`` entry of ``result.json``."""
        return {
            "explains_data": self.explains,
            "rms_mm": self.rms_mm,
            "noise_rms_mm": self.noise_rms_mm,
            "chi2": self.statistic,
            "dof": self.dof,
            "p_value": self.p_value,
            "log10_p_value": self.log10_p,
            "level": self.level,
            "summary": self.line,
        }


def _text(explains: bool, rms: float, noise_rms: float, statistic, dof, log10_p) -> str:
    p = f"p = {10**log10_p:.2g}" if log10_p > -300 else "p < 1e-300"
    test = f"chi^2 {statistic:.4g} on {dof} dof, {p}"
    if explains:
        noise = f"noise alone {noise_rms * 1e3:.1f} um"
        return f"the fit explains the data: RMS {rms * 1e3:.1f} um, {noise}; {test}"
    if rms > FAR_ABOVE * noise_rms:
        return (
            f"the fit does NOT explain the data: RMS {rms * 1e3:.4g} um is {rms / noise_rms:.3g}x "
            "the "
            f"{noise_rms * 1e3:.1f} um of noise alone ({test}); the model misses something "
            "(try dvs diagnose) or the data are not what they claim"
        )
    return (
        f"the fit does not explain the data: RMS {rms * 1e3:.1f} um against "
        f"{noise_rms * 1e3:.1f} um "
        f"of noise alone ({test}); try dvs diagnose"
    )


def fit_verdict(
    problem, states: list[np.ndarray], rms_mm: float, objective: str = "markers", level=LEVEL
) -> Verdict:
    """The residual test of a fit of ``problem`` at its solution ``states``.

    Parameters
    ----------
    problem : InverseProblem
        The problem fitted; ``noise_mm`` is the dataset's sigma [mm].
    states : list of numpy.ndarray
        The solution's state of every case.
    rms_mm : float
        RMS marker distance of the fit [mm].
    objective : {"markers", "control_points"}
        What the fit compared; only markers have a noise model.
    level : float
        Significance level.
    """
    if objective != "markers" or not problem.noise_mm:
        reason = (
            "the dataset gives no noise level"
            if objective == "markers"
            else ("the control-point objective has no noise model")
        )
        line = f"no verdict: {reason} (RMS {rms_mm * 1e3:.1f} um)"
        return Verdict(None, rms_mm, None, None, None, None, None, level, line)
    residual = np.concatenate(
        [problem.case_residual(case, state) for case, state in zip(problem.cases, states)]
    )
    markers = sum(len(problem.observed) * case.n_observations for case in problem.cases)
    whitening = Whitening.of(problem.rest_noise_map(), residual.size, markers)
    sigma = float(problem.noise_mm)
    statistic = float(np.sum((whitening.matrix @ residual) ** 2) / sigma**2)
    dof = max(residual.size - int(np.sum(problem.active)), 1)
    log10_p = log_chi2_sf(statistic, dof) / np.log(10.0)
    p_value = float(10.0**log10_p)
    noise_rms = whitening.noise_rms(sigma, len(problem.observed))
    explains = p_value >= level
    line = _text(explains, rms_mm, noise_rms, statistic, dof, log10_p)
    return Verdict(explains, rms_mm, noise_rms, statistic, dof, p_value, log10_p, level, line)
