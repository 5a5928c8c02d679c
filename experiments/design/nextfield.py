"""``dvs next --target field``: the next press for a map of Young's modulus
(docs/imaging.md, "Adaptive imaging").

The question is the one of the imaging acceptance: is there an inclusion of a stated size
and contrast anywhere over the marked area, and where?

1. The continuum ``dvs image`` maps on: step 0's (``experiments.imaging.continuum``), its
   homogeneous fit (E_ref and the held nu).
2. The candidates: an n x n grid of contacts over the marked area
   (``solvers.design.candidates.contact_grid``), each pressed along the inward normal
   with the largest force of the safe range, with the dataset's probe; each hides the
   markers the dataset's own rule hides (``occlusion_radius``).
3. The dataset's presses and the candidates as one field problem linearised at the
   homogeneous fit, its rows kept per press (``solvers.imaging.fielddesign.PressRows``): the
   posterior of the inclusion's place from the data (eq. I12), the stop (eq. I14), or the
   candidate of eq. (I13).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class FieldTarget:
    """The inclusion to find and the loop's choices.

    Attributes
    ----------
    diameter_mm, ratio : float
        The inclusion's size [mm] and stiffness ratio (the imaging benchmark's 8 mm, 2x).
    shape : tuple of int
        Nodes of the surface field (``symbolic.field.StiffnessField``).
    contacts : int
        Candidate contacts per side of the grid over the marked area.
    force_n : float
        The candidates' force [N] (along the inward normal).
    goal, precision : float
        Eq. (I14): the posterior mass within 3 mm of the mode, and the standard error of
        the inclusion's amplitude in units of its log-contrast, that stop the loop.
    """

    diameter_mm: float = 8.0
    ratio: float = 2.0
    shape: tuple = (16, 16)
    contacts: int = 7
    force_n: float = 0.25
    goal: float = 0.9
    precision: float = 0.1

    def __post_init__(self) -> None:
        if not 0 < self.diameter_mm <= 40:
            raise ValueError(
                f"--inclusion must be a diameter in (0, 40] mm, got {self.diameter_mm}"
            )
        if not 1 < self.ratio <= 20:
            raise ValueError(f"--ratio must lie in (1, 20], got {self.ratio}")


LOCALISED_MM = 3.0
"""The radius of eq. (I14)'s posterior mass [mm]."""


def candidates(model, dataset, target: FieldTarget):
    """The candidate presses (normal, ``target.force_n``, the dataset's probe), their
    contacts on the rest skin [mm] and the markers each leaves visible."""
    from solvers.design.candidates import (
        candidate_presses,
        contact_grid,
        contact_point,
        hidden_markers,
        occlusion_radius,
    )

    rest = dataset.outer_rest.reshape(-1, 3)
    marker_uv, _ = model.volume.project_to_outer(rest)
    seen = np.isfinite(dataset.outer_loaded.reshape(dataset.n_loads, -1, 3)).all(axis=2)
    hide = occlusion_radius(rest, dataset.contacts, seen)
    probe = 0.0 if dataset.probe_radius is None else float(np.median(dataset.probe_radius))
    presses = candidate_presses(
        model,
        contact_grid(marker_uv, target.contacts),
        (target.force_n,),
        0.0,
        0,
        probe,
        dataset.probe_shape or "gauss",
    )
    points = np.array([contact_point(model, p.uv) for p in presses])
    visible = [~hidden_markers(rest, point, hide) for point in points]
    return presses, points, visible


def with_candidates(dataset, presses, points, visible):
    """The dataset with every candidate appended as a load case whose markers sit at
    rest (placeholders: only its sensitivities are used) where visible, NaN where hidden."""
    rest = dataset.outer_rest
    loaded = np.repeat(rest[None], len(presses), axis=0)
    for k, mask in enumerate(visible):
        loaded[k].reshape(-1, 3)[~mask] = np.nan
    radius = [p.probe_radius for p in presses]
    return replace(
        dataset,
        forces=np.vstack([dataset.forces, [p.force for p in presses]]),
        contacts=np.vstack([dataset.contacts, points]),
        outer_loaded=np.concatenate([dataset.outer_loaded, loaded]),
        probe_radius=None
        if dataset.probe_radius is None
        else np.concatenate([dataset.probe_radius, radius]),
    )


