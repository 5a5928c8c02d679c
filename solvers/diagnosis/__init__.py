"""The discrepancy loop: residual -> candidate effect -> refit (docs/diagnosis.md).

- ``loop``: ``diagnose``; ``record``: its settings and what it records (``diagnosis.json``);
- ``extended``: an inverse problem extended by effects (docs/inverse.md eq. 24), sharing a
  ``cache``; on a model linear in the state it runs ``solvers.forward.linearpath``;
- ``fit``: its nested least-squares fit; ``stability``: the admissible set;
- ``stats``: the residual test, score tests, the information criterion, the chi^2 power;
- ``guard``: the left-out-contact check against overfitting; ``blind``: what the design
  cannot see;
- ``verdict``: does a fit explain the data; ``report``: ``report.md``;
- ``casadieval``: fast evaluation of CasADi Functions into numpy and scipy arrays."""

from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import EffectFit, fit
from solvers.diagnosis.loop import diagnose
from solvers.diagnosis.record import Diagnosis, DiagnosisSettings, Step
from solvers.diagnosis.stats import ScoreTest, power, score_test
from solvers.diagnosis.verdict import Verdict, fit_verdict

__all__ = [
    "Diagnosis",
    "DiagnosisSettings",
    "EffectFit",
    "ExtendedProblem",
    "ScoreTest",
    "Step",
    "Verdict",
    "diagnose",
    "fit",
    "fit_verdict",
    "power",
    "score_test",
]
