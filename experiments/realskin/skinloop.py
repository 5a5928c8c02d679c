"""The loop on real skin: a linear fit, then score tests and refits while a candidate is worth it.

The candidates are stiffening k0 (eq. 1), a volumetric coupling, in-plane anisotropy and a
second material found by the rectangle scan (``experiments.realskin.scan``); an effect
is added while its score test is significant and its predicted cost decrease is worth it
(``RealSkinSettings.significance`` and ``min_gain``; docs/realskin.md).
"""

from __future__ import annotations

from experiments.realskin.scan import SCAN, CellTerms, ScanResult, rect_indicator, scan, with_region
from experiments.realskin.setup import RealSkinSettings, Setup
from experiments.realskin.stages import LABELS, NULL, ONE_SIDED, StageFit, fit_stage, score_test
from solvers.forward.equilibrium import EquilibriumError
from solvers.inverse.space import SkinParameterSpace
from symbolic.skin_slab import REGION_RATIO


def parameter_space(names, start, settings: RealSkinSettings) -> SkinParameterSpace:
    return SkinParameterSpace.build(names, start, settings.bounds)


def fit_base(setup: Setup, settings: RealSkinSettings, label: str, log) -> StageFit:
    """The fit of the setup's base parameters (``setup.base_names``) from its start values."""
    return fit_stage(
        setup.model,
        setup.cases,
        parameter_space(setup.base_names, setup.start, settings),
        label,
        log,
    )


def _score_all(setup: Setup, fit: StageFit, names, settings) -> dict:
    """Score test of every candidate at the fit; the scan's entry is a ``ScanResult``."""
    out = {}
    for name in names:
        if name == SCAN:
            if setup.cells is None:
                setup.cells = CellTerms.build(setup.model, setup.grid)
            out[name] = scan(
                setup.model,
                setup.cases,
                fit.names,
                fit.x,
                settings.bounds,
                setup.grid,
                setup.cells,
                states=fit.states,
            )
        else:
            out[name] = score_test(
                setup.model,
                setup.cases,
                fit.names,
                fit.x,
                name,
                NULL[name],
                settings.bounds,
                ONE_SIDED[name],
                fit.states,
            )
    return out


def fit_from_starts(
    setup: Setup, names: tuple, start: dict, settings: RealSkinSettings, label: str, log
) -> StageFit:
    """Fit ``names`` from ``start``; a parameter at its null value with several start
    values (``settings.starts``) is fitted from each in turn, the other parameters
    starting from the best fit so far (a continuation: with k0 larger, the tensions
    must be smaller). The lowest cost wins; a start without equilibrium is skipped."""
    name = next(
        (n for n in names if start.get(n) == NULL.get(n) and len(settings.starts.get(n, ())) > 1),
        None,
    )
    if name is None:
        return fit_stage(
            setup.model, setup.cases, parameter_space(names, start, settings), label, log
        )
    best = None
    for value in settings.starts[name]:
        trial = {**(start if best is None else best.as_dict()), name: value}
        log(f"  start {name} = {value:g}")
        try:
            fit = fit_stage(
                setup.model, setup.cases, parameter_space(names, trial, settings), label, log
            )
        except EquilibriumError as error:
            log(f"  {label}: start skipped ({error})")
            continue
        if best is None or fit.cost < best.cost:
            best = fit
    if best is None:
        raise EquilibriumError(f"{label}: no start reached an equilibrium")
    return best


def _score(entry):
    return entry.score if isinstance(entry, ScanResult) else entry


