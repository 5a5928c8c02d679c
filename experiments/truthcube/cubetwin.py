"""A synthetic twin of the Truth Cube: scikit-fem beads at a known nu and plate contact.

The twin is the cube experiment with everything known (docs/truthcube.md, "Results",
"Synthetic twin"): the same 80 mm cube in the model frame of the real data
(``cubemodel.CubeFrame``), bonded to its base, linear elasticity by scikit-fem's
quadratic tetrahedra (``cubechecks.FemCube``: another discretisation than the spline's),
Poisson's ratio ``TWIN_NU`` (not the value the real beads give), the plate moved straight
down by each state's nominal travel, and one of two planted plate contacts:

- **bonded**: every displacement component of the top face prescribed;
- **frictionless**: only the vertical one, the face slides freely.

The beads are the real cube's rest beads; their displacements are the FE solution
interpolated there (``FemCube.at``). Every located coordinate, at rest and in each
state, gets independent Gaussian noise of the real beads' location noise per component,
the rest lattice's scatter about a quadratic map of the bead index
(``cubemodel.lattice_scatter``, as ``cubestudy.noise_record``): the twin's rest beads are
measured with noise like the real ones. The result is a ``TruthCube``, which the study
takes as it takes the real one.

``twin_study`` runs the study's contact decision (``cubefolds.contact_study``: both
contacts fitted and left out state by state) on each twin: the contact named must be
the planted one (a frictionless plate is the study's "slip": the face's lateral stretch
b is its stand-in, ``cubefit``), and nu must come back.
"""

from __future__ import annotations

import time

import numpy as np

from experiments.data.truthcube import TruthCube
from experiments.truthcube.cubechecks import FemCube
from experiments.truthcube.cubefit import CubeSolver, fit_cube
from experiments.truthcube.cubefolds import contact_study
from experiments.truthcube.cubemodel import (
    CubeData,
    CubeFrame,
    CubeSettings,
    cube_model,
    lattice_scatter,
)

TWIN_NU = 0.47
"""Poisson's ratio planted in the twins [1] (the real beads give 0.48-0.50)."""
TWIN_CONTACTS = {"bonded": "bonded", "frictionless": "slip"}
"""Planted contact (``cubechecks.FEM_CONTACTS``) -> the study's contact that must be
named for it (``cubefolds.CONTACTS``)."""
TWIN_CELLS = 8
"""Hexahedral cells per edge of the twin's scikit-fem mesh (each cut into P2 tetrahedra)."""
TWIN_SEED = 2
"""Seed of the twin's noise."""


def twin_cube(
    cube: TruthCube,
    contact: str,
    nu: float = TWIN_NU,
    cells: int = TWIN_CELLS,
    seed: int = TWIN_SEED,
    noise_mm: np.ndarray | None = None,
) -> TruthCube:
    """The twin of ``cube`` with a planted contact (module docstring).

    Parameters
    ----------
    cube : TruthCube
        The real cube: its bead index, rest beads, compressions and lattice scatter.
    contact : {"bonded", "frictionless"}
        The planted plate contact (``TWIN_CONTACTS``).
    nu : float
        The planted Poisson's ratio [1].
    cells : int
        Hexahedral cells per edge of the FE mesh.
    seed : int
        Seed of the noise.
    noise_mm : numpy.ndarray, optional
        (3,) standard deviation of the noise per file-frame component [mm]; default the
        rest lattice's scatter about a quadratic map of the bead index; 0: none.

    Returns
    -------
    TruthCube
        The twin's beads in the file frame [mm].
    """
    if contact not in TWIN_CONTACTS:
        raise ValueError(f"contact must be one of {sorted(TWIN_CONTACTS)}, got {contact!r}")
    frame = CubeFrame.from_lattice(cube.rest)
    if noise_mm is None:
        noise_mm = lattice_scatter(cube.index, cube.rest, order=2)
    sigma = np.broadcast_to(np.asarray(noise_mm, dtype=float), (3,))
    rng = np.random.default_rng(seed)
    fem = FemCube(cells, nu, frame.edge, contact)
    at = frame.to_model(cube.rest)
    loaded = []
    for travel in cube.plate_travel_mm():
        moved = fem.at(fem.displacement(np.array([0.0, 0.0, -travel])), at)
        loaded.append(cube.rest + frame.to_file(moved) + rng.normal(0.0, sigma, at.shape))
    rest = cube.rest + rng.normal(0.0, sigma, at.shape)
    return TruthCube(cube.index.copy(), rest, np.array(loaded), tuple(cube.compression))


def twin_study(
    cube: TruthCube,
    settings: CubeSettings,
    energy: str = "linear",
    cells: int = TWIN_CELLS,
    nu: float = TWIN_NU,
    seed: int = TWIN_SEED,
    log=print,
) -> list[dict]:
    """The study's contact decision on both twins of ``cube`` (module docstring).

    Per twin: the planted contact and the one expected, the decision
    (``cubefolds.decide_contact``), nu and its standard error of both contacts' fits,
    nu and the RMS bead distance per state [mm] of the named contact fitted to the
    noise-free twin (the spline model's own bias and misfit against the FE beads), the
    noise used [mm] and the seconds taken.
    """
    noise = lattice_scatter(cube.index, cube.rest, order=2)
    records = []
    for planted, expected in TWIN_CONTACTS.items():
        begin = time.perf_counter()
        log(f"twin, {planted} plate, nu {nu}:")
        data = CubeData.of(twin_cube(cube, planted, nu, cells, seed, noise))
        fits, decision = contact_study(settings, energy, data, lambda line: log(f"  {line}"))
        clean = CubeData.of(twin_cube(cube, planted, nu, cells, seed, 0.0))
        slip = decision["named"] == "slip"
        noise_free = fit_cube(CubeSolver(cube_model(settings, energy), clean, slip=slip), nu0=0.45)
        records.append(
            {
                "planted": planted,
                "expected": expected,
                "nu_planted": nu,
                "energy": energy,
                "cells": cells,
                "seed": seed,
                "noise_mm": noise.tolist(),
                "decision": decision,
                "fits": {
                    f["contact"]: {"nu": f["nu"], "nu_se": f["nu_se"], "rms_mm": f["rms_mm"]}
                    for f in fits
                },
                "nu_noise_free": noise_free.nu,
                "rms_noise_free_mm": noise_free.rms_mm,
                "seconds": time.perf_counter() - begin,
            }
        )
        named = fits[0] if decision["named"] == "bonded" else fits[1]
        log(
            f"  named {decision['named']} (planted {planted}): nu {named['nu']:.4f} +- "
            f"{named['nu_se']:.4f}, noise-free {noise_free.nu:.4f}"
        )
    return records
