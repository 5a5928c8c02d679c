"""Synthetic datasets from the forehead phantom (``dvs simulate``).

The truth is the phantom model (``experiments.synthetic``). Markers are
material points of its skin; the dataset holds what a camera rig would
measure: marker positions before and under each load, with Gaussian noise,
markers hidden under the probe and a few missing at random. The geometry the
inverse sees is rebuilt from those markers, so a fit on a simulated dataset
also carries the (small) error of re-fitting the rest shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.dataset import Dataset
from experiments.synthetic import (
    TRUE_PARAMETERS,
    PhantomSettings,
    forehead_model,
    marker_uv,
    probe_loads,
)
from solvers.equilibrium import EquilibriumSolver


@dataclass(frozen=True)
class SimulationSettings:
    """What the synthetic measurement adds to the truth.

    Attributes
    ----------
    noise_mm : float
        Standard deviation of each marker coordinate [mm], rest and loaded.
    seed : int
        Random seed.
    missing_fraction : float
        Fraction of markers lost at random in each loaded capture.
    occlusion_radius_mm : float
        Markers closer than this to the contact are hidden by the probe [mm].
    """

    noise_mm: float = 0.02
    seed: int = 0
    missing_fraction: float = 0.03
    occlusion_radius_mm: float = 2.0

    def __post_init__(self) -> None:
        if self.noise_mm < 0:
            raise ValueError(f"noise must be >= 0 mm, got {self.noise_mm}")
        if not 0 <= self.missing_fraction < 0.5:
            raise ValueError("missing_fraction must lie in [0, 0.5)")


def simulate(
    phantom: PhantomSettings | None = None,
    measurement: SimulationSettings | None = None,
    parameters: dict[str, float] | None = None,
    model=None,
) -> Dataset:
    """A dataset v1 from the phantom (or from a given truth ``model``).

    Parameters
    ----------
    phantom : PhantomSettings
        Geometry, markers and forces.
    measurement : SimulationSettings
        Noise, missing markers, occlusion.
    parameters : dict, optional
        True parameters (default ``TRUE_PARAMETERS``).
    model : TissueModel, optional
        A ready truth model (for example one with an undeclared effect).
    """
    phantom = phantom or PhantomSettings()
    measurement = measurement or SimulationSettings()
    rng = np.random.default_rng(measurement.seed)
    truth = model or forehead_model(phantom, parameters or TRUE_PARAMETERS)
    uv = marker_uv(phantom)
    shape = phantom.markers
    outer = truth.volume.outer_params(uv)
    inner = np.column_stack([uv, np.zeros(len(uv))])
    markers = truth.volume.collocation(outer)
    rest = markers @ truth.rest
    solver = EquilibriumSolver(truth)
    loads = probe_loads(truth, phantom)
    loaded = []
    for load in loads:
        positions = solver.solve(truth.generalized_force(load)).positions
        observed = markers @ positions + rng.normal(0.0, measurement.noise_mm, rest.shape)
        contact = truth.volume.evaluate(truth.volume.outer_params(load.uv[None]))[0]
        hidden = np.linalg.norm(rest - contact, axis=1) < measurement.occlusion_radius_mm
        hidden |= rng.random(len(rest)) < measurement.missing_fraction
        observed[hidden] = np.nan
        loaded.append(observed.reshape(shape + (3,)))
    contacts = np.array(
        [truth.volume.evaluate(truth.volume.outer_params(ld.uv[None]))[0] for ld in loads]
    )
    radius = np.full(len(loads), phantom.probe_radius)
    return Dataset(
        outer_rest=(rest + rng.normal(0.0, measurement.noise_mm, rest.shape)).reshape(shape + (3,)),
        inner_rest=(truth.volume.collocation(inner) @ truth.rest).reshape(shape + (3,)),
        forces=np.array([ld.force for ld in loads]),
        contacts=contacts,
        outer_loaded=np.stack(loaded),
        noise_mm=float(measurement.noise_mm),
        probe_radius=radius,
    )