def close_the_loop(
    setup: Setup, settings: RealSkinSettings, log=print, base_label: str = "linear"
) -> dict:
    """Base fit (``base_label``), then score tests and refits while a candidate is worth
    adding.

    Returns
    -------
    dict
        ``stages`` (list of StageFit, the linear fit first), ``rounds`` (per round the
        scores of every remaining candidate and the chosen one; ``failed_refit``, the
        StageFit of a refit that ended above the previous cost, which the nested model
        cannot do at a true optimum: it is not added and the loop stops) and ``diagnostics``
        (scores of extensions that are not candidates, at the final fit).
    """
    stage = fit_base(setup, settings, base_label, log)
    stages, rounds = [stage], []
    available = [
        c for c in settings.candidates if c != REGION_RATIO or setup.model.region is not None
    ]
    found = None
    while available and len(stages) <= settings.max_effects:
        entries = _score_all(setup, stage, available, settings)
        scores = {k: _score(v) for k, v in entries.items()}
        best = max(scores.values(), key=lambda s: s.statistic)
        worth = best.p_value < settings.significance and (
            best.predicted_decrease >= settings.min_gain * stage.cost
        )
        rounds.append({"scores": scores, "chosen": best.name if worth else None})
        if SCAN in entries:
            rounds[-1]["scan"] = entries[SCAN]
        log(
            "  scores: "
            + ", ".join(
                f"{s.name} T={s.statistic:.3g} (p={s.p_value:.2g}, "
                f"predicted -{s.predicted_decrease:.3g})"
                for s in scores.values()
            )
            + f" -> {best.name if worth else 'stop'}"
        )
        if not worth:
            break
        best, refit = _refit_best(setup, stage, scores, entries, settings, log)
        rounds[-1]["chosen"] = best.name
        if best.name == SCAN:
            found = entries[SCAN]
        if refit.cost > stage.cost:  # nested: the null value alone gives stage.cost
            log(
                f"  {LABELS[best.name]}: the refit ends above the previous cost "
                f"({refit.cost:.6g} > {stage.cost:.6g}); not added, the loop stops"
            )
            rounds[-1].update(chosen=None, failed_refit=refit)
            break
        stage = refit
        stages.append(stage)
        available.remove(best.name)
    diagnostics = {
        k: _score(v) for k, v in _score_all(setup, stage, settings.diagnostics, settings).items()
    }
    return {"stages": stages, "rounds": rounds, "diagnostics": diagnostics, "found": found}


def _refit_best(setup: Setup, stage: StageFit, scores: dict, entries: dict, settings, log):
    """Refit the ``settings.lookahead`` worthy candidates with the largest statistics
    (each added alone to the stage) and return (score, refit) of the one that ends
    lowest; the scanned region, when chosen, stays in ``setup.model``."""
    ranked = sorted(scores.values(), key=lambda s: s.statistic, reverse=True)
    worthy = [
        s
        for s in ranked
        if s.p_value < settings.significance
        and s.predicted_decrease >= settings.min_gain * stage.cost
    ][: max(settings.lookahead, 1)]
    base_model, tried = setup.model, []
    for score in worthy:
        setup.model = base_model
        parameter = REGION_RATIO if score.name == SCAN else score.name
        if score.name == SCAN:
            found = entries[SCAN]
            setup.model = with_region(base_model, rect_indicator(setup.grid.region, found.rect))
            log(f"  found region: {found.rect} (direction {found.score.direction:+.0f})")
        names = stage.names + (parameter,)
        start = {**stage.as_dict(), parameter: NULL[parameter]}
        label = f"+ {LABELS[score.name]}"
        try:
            refit = fit_from_starts(setup, names, start, settings, label, log)
        except EquilibriumError as error:
            if len(worthy) == 1:
                raise
            log(f"  {label}: no refit ({error})")
            continue
        tried.append((score, refit, setup.model))
    if not tried:
        raise EquilibriumError("no candidate's refit reached an equilibrium")
    best, refit, setup.model = min(tried, key=lambda t: t[1].cost)
    if len(worthy) > 1:
        log(f"  lookahead: {best.name} ends lowest ({refit.cost:.6g})")
    return best, refit


def likelihood_ratio(before: StageFit, after: StageFit) -> float:
    """2 (cost_before - cost_after) / sigma_after^2: chi^2 with the added parameters."""
    return 2.0 * (before.cost - after.cost) / after.sigma**2
