"""report.md of a diagnosis: residual before/after, every test, the added parameters.

Plain text from ``Diagnosis.document()`` (schema ``dvs-diagnosis/1``) and the
Diagnosis itself (for the effects' equations); the residual-map figure it
links to is drawn by ``experiments.diagnosis.diagnose.plot_residuals``.
"""

from __future__ import annotations

from solvers.diagnosis.blind import sentence


def _parameter_lines(record: dict, names) -> list[str]:
    lines = ["| parameter | value | std | unit |", "|---|---|---|---|"]
    for label, entry in record["parameters"].items():
        if names is not None and label.split("[")[0] not in names:
            continue
        std = "-" if entry["std"] is None else f"{entry['std']:.3g}"
        lines.append(f"| {label} | {entry['value']:.4g} | {std} | {entry['unit']} |")
    return lines


def verdict(document: dict) -> str:
    """What the diagnosis concludes, worded so that no stand-in reads as a cause.

    When the residual stays significant the added effects are reported as the library's
    closest approximations, not as the cause of the discrepancy. When it is consistent
    with noise, the effects the design would likely have missed follow as not ruled out
    (``blind_spots``).
    """
    text = _verdict(document)
    if not document["unexplained"] and document.get("blind_spots"):
        text += "; " + sentence(document["blind_spots"])
    return text


def _remains(document: dict) -> str:
    """'model error X um (Y x the noise) remains' (eq. G4)."""
    error = document.get("model_error_mm", 0.0)
    ratio = document.get("model_error", {}).get("times_noise", 0.0)
    if error <= 0.0 and document.get("steps"):  # significant, yet predicted to the noise
        last = document["steps"][-1]
        return (
            f"the residual exceeds the noise (chi2 {last['residual_statistic']:.0f} on "
            f"{last['residual_dof']}, p {last['residual_p_value']:.2g}) but its left-out "
            "prediction does not, so no model error can be stated"
        )
    return f"model error {error * 1e3:.1f} um ({ratio:.2g} x the noise) remains"


def _stand_in_clause(document: dict) -> str:
    """'; A, B lower the residual but are stand-ins' ('' without any)."""
    names = list(dict.fromkeys(s["effect"] for s in document.get("stand_ins", [])))
    if not names:
        return ""
    verb = "lowers" if len(names) == 1 else "lower"
    return (
        f"; {', '.join(names)} {verb} the residual but "
        f"{'is a stand-in' if len(names) == 1 else 'are stand-ins'}, not causes (report.md)"
    )


def base_at_noise(document: dict) -> bool:
    """True when the base model's residual already passes the residual test (p >= level):
    effects added after it are then not needed to explain the residual."""
    p_value = document["steps"][0].get("residual_p_value") if document.get("steps") else None
    return p_value is not None and p_value >= document.get("level", 0.01)


def untested_at_one_point(document: dict) -> list[str]:
    """Selected effects with parameters shared by the loads when every load is at one
    contact point: leaving out a load there is no test of prediction elsewhere (the
    model scales the same point's response), so the left-out gain of such an effect is
    no stronger evidence than its in-sample drop. Per-capture effects are tested across
    each capture's marker halves and are not listed."""
    if (document.get("design") or {}).get("contacts") != 1:
        return []
    return [
        step["effect"]
        for step in document.get("steps", [])[1:]
        if step.get("effect") in document["selected"]
        and (step.get("prediction") or {}).get("added_dof", 0) > 0
    ]


def presents_as_cause(document: dict) -> bool:
    """True when the verdict names the selected effects as what explains the residual:
    explained, effects selected, the base model alone not consistent with noise, and
    not a shared effect on a design with every load at one point."""
    return (
        bool(document["selected"])
        and not document["unexplained"]
        and not base_at_noise(document)
        and not untested_at_one_point(document)
    )


def _verdict(document: dict) -> str:
    rivals = document.get("rivals", {})
    selected = ", ".join(
        " or ".join([name, *rivals[name]]) if name in rivals else name
        for name in document["selected"]
    )
    if document["selected"] and not document["unexplained"] and base_at_noise(document):
        p_value = document["steps"][0]["residual_p_value"]
        one = len(document["selected"]) == 1 and not rivals
        return (
            f"explained: the base model alone is consistent with noise (p {p_value:.2g}); "
            f"{selected} {'predicts' if one else 'predict'} left-out data better than chance "
            f"but {'is' if one else 'are'} not needed to explain the residual: weak "
            "evidence, not an established cause"
        )
    untested = untested_at_one_point(document)
    if document["selected"] and not document["unexplained"] and untested:
        return (
            f"explained: the residual is consistent with noise once {selected} is added; "
            "every load is at one point, so the left-out loads do not test prediction "
            f"elsewhere and {', '.join(untested)} {'is' if len(untested) == 1 else 'are'} "
            "not established as the cause"
        )
    if rivals:
        return (
            f"{'unexplained' if document['unexplained'] else 'explained'}: the residual "
            f"{'is not noise even' if document['unexplained'] else 'is consistent with noise'}"
            f" with {selected} added; where the effects are joined by 'or' this design "
            "cannot tell them apart, so neither is established as the cause"
        )
    if not document["unexplained"]:
        if selected:
            return f"explained: the residual is consistent with noise once {selected} is added"
        return "consistent with noise: the base model needs nothing added"
    if selected:
        return (
            f"unexplained: {_remains(document)} even with {selected} added (each predicts "
            "left-out data better than chance); these are the library's closest "
            "approximations, not established causes" + _stand_in_clause(document)
        )
    return (
        f"unexplained: {_remains(document)}; no effect in the library predicts it"
        + _stand_in_clause(document)
    )


