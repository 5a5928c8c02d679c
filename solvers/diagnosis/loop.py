"""The discrepancy loop: residual -> candidate effect -> refit (docs/diagnosis.md, "The
loop and its selection rule").

1. Fit the base model (nested, whitened least squares; ``solvers.diagnosis.fit``) and
   test its residual against the noise (chi^2 of |W r|^2 / sigma^2).
2. Score-test every candidate effect at theta = 0 (``solvers.diagnosis.stats``), the
   statistics over the current model's left-out dispersion phi (eq. G2,
   ``solvers.diagnosis.leftout``); the significant ones (Bonferroni) are refitted in
   their order and judged (``_Loop.judge``): rejected when the BIC (chi^2 / phi + k log m)
   does not fall; a **stand-in** (``solvers.diagnosis.standin``: never selected) when it
   drives the model to a bound, ends on its own bound, leaves its plausible range, does
   not predict left-out data better than chance (eq. G3, ``solvers.diagnosis.guard``),
   does not survive a refinement of an unchecked volume (``refine``), or a bounded
   stand-in of the round explains far more (``undominated``); else accepted.
3. Rivals: the other significant candidates whose score reaches ``RIVAL_SCREEN`` of the
   accepted drop are refitted; one that explains far more is taken instead, one within
   ``rival_margin`` is named beside it (the design cannot tell them apart).
4. With ``revisit`` (a continuum chosen by step 0) the surroundings are searched again
   with each accepted effect in (``experiments.basemodel.revisit``).
5. Stop when nothing is accepted or ``max_effects`` are in. ``unexplained``: the final
   residual is still significant; the model error left is the final model's left-out
   dispersion (eq. G4). The last round's score tests give the blind spots
   (``solvers.diagnosis.blind``).

``Diagnosis.document()`` is ``diagnosis.json`` (schema ``dvs-diagnosis/1``).
"""

from __future__ import annotations

import numpy as np

from solvers.diagnosis.discretisation import discretisation_reason
from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.fit import STATISTICAL_TOLERANCE, EffectFit, fit, statistical_tolerance
from solvers.diagnosis.guard import left_out, prediction_check
from solvers.diagnosis.leftout import chance
from solvers.diagnosis.record import Diagnosis, DiagnosisSettings, Step
from solvers.diagnosis.standin import bic_improves, stand_in_reason
from solvers.diagnosis.stats import (
    ScoreTest,
    bic,
    residual_test,
    robust_sigma,
    score_test,
)
from solvers.inverse.problem import InverseProblem
from solvers.linalg.blas import one_thread
from symbolic.effects.library import effect_library


def _step(effect, current: EffectFit, sigma: float, statistic=None, p_value=None) -> Step:
    residual = residual_test(current, sigma)
    return Step(
        effect=effect,
        fit=current,
        residual=residual,
        statistic=residual.statistic if statistic is None else statistic,
        p_value=residual.p_value if p_value is None else p_value,
        bic=bic(current, sigma),
        sigma=sigma,
    )


RIVAL_SCREEN = 0.5
"""A candidate is refitted as a possible rival when its score statistic reaches this
fraction of the accepted effect's chi^2 drop."""


def _drop(previous: Step, step: Step, phi: float) -> float:
    """The chi^2 drop from ``previous`` to ``step``, divided by the dispersion."""
    return (previous.residual.statistic - step.residual.statistic) / phi


def _contenders(current, accepted, previous, ranked, library, sigma, phi) -> list[Step]:
    """The other significant candidates of the round, refitted, that keep the BIC rule
    and are no stand-ins by their bounds; only those whose score reaches
    ``RIVAL_SCREEN`` of the accepted drop."""
    drop = _drop(previous, accepted, phi)
    steps = []
    for test in ranked:
        if test.effect == accepted.effect or test.statistic < RIVAL_SCREEN * drop:
            continue
        refit = _refit(current, library[test.effect], test)
        other = _step(test.effect, refit, sigma, test.statistic, test.p_value)
        if stand_in_reason(current, refit, library[test.effect]) is None and bic_improves(
            previous, other, phi
        ):
            steps.append(other)
    return steps


