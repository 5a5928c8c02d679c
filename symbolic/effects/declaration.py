"""How an effect declares its parameters and its realistic magnitude (docs/effects.md,
"The effects"): one ``Parameter`` row per parameter, one ``Magnitude``."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Parameter:
    """One parameter of an effect's theta (one case's block for a per-case effect).

    Attributes
    ----------
    name, unit : str
        Its name and unit.
    scale : float
        Typical magnitude: the unit of its internal coordinate.
    lower, upper : float
        Bounds in natural units; a lower bound of 0 makes the score test one-sided.
    plausible : tuple of float, optional
        The range a tissue (or a set-up) can have, where it is narrower than the bounds
        (which keep the fit well posed); a fit outside it is a stand-in
        (``solvers.diagnosis.standin``). None: the bounds.
    """

    name: str
    unit: str
    scale: float
    lower: float
    upper: float
    plausible: tuple[float, float] | None = None

    @property
    def plausible_range(self) -> tuple[float, float]:
        """``plausible``, or the bounds."""
        return self.plausible if self.plausible is not None else (self.lower, self.upper)


@dataclass(frozen=True)
class Magnitude:
    """A realistic size of the effect, for synthetic data (``Effect.true_parameters``).

    Attributes
    ----------
    value : float
        The magnitude.
    unit : str
        Its unit.
    direction : tuple of float, optional
        The pattern of theta the magnitude scales; None: 1 for every parameter.
    """

    value: float
    unit: str
    direction: tuple[float, ...] | None = None
