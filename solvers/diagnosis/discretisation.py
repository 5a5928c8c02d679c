"""The discretisation error an effect must beat: what step 0's resolution check left.

Step 0 (``experiments.basemodel``) checks the chosen continuum on volumes whose knot
spans are r times smaller, and records the chi^2 distance between the predicted
markers of successive volumes, Delta_i = |W (u_(i+1) - u_i)|^2 / sigma^2
(``base_choice.resolution``, each record's ``prediction_chi2``). With a discretisation
error of the predicted markers that falls as e_h = C h^p, each change is
sqrt(Delta_i) = C h_i^p (1 - r^-p), and the error left on the volume adopted is

    e = sqrt(Delta) / (1 - r^-p)    the coarser volume of a converged check,   (D1a)
    e = sqrt(Delta) / (r^p - 1)     the finer volume of the last refinement,    (D1b)

D = e^2 in chi^2 units. The order p comes from two successive changes,
r^p = sqrt(Delta_1 / Delta_2) (D2), within [1, 4]; from one change it is taken as 1,
the order of a concentrated load's near field and the slowest the checks have shown.

An effect can absorb at most the error the model leaves. One whose left-out gain G
(eq. G1) is no larger than D may be fitting the volume's own error, which is common to
every left-out contact and so passes (G3) as if it were physics; it is a stand-in for
the discretisation (docs/diagnosis.md, "The selection rule"):

    G > D.                                                                  (D3)
"""

from __future__ import annotations

import numpy as np

MIN_ORDER, MAX_ORDER = 1.0, 4.0
"""The range of the order p of (D2); 1 where it cannot be measured."""


def remaining_error(records: list[dict], factor: float) -> dict:
    """D of eq. (D1) from step 0's resolution records.

    Parameters
    ----------
    records : list of dict
        ``base_choice.resolution``: each check's ``verdict`` ("converged", "refined" or
        "not checked") and, when checked, ``prediction_chi2`` (Delta).
    factor : float
        r, the factor by which each check divides the knot span.

    Returns
    -------
    dict
        ``chi2`` (D, chi^2 units; 0 when nothing was checked), ``order`` (p), ``how``
        ("measured" from two changes, "assumed" from one, or "not estimated").
    """
    changes = [float(r["prediction_chi2"]) for r in records if "prediction_chi2" in r]
    if not changes:
        return {"chi2": 0.0, "order": None, "how": "not estimated"}
    order, how = MIN_ORDER, "assumed"
    if len(changes) >= 2 and changes[-1] > 0.0:
        ratio = np.sqrt(changes[-2] / changes[-1])
        order = float(np.clip(np.log(max(ratio, 1.0)) / np.log(factor), MIN_ORDER, MAX_ORDER))
        how = "measured"
    checked = [r for r in records if "prediction_chi2" in r]
    shrink = factor**order
    if checked[-1]["verdict"] == "converged":  # the coarser volume is kept (D1a)
        scale = 1.0 - 1.0 / shrink
    else:  # the finer volume is adopted (D1b)
        scale = shrink - 1.0
    return {"chi2": changes[-1] / scale**2, "order": order, "how": how}


def discretisation_reason(check, remaining: float) -> str | None:
    """Why an effect that predicts left-out data better than chance is still a stand-in
    for the discretisation (D3), or None. ``check`` is its ``PredictionCheck``."""
    if check is None or remaining <= 0.0 or check.improvement > remaining:
        return None
    return (
        f"its left-out gain G {check.improvement:.1f} is within the discretisation error "
        f"step 0's resolution check left (chi2 {remaining:.1f}, eq. D3): it may fit the "
        "volume's own error"
    )
