"""The small FE tissue patch of the step-0 tests (``experiments.phantom.tissue``, Q2
hexahedra): 4 mm thick, clamped 4 mm beyond the markers, 3 mm cells in 3 layers, 8 loads
at four contacts, so that a step 0 takes seconds."""

from __future__ import annotations


def patch_dataset(marked, markers, radius: float, probe: str = "disc", seed: int = 3):
    """The dataset of the patch over a ``marked`` area (x, y) [mm] with ``markers`` (U, V)
    markers, pressed by a probe of ``radius`` [mm] and shape ``probe`` whose radius the
    dataset does not declare; 0.02 mm marker noise drawn with ``seed``."""
    from experiments.phantom.simulate import SimulationSettings
    from experiments.phantom.tissue import TissuePatch, tissue_cases, tissue_dataset

    patch = TissuePatch(
        marked=marked,
        extent_mm=4.0,
        thickness=4.0,
        poisson=0.45,
        support="clamped",
        layers=3,
        spacing_mm=3.0,
    )
    forces, contacts = tissue_cases("corners", patch)
    measurement = SimulationSettings(noise_mm=0.02, seed=seed)
    return tissue_dataset(patch, forces, contacts, radius, markers, probe, measurement=measurement)
