"""Do the design's predictions hold? Monte Carlo over noisy simulations of one design.

On the phantom (``experiments.phantom.simulate.simulate_with_effects``) with a named
design, the predictions of ``solvers.design.information`` are made once, from the
noise-free data, and compared with what happens over ``n`` noisy simulations (seeds
1..n, no markers lost at random, so that every simulation has the same design):

- the standard errors of eq. (D1) against the spread (sample standard deviation) of
  the base parameters fitted to data without effects;
- the power of eq. (D3) against the rejection rate of the loop's score test at the
  same level, on data with the effect at the stated magnitude.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from solvers.design.information import effect_power, fisher_information

NOISE_MM = 0.02
"""Marker noise of the simulations [mm] (the project's phantom default)."""


def phantom_dataset(effects: dict, seed: int, design: str, noise_mm: float):
    """A phantom dataset of a design (a name, or a ``design.json`` of ``dvs design``) with
    ``effects`` at ``noise_mm`` [mm] (0: noise free), declaring ``NOISE_MM`` so that every
    one is whitened alike; no random losses."""
    from experiments.phantom.designs import design_options
    from experiments.phantom.simulate import simulate_with_effects

    data = simulate_with_effects(
        effects, noise_mm=noise_mm, seed=seed, missing_fraction=0.0, **design_options(design)
    )
    return dataclasses.replace(data, noise_mm=NOISE_MM)


def base_fit(dataset, grid=None, base=None):
    """The loop's base fit (``solvers.diagnosis.fit``) of a dataset; ``base`` is the base
    model's ``FitSettings`` (default ``base_settings(grid)``: the paper's energy)."""
    from experiments.diagnosis.diagnose import base_settings
    from experiments.problem.fitting import build_problem, dataset_loads
    from solvers.diagnosis.extended import ExtendedProblem
    from solvers.diagnosis.fit import fit

    problem = build_problem(dataset, base or base_settings(grid))
    loads = dataset_loads(dataset, problem.model.volume)
    return fit(ExtendedProblem(problem, loads, []))


def calibrate(
    design: str = "diagnosis",
    effects: dict | None = None,
    n: int = 200,
    level: float = 0.01,
    log=print,
) -> dict:
    """Predicted against observed, for the base parameters and each effect.

    Parameters
    ----------
    effects : dict
        Effect name -> magnitude; each is simulated alone, ``n`` times.

    Returns
    -------
    dict
        ``parameters``: per base parameter the predicted standard error, the observed
        spread and their ratio; ``effects``: per effect the predicted power and
        non-centrality and the observed rejection rate; ``seconds``.
    """
    from solvers.diagnosis.stats import score_test
    from symbolic.effects.library import make_effect

    begin = time.perf_counter()
    clean = base_fit(phantom_dataset({}, 0, design, 0.0))
    labels, information = fisher_information(clean, NOISE_MM)
    predicted = np.sqrt(np.diag(np.linalg.inv(information)))
    estimates = []
    for seed in range(1, n + 1):
        estimates.append(base_fit(phantom_dataset({}, seed, design, NOISE_MM)).p[clean.estimated()])
    spread = np.std(np.array(estimates), axis=0, ddof=1)
    out = {
        "design": design,
        "n": n,
        "level": level,
        "parameters": {
            name: {"predicted_std": float(p), "observed_std": float(o), "ratio": float(o / p)}
            for name, p, o in zip(labels, predicted, spread)
        },
        "effects": {},
    }
    log(f"  {design}: base parameters over {n} simulations: {out['parameters']}")
    for name, magnitude in (effects or {}).items():
        effect = make_effect(name)
        prediction = effect_power(clean, effect, magnitude, NOISE_MM, level)
        rejected = 0
        for seed in range(1, n + 1):
            fitted = base_fit(phantom_dataset({name: magnitude}, seed, design, NOISE_MM))
            rejected += score_test(fitted, make_effect(name), NOISE_MM).p_value < level
        out["effects"][name] = {
            "magnitude": magnitude,
            "noncentrality": prediction.noncentrality,
            "dof": prediction.dof,
            "one_sided": prediction.one_sided,
            "predicted_power": prediction.power,
            "observed_rate": rejected / n,
        }
        log(f"  {name} at {magnitude:g}: {out['effects'][name]}")
    out["seconds"] = time.perf_counter() - begin
    return out