def field_step(dataset, target: FieldTarget, budget: int, log=print) -> dict:
    """Step 0, the homogeneous fit, the posterior and the next press, or why to stop."""
    from experiments.design.plan import press_document
    from experiments.fit.stepzero import model_record
    from experiments.imaging.continuum import imaging_model
    from experiments.problem.fitting import build_problem, solve
    from solvers.imaging.fielddesign import (
        PlacePosterior,
        PressRows,
        inclusion_templates,
        press_scores,
    )
    from solvers.imaging.fieldproblem import FieldProblem
    from symbolic.field import StiffnessField

    begin = time.perf_counter()
    chosen_model = imaging_model(dataset, log=log)
    dataset = chosen_model.dataset(dataset)
    settings = chosen_model.settings()
    problem = chosen_model.problem()
    fit = solve(problem, "nested")
    young, poisson = (float(v) for v in fit.x)
    model = problem.model
    presses, points, visible = candidates(model, dataset, target)
    augmented = with_candidates(dataset, presses, points, visible)
    field = StiffnessField(tuple(target.shape), "surface")
    fp = FieldProblem(build_problem(augmented, settings), field, young, poisson)
    zero = np.zeros(field.size)
    rows = PressRows.split(
        fp, fp.sensitivities(zero), fp.poisson_sensitivity(zero), fp.residual(zero)
    )
    log(
        f"  homogeneous E {young:.4g} kPa, nu {poisson:.4f}; sensitivities of "
        f"{dataset.n_loads} presses and {len(presses)} candidates "
        f"({time.perf_counter() - begin:.0f} s)"
    )
    xy = np.asarray(model.volume.collocation(field.nodes()) @ model.rest)[:, :2]
    rest_xy = dataset.outer_rest.reshape(-1, 3)[:, :2]
    over = np.all((xy >= rest_xy.min(axis=0)) & (xy <= rest_xy.max(axis=0)), axis=1)
    places = xy[over]
    templates = inclusion_templates(xy, places, target.diameter_mm / 2, np.log(target.ratio))
    own = list(range(dataset.n_loads))
    J, y, _ = rows.select(own)
    posterior = PlacePosterior.of(J, y, templates, places)
    mode = int(np.argmax(posterior.probability))
    information = float(np.sum((J @ templates[:, mode]) ** 2))
    known = posterior.known(J, templates, LOCALISED_MM, target.goal, target.precision)
    question = (
        f"image an inclusion of {target.diameter_mm:g} mm, {target.ratio:g}x as stiff, "
        "anywhere over the marked area"
    )
    row = {
        "presses": dataset.n_loads,
        "question": question,
        "posterior": {
            "mode_mm": [float(v) for v in posterior.mode()],
            "localised": posterior.localised(LOCALISED_MM),
            "no_inclusion": posterior.none,
            "information": information,
            "needed": target.precision**-2,
            "places_mm": places.tolist(),
            "probability": posterior.probability.tolist(),
        },
        "stop": None,
        "press": None,
        "model": {
            **model_record(model, settings.margin, dataset),
            "E_ref_kPa": young,
            "nu": poisson,
            "source": chosen_model.source,
        },
        "base_choice": chosen_model.base_choice,
    }
    if known:
        row["stop"] = "no inclusion" if posterior.none >= target.goal else "inclusion known"
    elif budget <= 0:
        row["stop"] = "budget spent"
    else:
        weights = posterior.probability / posterior.probability.sum()
        pool = list(range(dataset.n_loads, len(rows)))
        scores = press_scores(rows, own, pool, templates, weights)
        best = pool[int(np.argmax(scores))]
        after = float(np.sum((rows.select(own + [best])[0] @ templates[:, mode]) ** 2))
        row["press"] = {
            **press_document(model, presses[best - dataset.n_loads]),
            "answers": question,
            "information_before": information,
            "information_after": after,
            "progress": float(np.max(scores)),
        }
    row["seconds"] = time.perf_counter() - begin
    return row


