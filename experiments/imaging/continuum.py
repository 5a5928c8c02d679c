"""The continuum ``dvs image`` images on by default: step 0's (docs/cli.md, ``dvs image``).

A map of E needs the linear-elastic continuum. With ``--energy auto`` (the default)
``dvs image`` runs step 0 as ``dvs fit`` and ``dvs diagnose`` do
(``experiments.basemodel.choose_base``) and takes, in this order:

1. **the continuum step 0 chose** (``source`` "step 0"): its volume, degrees, band of
   tissue beyond the markers, support, probe radius and checked resolution, the model
   fit and diagnose use;
2. when step 0 keeps the paper's energy after trying the continuum (the BIC prefers the
   paper's), **the best continuum of step 0's search** ("step 0's best continuum"),
   refitted on the starting volume and checked by step 0's resolution rule, as step 0
   treats a continuum it chooses;
3. when the paper's energy fits at the noise, so that step 0 never tried the continuum,
   **step 0's search of the continuum's surroundings run here** ("continuum search"),
   then the same check.

In cases 2 and 3 the map is of a model the data do not prefer: one line says so and
image.json records it (``model.source``, ``model.note``). ``continuum_search`` runs the
search of ``choose_base`` (``search_surroundings``) on its volumes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from experiments.basemodel.choice import search_surroundings
from experiments.basemodel.family import (
    MARGINS_MM,
    SEARCH_SPAN_OF_SPACING,
    SUPPORTS,
    Family,
    starting_resolution,
    with_radius,
)

SOURCES = ("step 0", "step 0's best continuum", "continuum search", "options")
"""``model.source`` of image.json: where the imaged continuum came from."""


@dataclass
class ImagingModel:
    """The continuum a map is made on, and where it came from.

    Only the imaged trial is kept: step 0's other trials (their built volumes) are
    released once its record is made, before the map's own solves.

    Attributes
    ----------
    base_choice : dict
        Step 0's record (``BaseChoice.record``, image.json's ``base_choice``).
    trial : Trial
        The fitted continuum imaged on.
    source : str
        One of ``SOURCES``.
    resolution : list of dict
        The checks of the volume's resolution (step 0's records).
    note : str
        Why this continuum, in words ('' when step 0 chose it; ``fallback_note``).
    seconds : float
        Wall time beyond step 0 (the search and the checks) [s].
    """

    base_choice: dict
    trial: object
    source: str
    resolution: list
    note: str = ""
    seconds: float = 0.0

    def dataset(self, dataset):
        """The dataset with the continuum's probe radius (step 0's estimate, if any)."""
        s = self.trial.surroundings
        return with_radius(dataset, s.radius_mm, s.shape)

    def settings(self):
        """The continuum's ``FitSettings``, started at its estimate."""
        fitted = self.trial.fit
        start = dict(zip(fitted.problem.names, map(float, fitted.p)))
        return replace(self.trial.settings, names=("E", "nu"), start=start)

    def problem(self):
        """The homogeneous problem, on the model step 0 built, started at its estimate."""
        from solvers.inverse.space import ParameterSpace

        base = self.trial.fit.problem.base
        settings = self.settings()
        return replace(base, space=ParameterSpace.create(settings.names, settings.start))

    def line(self) -> str:
        """One line naming the imaged volume and why (printed after step 0's own line
        when the map is not of step 0's choice)."""
        settings = self.trial.settings
        grid, degrees = ("x".join(map(str, v)) for v in (settings.grid, settings.degrees))
        text = f"imaging on linear-elastic, grid {grid}, degrees {degrees}"
        reason = self.note or "step 0's choice"
        return f"{text}, {self.trial.surroundings.label()} ({reason})"


def fallback_note(choice, source: str) -> str:
    """Why the map is of ``source``'s continuum when step 0 kept the paper's energy."""
    if source == SOURCES[1]:
        return (
            f"step 0 keeps the paper's energy (BIC {choice.paper.bic:.0f} against the "
            f"continuum's {choice.continuum.bic:.0f}); the map is of the best continuum it tried"
        )
    if source == SOURCES[2]:
        return (
            "step 0 keeps the paper's energy, which fits at the noise, and did not try the "
            "continuum; the map is of the continuum step 0's search finds here"
        )
    return ""


def imaging_model(dataset, level: float = 0.01, log=print) -> ImagingModel:
    """Step 0, then the continuum to image on (module docstring); prints step 0's lines,
    its one line and, when the map is not of step 0's choice, one line saying so."""
    import gc

    from experiments.fit.stepzero import run_step0
    from solvers.linalg.blas import one_thread

    choice = run_step0(dataset, level, log)
    record = choice.record()
    if choice.chosen is choice.continuum:
        model = ImagingModel(record, choice.chosen, SOURCES[0], list(choice.resolution))
    else:
        begin = time.perf_counter()
        trial, source = choice.continuum, SOURCES[1]
        with one_thread():  # as step 0's own fits
            if trial is None:
                trial, source = continuum_search(dataset, choice.sigma, log), SOURCES[2]
            trial, resolution = checked_continuum(dataset, trial, choice.sigma, level, log)
        note = fallback_note(choice, source)
        model = ImagingModel(record, trial, source, resolution, note, time.perf_counter() - begin)
        log(f"  {model.line()}")
    del choice
    gc.collect()  # the other trials' volumes (trials and families refer to each other)
    return model


def continuum_search(dataset, sigma: float, log=print):
    """The best continuum over step 0's surroundings, searched as ``choose_base`` does
    (``search_surroundings`` from a 5 mm free band, on the search's volumes)."""
    span, layers = starting_resolution(dataset, SEARCH_SPAN_OF_SPACING)
    family = Family(dataset, span, layers, sigma, lambda line: log(f"  continuum: {line}"))
    return search_surroundings(family, MARGINS_MM[1], SUPPORTS[0])


def checked_continuum(dataset, trial, sigma: float, level: float, log=print):
    """``trial`` refitted on step 0's starting volume and checked by its resolution rule
    and its probe's shape (``experiments.basemodel.choice``), as step 0 treats a
    continuum it chooses: the resolved trial and the resolution checks."""
    from experiments.basemodel.choice import checked_shape
    from experiments.basemodel.resolution import checked_resolution

    span, layers = starting_resolution(dataset)
    start = Family(dataset, span, layers, sigma, lambda *_: None)
    begun = start.trial_at(trial.surroundings, trial.fit.p)

    def prefixed(line):
        log(f"  continuum: {line}")

    resolved, checks = checked_resolution(dataset, start, begun, sigma, level, prefixed)
    return checked_shape(resolved, level, prefixed)[0], checks