def report(diagnosis, document: dict) -> str:
    """report.md: residual before/after, each step's test, the added effects' parameters."""
    steps = document["steps"]
    first, last = steps[0], steps[-1]
    lines = [
        "# Diagnosis: what the base model is missing",
        "",
        f"- noise: {document['noise_mm']:.4g} mm per coordinate ({document['noise_source']}); "
        "a pure-noise residual has an RMS marker distance of "
        f"{document['noise_rms_mm'] * 1e3:.1f} um",
        f"- residual RMS {document['rms_before_mm'] * 1e3:.1f} um -> "
        f"{document['rms_after_mm'] * 1e3:.1f} um; max {first['max_residual_mm'] * 1e3:.1f} um -> "
        f"{last['max_residual_mm'] * 1e3:.1f} um",
        f"- selected: {', '.join(document['selected']) or 'nothing'}",
        f"- model error: {document.get('model_error_mm', 0.0) * 1e3:.1f} um "
        f"({document.get('model_error', {}).get('times_noise', 0.0):.2g} x the noise; the "
        "final model's left-out RMS beyond the noise's)",
        f"- unexplained: **{str(document['unexplained']).lower()}** (final chi^2 "
        f"{last['residual_statistic']:.1f} on {last['residual_dof']} dof, p = "
        f"{last['residual_p_value']:.3g}, level {document['level']})",
        f"- verdict: {verdict(document)}",
        "",
        "## Steps",
        "",
        "| step | effect | RMS [um] | max [um] | statistic | p-value | residual chi^2 / dof "
        "| residual p | BIC |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for k, step in enumerate(steps):
        lines.append(
            f"| {k} | {step['effect'] or 'base model'} | {step['rms_mm'] * 1e3:.1f} | "
            f"{step['max_residual_mm'] * 1e3:.1f} | {step['statistic']:.1f} | "
            f"{step['p_value']:.3g} | {step['residual_statistic']:.0f} / {step['residual_dof']} | "
            f"{step['residual_p_value']:.3g} | {step['bic']:.1f} |"
        )
    lines += [
        "",
        "The base step's statistic is the residual chi^2; an effect's is the score "
        "statistic that selected it.",
        "",
    ]
    for k, step in enumerate(steps):
        if not step["score_tests"]:
            continue
        lines += [
            f"## Score tests at step {k} ({step['effect'] or 'base model'})",
            "",
            "| candidate | statistic | dof | p-value | note |",
            "|---|---|---|---|---|",
        ]
        for test in sorted(step["score_tests"], key=lambda t: t["log10_p_value"]):
            lines.append(
                f"| {test['effect']} | {test['statistic']:.2f} | {test['dof']} | "
                f"{test['p_value']:.3g} | {test['note']} |"
            )
        lines.append("")
    for k, step in enumerate(steps[1:], start=1):
        effect = next(e for e in diagnosis.steps[k].fit.problem.effects if e.name == step["effect"])
        lines += [f"## Step {k}: {step['effect']}", "", f"Added term: {effect.equation}.", ""]
        names = set(effect.parameter_names) | set(diagnosis.steps[k].fit.problem.names)
        lines += _parameter_lines(step, names) + [""]
        if step["prediction"]:
            check = step["prediction"]
            lines.append(
                f"Left-out prediction chi^2 {sum(check['chi2_before']):.1f} -> "
                f"{sum(check['chi2_after']):.1f} (improvement {check['improvement']:.1f} "
                f"after charging nuisance parameters; over the dispersion "
                f"{check['dispersion_after']:.3g}, {check['scaled_improvement']:.1f} against "
                f"{check['chance']:.1f} by chance)."
            )
            if "rms_before_mm" in check:
                lines.append(
                    f"Left-out RMS {check['rms_before_mm'] * 1e3:.1f} -> "
                    f"{check['rms_after_mm'] * 1e3:.1f} um."
                )
            lines.append("")
    if document.get("rivals"):
        lines += ["## Explanations the design cannot tell apart", ""]
        for step in steps[1:]:
            lines += [
                f"- {step['effect']} (chi^2 drop {r['accepted_drop']:.1f}) or {r['effect']} "
                f"(chi^2 drop {r['chi2_drop']:.1f})"
                for r in step.get("rivals", [])
            ]
        lines.append("")
    if document.get("blind_spots"):
        lines += [
            "## What this design would likely miss",
            "",
            "Power of the last round's score test against each effect at a realistic size "
            "(linearised, at that round's Bonferroni level); below 0.8 the effect is not "
            "ruled out by a residual at the noise.",
            "",
            "| effect | realistic size | power there | detected with power 0.8 above |",
            "|---|---|---|---|",
        ]
        for spot in document["blind_spots"]:
            above = "-" if spot["detectable"] is None else f"{spot['detectable']:.3g}"
            lines.append(
                f"| {spot['effect']} | {spot['realistic']:g} {spot['unit']} | "
                f"{spot['power']:.2f} | {above} |"
            )
        lines.append("")
    if document.get("stand_ins"):
        lines += [
            "## Stand-ins",
            "",
            "Candidates that lowered the residual but are not causes: at a bound, implausible "
            "for tissue, or not predicting left-out data better than chance. None is selected.",
            "",
        ]
        lines += [f"- {s['effect']}: {s['reason']}" for s in document["stand_ins"]] + [""]
    if document["rejected"]:
        lines += ["## Candidates tried and rejected", ""]
        lines += [
            f"- {r['effect']}: {r['reason']}" for r in document["rejected"] if not r.get("stand_in")
        ] + [""]
    lines += ["## Residual maps", "", "![marker residuals before and after](residuals.png)", ""]
    return "\n".join(lines)