def field_document(row: dict, target: FieldTarget, args) -> dict:
    """``next.json`` of ``--target field`` (docs/formats.md): a ``dvs-design/1`` file whose
    ``presses`` hold the proposal, with the posterior of the inclusion's place."""
    from experiments.design.nextjson import next_header, next_why

    posterior = row["posterior"]
    return {
        **next_header(row, args, "field"),
        "why": next_why(row["press"], "information", needed=posterior["needed"]),
        "inclusion": {
            "diameter_mm": target.diameter_mm,
            "ratio": target.ratio,
            "goal": target.goal,
            "precision": target.precision,
        },
        "posterior": posterior,
        "model": row["model"],
        "base_choice": row["base_choice"],
        "candidates": {"contacts": target.contacts, "tilt_deg": 0.0, "forces_N": [target.force_n]},
        "diagnosis_s": row["seconds"],
    }


def field_report(document: dict, headline: str) -> str:
    """report.md of ``--target field``."""
    posterior = document["posterior"]
    x, y = posterior["mode_mm"]
    lines = [
        "# The next press for the stiffness map (`dvs next --target field`)",
        "",
        f"**{headline}.**",
        "",
        f"Question: is there an inclusion of {document['inclusion']['diameter_mm']:g} mm, "
        f"{document['inclusion']['ratio']:g}x as stiff, over the marked area, and where? "
        f"Data so far: {document['presses_so_far']} presses, {document['budget']} allowed "
        "from here.",
        "",
        f"- No inclusion: probability {posterior['no_inclusion']:.3f}.",
        f"- The most probable place: ({x:.1f}, {y:.1f}) mm; probability within 3 mm of it "
        f"{posterior['localised']:.3f} (goal {document['inclusion']['goal']:g}).",
        f"- The inclusion's signal there: lambda = {posterior['information']:.3g}, its "
        f"amplitude known to {posterior['information'] ** -0.5:.2f} of the target's "
        f"log-contrast (stop at {document['inclusion']['precision']:g}, lambda "
        f">= {posterior['needed']:.3g}).",
    ]
    if document["why"] is not None:
        why = document["why"]
        lines.append(
            f"- The proposed press raises lambda there from {why['information_before']:.3g} "
            f"to {why['information_after']:.3g} (predicted); eq. (I13) rises by "
            f"{why['progress']:.3g}."
        )
    return "\n".join(lines) + "\n"


def plot_field(path, document: dict, dataset, headline: str) -> None:
    """The posterior of the inclusion's place over the marked area, the presses so far
    and the proposed one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig

    posterior = document["posterior"]
    places = np.array(posterior["places_mm"])
    fig, ax = plt.subplots(figsize=(7.2, 6.0), layout="constrained")
    image = ax.scatter(
        places[:, 0], places[:, 1], c=posterior["probability"], s=140, marker="s", cmap="magma_r"
    )
    fig.colorbar(image, ax=ax, label="probability of the inclusion's place (eq. I12)")
    rest = dataset.outer_rest.reshape(-1, 3)
    ax.scatter(rest[:, 0], rest[:, 1], s=5, color="0.6", label="markers")
    ax.plot(*dataset.contacts[:, :2].T, "kx", ms=9, mew=2, label="presses so far")
    for press in document["presses"]:
        ax.plot(*press["contact_mm"][:2], "o", color="tab:green", ms=11, label="next press")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.legend(loc="upper left", fontsize=8, framealpha=0.8)
    x, y = posterior["mode_mm"]
    ax.set_title(
        f"{headline.split(', for ')[0]}\nno inclusion: {posterior['no_inclusion']:.2f}; most "
        f"probable place ({x:.1f}, {y:.1f}) mm, {posterior['localised']:.2f} within 3 mm",
        fontsize=9,
    )
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
