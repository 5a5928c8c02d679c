"""The experiment folder of ``dvs reconstruct``: images, cameras and loads, read and checked.

**Folder** (``c`` camera, ``k`` load, ``j`` board pose; all counted from 0):
``cam{c}_board{j}.png`` (every camera sees every pose), ``cam{c}_rest.png``,
``cam{c}_load{k}.png`` (probe in view), ``experiment.json`` and, for frame
``"segmentation"``, ``segmentation.npz`` (``outer``, ``inner``: (U, V, 3) [mm], the skin at
the markers and the inner surface below them). ``experiment.json``::

    {"schema": "dvs-stereo-experiment/1", "cameras": C, "markers": [U, V],
     "board": {"pattern": [cols, rows], "square_mm": s, "views": B},
     "frame": "segmentation" | "camera0", "segmentation": "segmentation.npz",
     "thickness_mm": h (frame camera0 only),
     "loads": [{"force_N": [fx, fy, fz], "contact_mm": [x, y, z], "probe_radius_mm": r}]}

Forces and contacts are given in the output frame (docs/stereo.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .rig import BoardTarget

SCHEMA = "dvs-stereo-experiment/1"


@dataclass(frozen=True)
class Experiment:
    """An experiment folder, read and checked; lengths in mm, forces in N."""

    folder: Path
    n_cameras: int
    shape: tuple[int, int]
    target: BoardTarget
    n_boards: int
    forces: np.ndarray
    contacts: np.ndarray
    probe_radius: np.ndarray
    segmentation: tuple[np.ndarray, np.ndarray] | None
    thickness_mm: float | None

    def image(self, c: int, name: str, size: tuple[int, int] | None = None) -> np.ndarray:
        """Grey image ``cam{c}_{name}.png``, checked against the calibrated ``size`` (w, h)."""
        image = cv2.imread(str(self.folder / f"cam{c}_{name}.png"), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"{self.folder / f'cam{c}_{name}.png'}: not a readable image")
        if size is not None and tuple(size) != image.shape[::-1]:
            raise ValueError(
                f"cam{c}_{name}.png is {image.shape[1]}x{image.shape[0]} px, but "
                f"the calibration of camera {c} is for {size[0]}x{size[1]} px"
            )
        return image


def read_experiment(folder) -> Experiment:
    """Read ``experiment.json`` and check that every image (and the segmentation) is present.

    Raises
    ------
    ValueError
        For a missing or malformed ``experiment.json``, missing images (all named) or a
        missing or misshapen segmentation.
    """
    folder = Path(folder)
    path = folder / "experiment.json"
    if not path.is_file():
        raise ValueError(f"{folder}: no experiment.json (see experiments.stereo.reconstruct)")
    try:
        spec = json.loads(path.read_text())
        n_cams, (U, V), board = int(spec["cameras"]), spec["markers"], spec["board"]
        target = BoardTarget(tuple(board["pattern"]), float(board["square_mm"]))
        loads = [
            (ld["force_N"], ld["contact_mm"], ld.get("probe_radius_mm", 0)) for ld in spec["loads"]
        ]
        forces, contacts, radius = (np.array(v, float) for v in zip(*loads))
        ok = spec["schema"] == SCHEMA and spec["frame"] in ("segmentation", "camera0")
        if not (ok and n_cams >= 2 and min(U, V) >= 3 and forces.shape[1:] == (3,)):
            raise ValueError("need its schema, >= 2 cameras, U, V >= 3, a frame, >= 1 load")
    except (ValueError, KeyError, TypeError, IndexError) as err:
        raise ValueError(f"{path}: malformed ({err}); see experiments.stereo.reconstruct") from None
    views = int(board["views"])
    names = [
        "rest",
        *(f"load{k}" for k in range(len(forces))),
        *(f"board{j}" for j in range(views)),
    ]
    missing = [f"cam{c}_{n}.png" for c in range(n_cams) for n in names]
    missing = [m for m in missing if not (folder / m).is_file()]
    if missing:
        raise ValueError(f"{folder}: missing images {', '.join(missing)}")
    seg, thickness = None, spec.get("thickness_mm")
    if spec["frame"] == "segmentation":
        seg_path = folder / spec.get("segmentation", "segmentation.npz")
        try:
            with np.load(seg_path, allow_pickle=False) as data:
                seg = (np.asarray(data["outer"], float), np.asarray(data["inner"], float))
        except (OSError, KeyError, ValueError) as err:
            raise ValueError(f"{seg_path}: no segmentation with outer and inner ({err})") from None
        if any(a.shape != (U, V, 3) for a in seg):
            raise ValueError(f"{seg_path}: outer and inner must have shape {(U, V, 3)}")
    elif not (isinstance(thickness, (int, float)) and thickness > 0):
        raise ValueError(f"{path}: frame 'camera0' needs thickness_mm > 0")
    args = (forces, contacts, radius, seg, thickness)
    return Experiment(folder, n_cams, (U, V), target, views, *args)
