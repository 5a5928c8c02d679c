"""What the discrepancy loop is told and what it records: its settings, each step (the
effect added, the fit, the tests) and the diagnosis as diagnosis.json holds it
(docs/diagnosis.md, docs/formats.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solvers.diagnosis.blind import blind_spots
from solvers.diagnosis.fit import EffectFit
from solvers.diagnosis.guard import PredictionCheck
from solvers.diagnosis.leftout import LeftOut
from solvers.diagnosis.stats import (
    ResidualTest,
    ScoreTest,
)
from symbolic.effects.library import ALL_EFFECT_NAMES, EFFECT_NAMES
from symbolic.model import PARAMETERS

SCHEMA = "dvs-diagnosis/1"


@dataclass(frozen=True)
class DiagnosisSettings:
    """Choices of the loop.

    Attributes
    ----------
    level : float
        Significance level of the residual test and (family-wise, Bonferroni)
        of the score tests of one round.
    max_effects : int
        Most effects added.
    candidates : tuple of str
        The library searched (default ``EFFECT_NAMES``: all effects but the opt-in
        ``stiffness_field``).
    cross_validate : bool
        Require a better prediction of left-out load cases (needs >= 2 cases).
    stop_when_consistent : bool
        Stop as soon as the residual is consistent with the noise. Off by
        default: the omnibus chi^2 over ~460 degrees of freedom has little power
        against an effect of a few parameters, which its score test (protected
        by the Bonferroni level) still finds.
    max_attempts : int
        Most significant candidates refitted per round before giving up.
    rival_margin : float
        A rival's chi^2 drop within this of the accepted effect's makes the two
        indistinguishable (default 3.84, the 95 % quantile of chi^2 with 1 dof; 0
        switches the rival refits off).
    """

    level: float = 0.01
    max_effects: int = 3
    candidates: tuple[str, ...] = EFFECT_NAMES
    cross_validate: bool = True
    stop_when_consistent: bool = False
    max_attempts: int = 3
    rival_margin: float = 3.84

    def __post_init__(self) -> None:
        if not 0 < self.level < 1:
            raise ValueError(f"level must lie in (0, 1), got {self.level}")
        unknown = set(self.candidates) - set(ALL_EFFECT_NAMES)
        if unknown:
            raise ValueError(f"unknown candidate effects {sorted(unknown)}; use {ALL_EFFECT_NAMES}")


@dataclass
class Step:
    """One model of the sequence: the base, then each added effect."""

    effect: str | None
    fit: EffectFit
    residual: ResidualTest
    statistic: float
    p_value: float
    bic: float
    sigma: float
    scores: list[ScoreTest] = field(default_factory=list)
    prediction: PredictionCheck | None = None
    rivals: list[dict] = field(default_factory=list)
    surroundings: dict | None = None
    """How the base model's surroundings changed once the effect was in (``revisit``)."""
    left_out: LeftOut | None = None
    """The model's own left-out prediction: its dispersion phi and model error (eq. G2, G4)."""

    def parameters(self) -> dict:
        """Every parameter of the fit: value, standard error, unit. The standard errors
        are at the step's dispersion phi (sigma sqrt(phi), quasi-likelihood): with model
        error the residual scatters more than the noise, and so do the estimates."""
        problem = self.fit.problem
        phi = 1.0 if self.left_out is None else self.left_out.dispersion
        std = self.fit.standard_errors(self.sigma * np.sqrt(phi))
        units = [PARAMETERS[n].unit for n in problem.names]
        for effect in problem.effects:
            units += list(effect.units) * (len(problem.positions) if effect.per_case else 1)
        return {
            label: {
                "value": float(value),
                "std": None if not np.isfinite(s) else float(s),
                "unit": unit,
            }
            for label, value, s, unit in zip(problem.labels, self.fit.p, std, units)
        }

    def record(self) -> dict:
        """The step as in diagnosis.json."""
        rms, largest = self.fit.rms()
        noise_rms = self.fit.problem.noise_rms(self.sigma)
        return {
            "effect": self.effect,
            "rms_mm": rms,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "parameters": self.parameters(),
            "max_residual_mm": largest,
            "residual_statistic": self.residual.statistic,
            "residual_dof": self.residual.dof,
            "residual_p_value": self.residual.p_value,
            "bic": self.bic,
            "effective_dof": self.fit.effective_dof(),
            "prediction": None if self.prediction is None else self.prediction.record(noise_rms),
            "left_out": None if self.left_out is None else self.left_out.record(noise_rms),
            "rivals": self.rivals,
            "surroundings": self.surroundings,
            "score_tests": [
                {
                    "effect": t.effect,
                    "statistic": t.statistic,
                    "dof": t.dof,
                    "p_value": t.p_value,
                    "log10_p_value": t.log_p / np.log(10.0),
                    "note": t.note,
                    **({} if t.detail is None else {"detail": t.detail}),
                }
                for t in self.scores
            ],
        }