def _settle(accepted, contenders, previous, margin, guard, phi) -> Step:
    """The accepted step, or a contender whose chi^2 drop (over phi) beats it by more
    than ``margin`` and passes ``guard``; its ``rivals`` are the others within ``margin``.

    The score order is local; when a refit shows another candidate explaining far more
    (on the diagnosis design a probe twice the declared radius: contact_patch lowered
    chi^2 by 899 where pre_tension, first by score, lowered it by 448), the likelihood
    decides.
    """

    def drop(step):
        return _drop(previous, step, phi)

    for other in sorted(contenders, key=drop, reverse=True):
        if drop(other) <= drop(accepted) + margin:
            break
        if not guard(other):  # predicts a left-out contact worse: no rival either
            contenders = [c for c in contenders if c is not other]
            continue
        contenders = [accepted] + [c for c in contenders if c is not other]
        accepted = other
        break
    accepted.rivals = [
        {"effect": c.effect, "chi2_drop": float(drop(c)), "accepted_drop": float(drop(accepted))}
        for c in contenders
        if drop(c) >= drop(accepted) - margin
    ]
    return accepted


def _refit(current: EffectFit, effect, test: ScoreTest) -> EffectFit:
    """Fit with one more effect, from the current estimate plus the score step."""
    problem = current.problem.with_effects(current.problem.effects + [effect])
    block = problem.slice_of(effect.name)
    start = np.concatenate([current.p, np.zeros(block.stop - block.start)])
    if effect.prior(problem.model) is None:  # a field starts flat, not at the raw GN step
        start[block] = np.clip(test.step, problem.lower[block], problem.upper[block])
    tolerance = statistical_tolerance(problem, current.whitened.size)
    refit = fit(problem, start, states=None, tolerance=tolerance)
    if not refit.success:
        start[block] = 0.0
        refit = fit(problem, start, tolerance=tolerance)
    return refit


def diagnose(
    base: InverseProblem,
    loads: list,
    settings: DiagnosisSettings | None = None,
    log=None,
    start: EffectFit | None = None,
    revisit=None,
    refine=None,
    discretisation: float = 0.0,
) -> Diagnosis:
    """Run the loop on a base problem, with BLAS on one thread (``solvers.linalg.blas``: the
    loop's dense work is small SVDs and QRs of Jacobians, which two OpenBLAS threads
    on a busy machine slow tenfold).

    Parameters
    ----------
    base : InverseProblem
        The base problem (``experiments.problem.fitting.build_problem``); its active
        parameters are refitted at every step.
    loads : list
        The dataset's declared loads (``experiments.problem.fitting.dataset_loads``).
    settings : DiagnosisSettings
        Level, candidates, limits.
    log : callable, optional
        Progress lines.
    start : EffectFit, optional
        A fit of the base model already made on ``base`` and ``loads`` (step 0's): the
        base fit starts from its estimate and reuses its problem's factorisations.
    revisit : callable, optional
        Called with a fit; returns None, or a fit with the same effects on another base
        problem (the surroundings re-estimated, ``experiments.basemodel.revisit``) and
        its record. The loop calls it after each accepted effect and goes on from the
        fit it returns, and, while the residual is still significant, on a candidate the
        overfitting guard rejects, which is then judged again on the surroundings it
        prefers.
    refine : callable, optional
        Called with a fit; returns the same model fitted on a refined volume
        (``experiments.diagnosis.refinement.Survival``). Where given (a volume whose
        resolution was not checked), an effect is accepted only if it also predicts
        left-out data better than chance there: else it stands in for the discretisation.
    discretisation : float
        D of eq. (D1), the discretisation error step 0's resolution check left (chi^2
        units, ``solvers.diagnosis.discretisation``): an effect whose left-out gain is
        no larger is a stand-in (D3).
    """
    with one_thread():
        quiet = log or (lambda *_: None)
        loop = _Loop(base, loads, settings or DiagnosisSettings(), quiet, revisit, refine)
        loop.discretisation = discretisation
        return loop.run(start)


