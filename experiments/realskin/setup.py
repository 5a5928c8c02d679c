"""Set-up of the real-skin study: its settings, and one case's base problem.

``build(name, settings)`` loads a case of ``skin-extensometer`` (``experiments.realskin.data``)
and poses it for the shared loop (``solvers.diagnosis``): the slab with glued pads
(``symbolic.skin_slab.SkinSlabModel``, in-plane isotropic), one load case per fitted
frame (both pads prescribed, the DIC markers observed in x and y, the moving pad's force
through the multipliers; ``experiments.realskin.cases``) and its ``FrameLoad``, the DIC
noise level (docs/realskin.md, "The experiment as a model load case").
"""

from __future__ import annotations

from dataclasses import dataclass, field

from experiments.realskin.cases import FrameData, force_weight, frame_data, load_cases
from experiments.realskin.data import SkinCase, dic_noise_mm, load_case
from experiments.realskin.geometry import Rect
from experiments.realskin.slab import Pads, slab_volume
from solvers.inverse.problem import PlanarProblem
from solvers.inverse.space import ParameterSpace
from symbolic.constraints import BoundaryConditions
from symbolic.loads import FrameLoad
from symbolic.skin_slab import SkinSlabModel
from symbolic.stiffening import exponential_stiffening, quadratic_stiffening

STIFFENING = {"exponential": exponential_stiffening, "quadratic": quadratic_stiffening}
"""s(eps) of eq. (1) by name."""

CANDIDATES = ("nonlinear_stiffening", "volumetric_coupling", "anisotropy", "stiffer_region")
"""The effects the loop may add to the slab (docs/effects.md, "The effects"): strain
stiffening (k0 of eq. 1), the in-plane Poisson coupling, the anisotropy T_y / T_x and a
stiffer rectangle of the skin."""


@dataclass(frozen=True)
class RealSkinSettings:
    """Choices of the study (docs/realskin.md gives the reasons).

    Attributes
    ----------
    thickness_mm : float
        Skin slab thickness [mm].
    grid : tuple of int
        In-plane control points (M, N) over the 100 x 50 mm region; L = 2, bicubic.
    boundary : {"inner", "lateral"}
        "inner": the inner layer is fixed (skin on a subcutaneous layer attached to the
        fascia, alpha_w estimated); "lateral": the region's edge ring is fixed and the
        inner layer free (alpha_u alone estimated).
    stiffening : {"exponential", "quadratic"}
        s(eps) of eq. (1): exp(k0 eps^2) (Fung-like) or 1 + k0 eps^2.
    pad_points : int
        Prescribed points per pad side (pad_points^2 per pad).
    dic_frames : int
        Frames with DIC and force, spread over the loading.
    force_only : int
        Extra force-only frames beyond the DIC (healthy skin: 3.8 to 8.4 mm of travel).
    candidates : tuple of str
        The effects the loop may add.
    max_effects : int
        At most this many effects are added.
    bounds : dict
        Bounds of the base parameters [N/mm] (natural units).
    """

    thickness_mm: float = 2.0
    grid: tuple[int, int] = (21, 11)
    boundary: str = "inner"
    stiffening: str = "exponential"
    pad_points: int = 4
    dic_frames: int = 6
    force_only: int = 4
    candidates: tuple[str, ...] = CANDIDATES
    max_effects: int = 4
    bounds: dict = field(default_factory=lambda: {"alpha_u": (1e-5, 1e3), "alpha_w": (1e-6, 1e3)})


def pad_rects(case: SkinCase) -> tuple[Rect, Rect]:
    """8 x 8 mm pads whose inner-edge midpoints are the pad files' reference points.

    For the keloid this is exactly the ``geometry.geo`` pads; for healthy skin it gives
    the 36.5 mm gap of the pad files instead of the .geo's 32 mm (docs/realskin.md).
    """
    geometry, offset = case.geometry, case.dic_to_model_mm
    size, half = geometry.pad_moving.width, 0.5 * geometry.pad_moving.height
    moving = case.pad_moving_mm[0] + offset
    fixed = case.pad_fixed_mm[0] + offset
    return (
        Rect(moving[0] - size, moving[1] - half, moving[0], moving[1] + half),
        Rect(fixed[0], fixed[1] - half, fixed[0] + size, fixed[1] + half),
    )


@dataclass
class Setup:
    """One case posed for the loop: the measurement, the pads, the frames, the base
    problem (``PlanarProblem``) and its loads, the force weight [mm/N] and DIC noise [mm]."""

    case: SkinCase
    pads: Pads
    pad_rects: tuple[Rect, Rect]
    data: FrameData
    base: PlanarProblem
    loads: list
    weight: float
    noise_mm: float


def build(name: str, settings: RealSkinSettings, case: SkinCase | None = None) -> Setup:
    """The slab model, pads, frames, load cases and base problem of one case: ``case``
    (e.g. rebuilt from a dataset, ``skindataset.case_from_dataset``), or else the shared
    data's case ``name`` (``load_case``)."""
    if settings.boundary not in ("inner", "lateral"):
        raise ValueError(f"boundary must be 'inner' or 'lateral', got {settings.boundary!r}")
    case = load_case(name) if case is None else case
    region = case.geometry.region
    rects = pad_rects(case)
    inner = settings.boundary == "inner"
    # start: T = 0.02 N/mm; inner: foundation decay length 10 mm; lateral: layers coupled
    tension, area = 0.02, region.width * region.height
    alpha_u = tension * region.height / region.width
    alpha_w = tension / 100.0 * area if inner else tension * area / settings.thickness_mm**2
    pads = Pads.build(region, *rects, settings.pad_points)
    model = SkinSlabModel(
        slab_volume(region, settings.thickness_mm, settings.grid),
        {"alpha_u": alpha_u, "alpha_w": alpha_w},
        BoundaryConditions(fix_inner=inner, fix_lateral=not inner),
        stiffening=STIFFENING[settings.stiffening],
        prescribed=pads.prescribed,
        isotropic=True,
    )
    data = frame_data(case, settings.dic_frames, settings.force_only)
    weight = force_weight(data)
    names = ("alpha_u", "alpha_w") if inner else ("alpha_u",)
    space = ParameterSpace.create(
        names, {"alpha_u": alpha_u, "alpha_w": alpha_w}, {n: settings.bounds[n] for n in names}
    )
    cases = load_cases(model, pads, data, weight)
    noise = dic_noise_mm(case)
    base = PlanarProblem(model, cases, space, noise_mm=noise)
    loads = [FrameLoad(c.label) for c in cases]
    return Setup(case, pads, rects, data, base, loads, weight, noise)