@dataclass
class Diagnosis:
    """The outcome of the loop."""

    steps: list[Step]
    noise_mm: float
    noise_source: str
    noise_rms_mm: float
    level: float
    rejected: list[dict] = field(default_factory=list)
    base_choice: dict | None = None
    """How the base model was chosen (step 0, ``experiments.basemodel``), if it was."""
    stand_ins: list[dict] = field(default_factory=list)
    """Candidates that lowered the residual but are no cause (``solvers.diagnosis.standin``)."""

    @property
    def selected(self) -> list[str]:
        """Effects added, in order."""
        return [s.effect for s in self.steps if s.effect is not None]

    @property
    def rivals(self) -> dict[str, list[str]]:
        """Selected effect -> the candidates the data cannot tell from it."""
        return {s.effect: [r["effect"] for r in s.rivals] for s in self.steps if s.rivals}

    def blind_spots(self) -> list[dict]:
        """Effects the final round's score tests would miss at realistic sizes
        (``solvers.diagnosis.blind``); empty when that round was not run."""
        last = self.steps[-1]
        energy = last.fit.problem.model.energy
        return blind_spots(last.scores, len(last.fit.problem.cases), self.level, energy=energy)

    @property
    def unexplained(self) -> bool:
        """True when the final residual is significantly above the noise."""
        return self.steps[-1].residual.significant(self.level)

    @property
    def model_error_mm(self) -> float:
        """The model error that remains [mm] (eq. G4): the final model's left-out RMS beyond
        the noise's; 0 when its residual is consistent with the noise."""
        last = self.steps[-1].left_out
        if last is None or not self.unexplained:
            return 0.0
        return last.model_error_mm(self.noise_rms_mm)

    def document(self) -> dict:
        """diagnosis.json (schema dvs-diagnosis/1, docs/formats.md)."""
        last = self.steps[-1].left_out
        return {
            "schema": SCHEMA,
            "success": all(bool(s.fit.success) for s in self.steps),
            "noise_mm": self.noise_mm,
            "rms_before_mm": self.steps[0].fit.rms()[0],
            "rms_after_mm": self.steps[-1].fit.rms()[0],
            "steps": [s.record() for s in self.steps],
            "selected": self.selected,
            "unexplained": self.unexplained,
            "noise_source": self.noise_source,
            "noise_rms_mm": self.noise_rms_mm,
            "level": self.level,
            "rejected": self.rejected,
            "rivals": self.rivals,
            "blind_spots": self.blind_spots(),
            "model_error_mm": self.model_error_mm,
            "model_error": {
                "dispersion": None if last is None else last.dispersion,
                "source": None if last is None else last.source,
                "times_noise": self.model_error_mm / self.noise_rms_mm
                if self.noise_rms_mm
                else 0.0,
            },
            "stand_ins": self.stand_ins,
            **({} if self.base_choice is None else {"base_choice": self.base_choice}),
        }
