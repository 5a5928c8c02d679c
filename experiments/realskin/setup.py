"""Set-up of the real-skin study: its settings, and one case's model, pads and load cases.

``build(name, settings)`` loads a case of ``skin-extensometer`` (``experiments.realskin.data``)
and makes everything its fits share (``Setup``): the slab model with glued pads, the DIC
frames with force and their load cases, the noise level and the start values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from experiments.realskin.cases import FrameData, force_weight, frame_data, load_cases
from experiments.realskin.data import SkinCase, dic_noise_mm, load_case
from experiments.realskin.geometry import Rect
from experiments.realskin.scan import SCAN, CellGrid, CellTerms
from experiments.realskin.slab import Pads, region_indicator, slab_volume
from symbolic.constraints import BoundaryConditions
from symbolic.skin_slab import ANISOTROPY, POISSON, REGION_RATIO, SkinSlabModel
from symbolic.stiffening import exponential_stiffening, quadratic_stiffening

STIFFENING = {"exponential": exponential_stiffening, "quadratic": quadratic_stiffening}
"""s(eps) of eq. (1) by name."""


@dataclass(frozen=True)
class RealSkinSettings:
    """Choices of the study (see ``docs/realskin.md`` for the reasons).

    Attributes
    ----------
    thickness_mm : float
        Skin slab thickness [mm].
    grid : tuple of int
        In-plane control points (M, N) over the 100 x 50 mm region; L = 2, bicubic.
    boundary : {"inner", "lateral"}
        "inner": the inner layer is fixed (skin on a subcutaneous layer attached to the
        fascia, alpha_w estimated); "lateral": the region's edge ring is fixed and the
        inner layer free (a membrane, alpha_w fixed large so the layers move together).
    stiffening : {"exponential", "quadratic"}
        s(eps) of eq. (1): exp(k0 eps^2) (Fung-like) or 1 + k0 eps^2.
    pad_points : int
        Prescribed points per pad side (pad_points^2 per pad).
    dic_frames : int
        Frames with DIC and force, spread over the loading.
    force_only : int
        Extra force-only frames beyond the DIC (healthy skin: 3.8 to 8.4 mm of travel).
    smoothing_mm : float
        Width of the keloid indicator's transition [mm] (``outline_region`` only).
    outline_region : bool
        Put the second material inside the keloid outline of ``geometry.geo`` (the old,
        predefined region; off: the region is found by the scan, ``experiments.realskin.scan``).
    significance : float
        An effect is added only if its score test has p below this...
    min_gain : float
        ...and its predicted cost decrease is at least this fraction of the cost.
    max_effects : int
        At most this many effects are added.
    lookahead : int
        Refit this many of the worthy candidates with the largest score statistics and add
        the one whose refit ends lowest (1: the largest statistic alone). The score test
        ranks by a local, first-order prediction; a candidate whose refit gains little can
        outrank one that gains much (docs/realskin.md, the continuum loop).
    candidates : tuple of str
        The effects the loop may add.
    starts : dict
        Start values tried when a parameter is added, e.g. {"k0": (0, 1, 3, 10)}
        (``--k0-starts``; the lowest cost wins, a start without equilibrium is skipped).
        Default: none, every parameter starts at its null value. The stiffening fits
        have local minima (docs/realskin.md, "Sensitivity"); several starts cost one
        fit each.
    diagnostics : tuple of str
        Extensions scored at the final fit but never added.
    bounds : dict
        Bounds of every parameter (natural units).
    """

    thickness_mm: float = 2.0
    grid: tuple[int, int] = (21, 11)
    boundary: str = "inner"
    stiffening: str = "exponential"
    pad_points: int = 4
    dic_frames: int = 6
    force_only: int = 4
    smoothing_mm: float = 1.0
    outline_region: bool = False
    significance: float = 1e-3
    min_gain: float = 0.05
    max_effects: int = 4
    lookahead: int = 1
    candidates: tuple[str, ...] = ("k0", POISSON, ANISOTROPY, SCAN)
    starts: dict = field(default_factory=dict)
    diagnostics: tuple[str, ...] = ()
    bounds: dict = field(
        default_factory=lambda: {
            "alpha_u": (1e-5, 1e3),
            "alpha_w": (1e-6, 1e3),
            "k0": (0.0, 100.0),
            REGION_RATIO: (0.1, 100.0),
            ANISOTROPY: (1e-3, 1e3),
            POISSON: (0.0, 20.0),
        }
    )


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
    """Everything one case's fits share."""

    case: SkinCase
    model: SkinSlabModel
    pads: Pads
    pad_rects: tuple[Rect, Rect]
    data: FrameData
    cases: list
    weight: float
    noise_mm: float
    base_names: tuple[str, ...]
    start: dict
    grid: CellGrid | None = None
    cells: CellTerms | None = None


def build(name: str, settings: RealSkinSettings, pads: tuple[Rect, Rect] | None = None) -> Setup:
    """The slab model, pads, frames and load cases of one case."""
    case = load_case(name)
    geometry = case.geometry
    rects = pad_rects(case) if pads is None else pads
    inner = settings.boundary == "inner"
    if settings.boundary not in ("inner", "lateral"):
        raise ValueError(f"boundary must be 'inner' or 'lateral', got {settings.boundary!r}")
    region = None
    if settings.outline_region and geometry.keloid is not None:
        region = region_indicator(geometry.region, geometry.keloid, settings.smoothing_mm)
    # start: T = 0.02 N/mm; inner: foundation decay length 10 mm; lateral: layers coupled
    tension = 0.02
    area = geometry.region.width * geometry.region.height
    alpha_u = tension * geometry.region.height / geometry.region.width
    alpha_w = tension / 100.0 * area if inner else tension * area / settings.thickness_mm**2
    pad_set = Pads.build(geometry.region, *rects, settings.pad_points)
    model = SkinSlabModel(
        slab_volume(geometry.region, settings.thickness_mm, settings.grid),
        {"alpha_u": alpha_u, "alpha_w": alpha_w},
        BoundaryConditions(fix_inner=inner, fix_lateral=not inner),
        stiffening=STIFFENING[settings.stiffening],
        prescribed=pad_set.prescribed,
        isotropic=True,
        region=region,
    )
    data = frame_data(case, settings.dic_frames, settings.force_only)
    weight = force_weight(data)
    names = ("alpha_u", "alpha_w") if inner else ("alpha_u",)
    start = {"alpha_u": alpha_u, "alpha_w": alpha_w}
    cases = load_cases(model, pad_set, data, weight)
    grid = CellGrid.of(model, geometry.region)
    return Setup(
        case, model, pad_set, rects, data, cases, weight, dic_noise_mm(case), names, start, grid
    )
