"""Load cases of the extensometer: which frames, which observations, which weights.

Each fitted frame is one load case of the model: both pads prescribed (the moving pad's
measured displacement, the fixed pad 0), the DIC markers observed in x and y, the moving
pad's x force observed through the multipliers (``TissueModel.point_force_rows``).
Frames beyond the DIC (healthy skin: the force record runs to 8.4 mm, the DIC to
3.8 mm of travel) are force-only cases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from experiments.realskin.data import SkinCase, force_at_travel
from experiments.realskin.geometry import Rect
from experiments.realskin.slab import Pads, surface_uv
from solvers.inverse.problem import LoadCase
from symbolic.skin_slab import SkinSlabModel


@dataclass(frozen=True)
class FrameData:
    """The measurements of the fitted frames of one case (model frame, mm and N).

    Attributes
    ----------
    labels : list of str
        One per load case, e.g. "frame 49" or "travel 6.12 mm (force only)".
    pad_mm : numpy.ndarray
        Moving-pad displacement (K, 2) [mm].
    force_n : numpy.ndarray
        Measured x force on the tissue by the moving pad (K,) [N] (negative).
    displacement_mm : list of numpy.ndarray or None
        DIC displacement (P, 2) [mm] per case, None for a force-only case.
    reference_mm : numpy.ndarray
        DIC reference positions (P, 2) [mm], spurious points removed.
    frames : list of int or None
        DIC frame index per case (None for force-only cases).
    """

    labels: list
    pad_mm: np.ndarray
    force_n: np.ndarray
    displacement_mm: list
    reference_mm: np.ndarray
    frames: list

    @property
    def travel_mm(self) -> np.ndarray:
        """Pad travel -dx (K,) [mm]."""
        return -self.pad_mm[:, 0]


def frame_data(case: SkinCase, dic_frames: int = 6, force_only: int = 0) -> FrameData:
    """DIC frames spread over the loading, plus force-only travels beyond the DIC.

    Parameters
    ----------
    case : SkinCase
        The loaded measurement.
    dic_frames : int
        Frames with DIC and force (``case.frames_for_fit``).
    force_only : int
        Extra cases at travels evenly spaced between the last DIC frame and the end of
        the force record, observed through the force alone; the pad's y drift is held
        at its last measured value. None when the record ends within 0.5 mm of the
        last DIC frame (keloid: the record ends before the DIC).
    """
    subset = case.fit_subset(dic_frames)
    labels = [f"frame {f}" for f in subset["frames"]]
    pad = list(subset["pad_displacement_mm"])
    force = list(subset["force_n"])
    disp = list(subset["displacement_mm"])
    frames = [int(f) for f in subset["frames"]]
    last = -subset["pad_displacement_mm"][-1, 0]
    record = -case.force_ux_mm
    if force_only and record.max() > last + 0.5:
        travels = np.linspace(last, record.max(), force_only + 1)[1:]
        travels[-1] = np.nextafter(record.max(), 0.0)
        values = force_at_travel(case.force_ux_mm, case.force_fx_n, -travels)
        for travel, value in zip(travels, values):
            labels.append(f"travel {travel:.2f} mm (force only)")
            pad.append(np.array([-travel, subset["pad_displacement_mm"][-1, 1]]))
            force.append(value)
            disp.append(None)
            frames.append(None)
    return FrameData(
        labels, np.array(pad), np.array(force), disp, subset["reference_model_mm"], frames
    )


def force_weight(data: FrameData) -> float:
    """w_f [mm/N] giving the force block the weight of the displacement block.

    **Choice**: equal relative weight, w_f^2 n_F rms(F)^2 = n_u rms(u)^2, so that a 1 %
    error of every force costs as much as a 1 % error of every DIC displacement
    component. The sensor and DIC noise levels cannot set it: the force record is
    filtered (healthy 5e-7 N) and model error dominates both blocks.
    """
    disp = np.concatenate([d.reshape(-1) for d in data.displacement_mm if d is not None])
    n_u, n_f = disp.size, data.force_n.size
    rms_u = np.sqrt(np.mean(disp**2))
    rms_f = np.sqrt(np.mean(data.force_n**2))
    return float(rms_u / rms_f * np.sqrt(n_u / n_f))


def load_cases(model: SkinSlabModel, pads: Pads, data: FrameData, weight: float) -> list[LoadCase]:
    """One ``LoadCase`` per fitted frame: pads prescribed, markers and/or force observed."""
    region = _region_of(model)
    uv = surface_uv(region, data.reference_mm)
    full_rows = model.volume.collocation(model.volume.outer_params(uv))
    rest = full_rows @ model.rest
    force_rows = sp.csr_matrix(model.point_force_rows(pads.moving_index)[:1])
    zero = np.zeros((model.n_free, 3))
    cases = []
    for label, pad, force, disp in zip(
        data.labels, data.pad_mm, data.force_n, data.displacement_mm
    ):
        if disp is None:
            rows = sp.csr_matrix((0, model.n_free))
            offset, points, index = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int)
        else:
            rows = full_rows[:, model.free].tocsr()
            offset = np.column_stack([-disp, np.zeros(len(disp))])
            points, index = rest, np.arange(len(disp))
        cases.append(
            LoadCase(
                force=zero,
                rows=rows,
                offset=offset,
                weights=np.ones(rows.shape[0]),
                prescribed=pads.displacement(pad),
                rest_points=points,
                label=label,
                marker_index=index,
                force_rows=force_rows,
                force_target=np.array([force]),
                force_weight=weight,
            )
        )
    return cases


def _region_of(model: SkinSlabModel):
    """The rectangle the slab covers, from its rest control points [mm]."""
    lo, hi = model.rest[:, :2].min(axis=0), model.rest[:, :2].max(axis=0)
    return Rect(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
