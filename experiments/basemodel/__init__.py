"""Step 0 of the loop: the base model, its surroundings and its resolution, from the data.

``choice`` decides (``choose_base``); ``family`` fits the continuum over the
surroundings it searches; ``resolution`` checks the chosen volume on finer ones.
docs/stepzero.md gives the rules and numbers.
"""

from experiments.basemodel.choice import BaseChoice, choose_base
from experiments.basemodel.family import MARGINS_MM, SUPPORTS, Surroundings, Trial

__all__ = ["BaseChoice", "MARGINS_MM", "SUPPORTS", "Surroundings", "Trial", "choose_base"]
