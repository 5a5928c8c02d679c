"""From a dataset to a regularised map of Young's modulus (docs/imaging.md).

1. Fit the homogeneous linear-elastic model (E, nu) by the nested method; its E is
   E_ref of eq. (I1) and its nu is held.
2. Estimate the field s = log(E / E_ref) (eq. I8) with the weight chosen by
   Morozov's principle (default), generalised cross-validation, the L-curve, or given.
3. The Laplace approximation around the estimate: standard deviations (marginal
   over the held nu, eq. I9) and the effective number of parameters.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from experiments.data.dataset import Dataset
from experiments.imaging.fieldchoice import describe, field_choice
from experiments.problem.fitting import FitSettings, build_problem, solve
from solvers.imaging.estimate import SOLVERS
from solvers.imaging.fieldproblem import FieldProblem
from solvers.imaging.laplace import Laplace, laplace
from solvers.imaging.regularization import Tikhonov, TotalVariation
from solvers.imaging.weight import WeightChoice, discrepancy_weight, gcv_weight, lcurve_weight
from symbolic.field import StiffnessField, tissue_lengths

REGULARIZERS = {"h1": Tikhonov, "tv": TotalVariation}
"""``--regularizer`` -> class (solvers/imaging/regularization.py)."""

DENSE_LAPLACE_MAX_N = 400
"""Up to this N the Laplace approximation forms J; above it, low rank (``LOW_RANK``)."""

LOW_RANK = 100
"""Eigenpairs of the low-rank Laplace approximation."""

AUTO_SENSITIVITY_MAX_N = 1024
"""``--method auto``: nested-sensitivity up to this N, nested-adjoint above. The formed
sensitivity was the fastest at every N measured, 16-1024 on 9x9x2 and 17x17x3
(docs/inverse.md, "Stiffness imaging: which method"); above 1024 its N columns per
case are unmeasured, and the adjoint never forms them."""


@dataclass(frozen=True)
class ImageSettings:
    """What ``dvs image`` does (lengths in mm).

    Attributes
    ----------
    shape : tuple of int or "auto"
        Nodes of the field: (M, N) for ``over="surface"``, (M, N, L) otherwise; "auto":
        chosen from the markers and the volume (``experiments.imaging.fieldchoice``).
    over : {"surface", "layers", "volume"}
        Layout of the field (``symbolic.field.StiffnessField``).
    regularizer : {"h1", "tv"}
    weight : str or float
        "morozov", "gcv", "lcurve", or beta [mm^2].
    method : str
        A key of ``solvers.imaging.estimate.SOLVERS``, or "auto".
    fit : FitSettings
        The model: grid, degrees, margin (energy linear-elastic).
    """

    shape: tuple | str = "auto"
    over: str = "surface"
    regularizer: str = "h1"
    weight: str | float = "gcv"
    method: str = "auto"
    fit: FitSettings = field(
        default_factory=lambda: FitSettings(names=("E", "nu"), energy="linear-elastic")
    )

    def solver_name(self, size: int) -> str:
        """The method used for a field of ``size`` coefficients."""
        if self.method != "auto":
            return self.method
        return "nested-sensitivity" if size <= AUTO_SENSITIVITY_MAX_N else "nested-adjoint"


@dataclass
class Image:
    """The result: the problem, the estimate, its weight and its uncertainty."""

    field_problem: FieldProblem
    regularizer: object
    choice: WeightChoice
    posterior: Laplace
    homogeneous: dict
    method: str
    seconds: float
    field_choice: dict
    """How the field's shape was chosen (image.json's ``field_choice``)."""

    @property
    def estimate(self):
        """The chosen ``FieldEstimate``."""
        return self.choice.estimate


def image_dataset(dataset: Dataset, settings: ImageSettings, log=print, problem=None) -> Image:
    """Fit the homogeneous model, then the field; see the module docstring.

    ``problem`` is the homogeneous linear-elastic ``InverseProblem`` when already built
    (step 0's, ``experiments.imaging.continuum``); otherwise it is built from ``settings.fit``.
    """
    begin = time.perf_counter()
    if problem is None:
        base = replace(settings.fit, names=("E", "nu"), energy="linear-elastic")
        problem = build_problem(dataset, base)
    result = solve(problem, "nested")
    if not result.success:
        raise RuntimeError(f"the homogeneous fit did not converge ({result.status})")
    homogeneous = {n: float(v) for n, v in zip(result.names, result.x)}
    errors = np.concatenate(problem.point_errors(result.states))
    homogeneous["rms_um"] = 1e3 * float(np.sqrt(np.mean(errors**2)))
    log(
        f"  homogeneous: E {homogeneous['E']:.4g} kPa, nu {homogeneous['nu']:.4f}, "
        f"rms {homogeneous['rms_um']:.1f} um"
    )
    choice_of_field = field_choice(dataset, problem.model, settings.over, settings.shape)
    shape = tuple(choice_of_field["shape"])
    log(f"  {describe(choice_of_field)}")
    stiffness_field = StiffnessField(shape, settings.over)
    fp = FieldProblem(problem, stiffness_field, homogeneous["E"], homogeneous["nu"])
    regularizer = REGULARIZERS[settings.regularizer](stiffness_field, tissue_lengths(problem.model))
    method = settings.solver_name(fp.size)
    estimator = SOLVERS[method]
    log(
        f"  field {'x'.join(map(str, shape))} over the {settings.over} "
        f"(N = {fp.size}), {settings.regularizer}, {method}, {fp.n_residuals} residuals"
    )
    rank = None if fp.size <= DENSE_LAPLACE_MAX_N else LOW_RANK
    if settings.weight == "morozov":
        choice = discrepancy_weight(fp, regularizer, estimator, log=log)
    elif settings.weight == "gcv":
        choice = gcv_weight(fp, regularizer, estimator, rank=rank, log=log)
    elif settings.weight == "lcurve":
        choice = lcurve_weight(fp, regularizer, estimator, log=log)
    else:
        beta = float(settings.weight)
        estimate = estimator(fp, regularizer).solve(beta)
        choice = WeightChoice(
            estimate, float(fp.n_residuals), True, [(beta, estimate.chi2)], "given", "given"
        )
    nuisance = fp.poisson_sensitivity(choice.estimate.coefficients)
    posterior = laplace(fp, regularizer, choice.estimate, rank, nuisance)
    seconds = time.perf_counter() - begin
    return Image(fp, regularizer, choice, posterior, homogeneous, method, seconds, choice_of_field)