class _Loop:
    """``diagnose``'s state: the library, the noise, the guard's cache, what was
    rejected and what stood in."""

    def __init__(self, base, loads, settings: DiagnosisSettings, log, revisit, refine) -> None:
        self.base, self.loads, self.settings, self.log = base, loads, settings, log
        self.revisit, self.refine = revisit, refine
        self.library = effect_library(settings.candidates, base.model.energy)
        self.cache: dict = {}
        self.rejected: list[dict] = []
        self.stand_ins: list[dict] = []
        self.dominant: list[Step] = []
        """The round's stand-ins by their bounds or size (``undominated``)."""
        self.sigma = 0.0
        self.discretisation = 0.0

    def predicts_better(self, step: Step, current: EffectFit) -> bool:
        """The overfitting guard (two or more load cases; G3), recorded as
        ``step.prediction``; with one case the in-sample drop over phi must beat chance."""
        if not (self.settings.cross_validate and len(self.base.cases) >= 2):
            step.left_out = left_out(step.fit, self.sigma, self.cache)
            k = max(step.fit.effective_dof() - current.effective_dof(), 1.0)
            drop = (current.cost - step.fit.cost) / self.sigma**2
            return drop / step.left_out.dispersion > chance(self.settings.level, k)
        step.prediction = prediction_check(
            current, step.fit, self.sigma, self.cache, level=self.settings.level
        )
        step.left_out = step.prediction.after
        return step.prediction.improves

    def left_out(self, step: Step) -> None:
        """The step's own left-out prediction (its dispersion phi, eq. G2)."""
        if step.left_out is None:
            step.left_out = left_out(step.fit, self.sigma, self.cache)

    def stand_in(self, step: Step, reason: str, previous: Step) -> None:
        """Record a candidate that lowered the residual but is no cause."""
        problem = step.fit.problem
        block = problem.slice_of(step.effect)
        values = dict(zip(problem.labels[block], map(float, step.fit.p[block])))
        entry = {
            "effect": step.effect,
            "reason": reason,
            "rms_mm": step.fit.rms()[0],
            "chi2_drop": float(previous.residual.statistic - step.residual.statistic),
            "parameters": values,
        }
        if step.prediction is not None:
            entry["prediction"] = step.prediction.record(step.fit.problem.noise_rms(self.sigma))
        self.stand_ins.append(entry)
        self.rejected.append({"effect": step.effect, "reason": reason, "stand_in": True})
        self.log(f"  {step.effect} is a stand-in: {reason}")

    def judge(self, current: EffectFit, previous: Step, test: ScoreTest) -> Step | None:
        """The refit with ``test``'s effect if it is accepted, else None (recorded as
        rejected or as a stand-in)."""
        effect = self.library[test.effect]
        refit = _refit(current, effect, test)
        candidate = _step(test.effect, refit, self.sigma, test.statistic, test.p_value)
        phi = previous.left_out.dispersion
        if not bic_improves(previous, candidate, phi):
            self.rejected.append({"effect": test.effect, "reason": "BIC did not improve"})
            return None
        reason = stand_in_reason(current, refit, effect)
        if reason is not None:
            self.stand_in(candidate, reason, previous)
            self.dominant.append(candidate)
            return None
        # dominated is a stand-in whatever the left-out refits say; with ``revisit`` a
        # rejected candidate may come back larger on new surroundings, so they decide
        if self.revisit is None and self.undominated(candidate, previous, phi) is None:
            return None
        if self.predicts_better(candidate, current):
            return self.surviving(candidate, current, previous)
        reason = candidate.prediction.reason()
        unexplained = previous.residual.significant(self.settings.level)
        moved = self.revisit(refit) if self.revisit is not None and unexplained else None
        if moved is not None:  # on the surroundings the effect prefers
            candidate = _moved(candidate, *moved)
            candidate.left_out = None
            if self.predicts_better(candidate, current) and bic_improves(previous, candidate, phi):
                return self.surviving(candidate, current, previous)
            reason += "; on revisited surroundings " + candidate.prediction.reason()
        self.stand_in(candidate, reason, previous)
        return None

    def surviving(self, candidate: Step, current: EffectFit, previous: Step) -> Step | None:
        """``candidate`` if its left-out gain beats the discretisation error (D3) and it
        still predicts better than chance on the refined volume (``refine``), or without
        one; else None, recorded as a stand-in."""
        reason = discretisation_reason(candidate.prediction, self.discretisation)
        if reason is not None:
            self.stand_in(candidate, reason, previous)
            return None
        if self.refine is None:
            return candidate
        finer = _step(candidate.effect, self.refine(candidate.fit), self.sigma)
        if self.predicts_better(finer, self.refine(current)):
            return candidate
        reason = "does not survive a refinement of the volume (discretisation error): "
        reason += finer.prediction.reason() if finer.prediction else "no gain beyond chance"
        self.stand_in(candidate, reason, previous)
        return None

    def run(self, start: EffectFit | None) -> Diagnosis:
        """The loop (module docstring)."""
        settings, log = self.settings, self.log
        if start is None:
            empty = ExtendedProblem(self.base, self.loads, [])
            current = fit(empty, tolerance=STATISTICAL_TOLERANCE)
        else:
            current = fit(
                start.problem, start.p, states=start.states, tolerance=STATISTICAL_TOLERANCE
            )
        if self.base.noise_mm is not None:
            sigma, source = float(self.base.noise_mm), "given"
        else:
            sigma, source = robust_sigma(current), "estimated (1.4826 median |W r|)"
        self.sigma = sigma
        current.problem.sigma = sigma  # scales the priors of the problems derived from it
        steps = [_step(None, current, sigma)]
        self.left_out(steps[-1])
        log(_line(steps[-1]))
        while len(steps) - 1 < settings.max_effects:
            if settings.stop_when_consistent and not steps[-1].residual.significant(settings.level):
                break
            accepted = self.round(current, steps[-1])
            if accepted is None:
                break
            moved = None
            if self.revisit is not None and not accepted.surroundings:
                moved = self.revisit(accepted.fit)
            if moved is not None:
                accepted = _moved(accepted, *moved)
                accepted.left_out = None
            current = accepted.fit
            current.problem.sigma = sigma
            self.left_out(accepted)
            steps.append(accepted)
            log(_line(accepted))
        noise_rms = ExtendedProblem(self.base, self.loads, []).noise_rms(sigma)
        return Diagnosis(
            steps, sigma, source, noise_rms, settings.level, self.rejected, None, self.stand_ins
        )

    def round(self, current: EffectFit, previous: Step) -> Step | None:
        """One round: score tests at the dispersion, then the candidates in their order."""
        settings = self.settings
        active = {a.name for a in current.problem.effects}
        remaining = [e for name, e in self.library.items() if name not in active]
        if not remaining:
            return None
        phi = previous.left_out.dispersion
        tests = [score_test(current, effect, self.sigma * np.sqrt(phi)) for effect in remaining]
        previous.scores = tests
        threshold = np.log(settings.level / len(remaining))
        ranked = sorted((t for t in tests if t.log_p < threshold), key=lambda t: t.log_p)
        scaled = f" (over dispersion {phi:.3g})" if phi > 1.0 else ""
        self.log(
            f"  score tests{scaled}: " + ", ".join(f"{t.effect} {t.statistic:.1f}" for t in tests)
        )
        accepted, self.dominant = None, []
        for test in ranked[: settings.max_attempts]:
            accepted = self.undominated(self.judge(current, previous, test), previous, phi)
            if accepted is not None:
                break
        if accepted is None or settings.rival_margin <= 0:
            return accepted
        contenders = _contenders(current, accepted, previous, ranked, self.library, self.sigma, phi)
        chosen = _settle(
            accepted,
            contenders,
            previous,
            settings.rival_margin,
            lambda step: (
                stand_in_reason(current, step.fit, self.library[step.effect]) is None
                and self.predicts_better(step, current)
                and discretisation_reason(step.prediction, self.discretisation) is None
            ),
            phi,
        )
        if chosen is not accepted:
            self.log(f"  {chosen.effect} lowers chi2 by far more than {accepted.effect}: taken")
        for rival in chosen.rivals:
            self.log(
                f"  {rival['effect']} explains it as well (chi2 drop {rival['chi2_drop']:.1f} "
                f"against {rival['accepted_drop']:.1f})"
            )
        return chosen if chosen is accepted else self.undominated(chosen, previous, phi)

    def undominated(self, chosen: Step | None, previous: Step, phi: float) -> Step | None:
        """``chosen``, unless a stand-in of the round by its bounds or size lowered chi^2
        (over phi) by more than ``rival_margin`` beyond it: the residual is then mostly
        what that stand-in absorbs, which the library cannot represent, and the smaller
        part ``chosen`` explains is not established as its cause (a stand-in too)."""
        if chosen is None:
            return None
        drop = _drop(previous, chosen, phi)
        margin = max(self.settings.rival_margin, 0.0)
        for other in self.dominant:
            if _drop(previous, other, phi) > drop + margin:
                reason = (
                    f"{other.effect}, a stand-in, lowers chi2 by far more "
                    f"({_drop(previous, other, phi):.1f} against {drop:.1f}): the residual is "
                    "mostly what the library cannot represent"
                )
                self.stand_in(chosen, reason, previous)
                return None
        return chosen


def _moved(step: Step, fitted: EffectFit, record: dict) -> Step:
    """The accepted step refitted on the surroundings ``revisit`` found."""
    moved = _step(step.effect, fitted, step.sigma, step.statistic, step.p_value)
    moved.scores, moved.prediction, moved.rivals = step.scores, step.prediction, step.rivals
    moved.surroundings = record
    return moved


def _line(step: Step) -> str:
    rms, _ = step.fit.rms()
    name = step.effect or "base model"
    out = (
        f"{name}: rms {rms * 1e3:.1f} um, chi2 {step.residual.statistic:.0f}/{step.residual.dof} "
        f"(p {step.residual.p_value:.2g}), statistic {step.statistic:.1f}, p {step.p_value:.2g}"
    )
    if step.left_out is not None and step.left_out.dispersion > 1.0:
        out += f", left-out dispersion {step.left_out.dispersion:.3g}"
    return out
