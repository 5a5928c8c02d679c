"""The Truth Cube through the shared loop (``solvers.diagnosis.diagnose``).

As the real skin's extensometer (``experiments.realskin.setup``): a base
``InverseProblem`` whose load cases prescribe the plate (``FrameLoad``: no force, the
displacement d of each state) and observe the beads, its parameter nu (E fixed), and the
loop's candidate effects. The plate's translations are those of the full fit
(``experiments.truthcube.cubefit``), held fixed: the loop has no effect that moves
prescribed points. The noise level is the loop's own robust estimate from the base
residual (1.4826 median |r|): the lattice scatter (``cubemodel.lattice_scatter``) is bead
placement more than CT localisation, and no independent localisation noise is known.
"""

from __future__ import annotations

import numpy as np

from experiments.truthcube.cubefit import NU_BOUNDS
from experiments.truthcube.cubemodel import CubeData, load_cases
from solvers.diagnosis.guard import predict_left_out
from solvers.diagnosis.loop import diagnose
from solvers.diagnosis.record import DiagnosisSettings
from solvers.inverse.problem import InverseProblem
from solvers.inverse.space import ParameterSpace
from symbolic.loads import FrameLoad

CANDIDATES = {
    "linear-elastic": ("rigid_motion", "measurement_scale", "heterogeneity", "base_compliance"),
    "neo-hookean": ("rigid_motion", "measurement_scale", "nonlinear_stiffening"),
}
"""The effects that apply to the cube, by base energy (docs/effects.md, "The effects"):
a registration error of each CT scan (rigid motion per state), a scale error of each
scan, a stiffness gradient, a compliant base (the acrylic is rigid, so it should not
be found) and, on the neo-Hookean base, strain stiffening. The contact and probe
effects need a contact point, which the plate has not; the surroundings and layering
do not exist for a free-standing homogeneous cube."""


def base_problem(model, data: CubeData, translations: np.ndarray, nu0: float):
    """The base problem (nu estimated, E fixed) and its loads, one per state."""
    cases = load_cases(model, data, translations)
    space = ParameterSpace.create(("nu",), {"nu": nu0}, {"nu": NU_BOUNDS})
    base = InverseProblem(model, cases, space, noise_mm=None)
    return base, [FrameLoad(c.label) for c in cases]


def run_loop(model, data: CubeData, translations, nu0: float, max_effects: int = 3, log=print):
    """The loop on the cube: returns the ``Diagnosis``."""
    base, loads = base_problem(model, data, translations, nu0)
    settings = DiagnosisSettings(candidates=CANDIDATES[model.energy], max_effects=max_effects)
    return diagnose(base, loads, settings, lambda line: log(f"  {line}"))


def step_table(diagnosis) -> list[dict]:
    """Each model of the loop's sequence: its effect, nu, the RMS bead distance per state
    and over all [mm]."""
    rows = []
    for step in diagnosis.steps:
        problem = step.fit.problem
        errors = problem.point_errors(step.fit.residual)
        values = dict(zip(problem.labels, map(float, step.fit.p)))
        rows.append(
            {
                "effect": step.effect or "base",
                "nu": values.get("nu"),
                "parameters": values,
                "rms_mm": [float(np.sqrt(np.mean(e**2))) for e in errors],
                "rms_all_mm": step.fit.rms()[0],
            }
        )
    return rows


def final_left_out(diagnosis) -> list[float]:
    """The loop's final model, each state predicted from the other two (the shared
    guard's ``predict_left_out``: the model and its shared parameters refitted without
    the state, its per-scan parameters fitted on one half of its beads and predicting
    the other): the RMS bead distance of each state [mm]."""
    final = diagnosis.steps[-1].fit
    sigma = diagnosis.noise_mm
    out = []
    for position in final.problem.positions:
        chi2, _ = predict_left_out(final, [position], sigma)
        beads = final.problem.cases[position].n_observations
        out.append(float(sigma * np.sqrt(chi2 / beads)))
    return out
