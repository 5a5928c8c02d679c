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

Forces and contacts are given in the output frame (docs/reconstruction.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from experiments.data.archive import ArchiveError, check_input_file, read_npz

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


LIMITS = {
    "cameras": (2, 16),
    "markers": (3, 200),
    "views": (3, 100),
    "loads": (1, 100),
    "pattern": (2, 50),
}
"""Accepted ranges of the counts in ``experiment.json`` (inclusive)."""

MAX_SPEC_BYTES = 1_000_000
"""Largest ``experiment.json`` [bytes]."""

MAX_IMAGE_BYTES = 200_000_000
"""Largest image file [bytes]."""


def _count(value, name: str) -> int:
    """An integer count within ``LIMITS[name]``."""
    low, high = LIMITS[name]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{name} must be an integer from {low} to {high}, got {value!r}")
    return value


def _finite(values, shape: tuple, name: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be {len(shape) and shape[-1]} finite numbers per load")
    return array


def _spec(path: Path) -> dict:
    """The parsed ``experiment.json``, a regular file of at most ``MAX_SPEC_BYTES``."""
    if not path.is_file() or path.is_symlink() and not path.resolve().is_file():
        raise ValueError(f"{path.parent}: no experiment.json (see experiments.stereo.experiment)")
    try:
        check_input_file(path, "experiment.json")
    except ArchiveError as error:
        raise ValueError(f"{path}: {error}") from None
    if path.stat().st_size > MAX_SPEC_BYTES:
        raise ValueError(f"{path}: over {MAX_SPEC_BYTES} bytes; not an experiment description")
    try:
        spec = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not JSON ({error})") from None
    if not isinstance(spec, dict):
        raise ValueError(f"{path}: must hold a JSON object")
    return spec


def read_experiment(folder) -> Experiment:
    """Read ``experiment.json`` and check that every image (and the segmentation) is present.

    Every count is bounded (``LIMITS``) and every number finite before anything is
    allocated from it.

    Raises
    ------
    ValueError
        For a missing or malformed ``experiment.json``, counts out of range, missing or
        unreadable images (all named), or a missing or misshapen segmentation.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(
            f"{folder}: not a folder, so no experiment.json; give the experiment folder"
        )
    path = folder / "experiment.json"
    spec = _spec(path)
    try:
        n_cams = _count(spec["cameras"], "cameras")
        markers, board = spec["markers"], spec["board"]
        if not isinstance(markers, list) or len(markers) != 2:
            raise ValueError(f"markers must be [U, V], got {markers!r}")
        U, V = (_count(m, "markers") for m in markers)
        pattern = tuple(_count(p, "pattern") for p in board["pattern"])
        square = float(board["square_mm"])
        if len(pattern) != 2 or not 0 < square <= 1000:
            raise ValueError("board needs a pattern [cols, rows] and 0 < square_mm <= 1000")
        target = BoardTarget(pattern, square)
        views = _count(board["views"], "views")
        loads = spec["loads"]
        if not isinstance(loads, list):
            raise ValueError("loads must be a list")
        k = _count(len(loads), "loads")
        forces = _finite([ld["force_N"] for ld in loads], (k, 3), "force_N")
        contacts = _finite([ld["contact_mm"] for ld in loads], (k, 3), "contact_mm")
        radius = _finite([ld.get("probe_radius_mm", 0) for ld in loads], (k,), "probe_radius_mm")
        if (radius < 0).any() or (radius > 100).any():
            raise ValueError("probe_radius_mm must lie in [0, 100]")
        if spec["schema"] != SCHEMA or spec["frame"] not in ("segmentation", "camera0"):
            raise ValueError(f"schema must be {SCHEMA!r} and frame segmentation or camera0")
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as err:
        raise ValueError(f"{path}: malformed ({err}); see experiments.stereo.experiment") from None
    names = ["rest", *(f"load{j}" for j in range(k)), *(f"board{j}" for j in range(views))]
    images = [f"cam{c}_{n}.png" for c in range(n_cams) for n in names]
    missing = [m for m in images if not (folder / m).is_file()]
    if missing:
        raise ValueError(f"{folder}: missing images {', '.join(missing)}")
    for image in images:
        try:
            check_input_file(folder / image, "image")
        except ArchiveError as error:
            raise ValueError(f"{folder / image}: {error}") from None
        if (folder / image).stat().st_size > MAX_IMAGE_BYTES:
            raise ValueError(f"{folder / image}: over {MAX_IMAGE_BYTES} bytes")
    seg, thickness = None, spec.get("thickness_mm")
    if spec["frame"] == "segmentation":
        seg_path = folder / str(spec.get("segmentation", "segmentation.npz"))
        try:
            data = read_npz(seg_path)
            seg = (np.asarray(data["outer"], float), np.asarray(data["inner"], float))
        except (ArchiveError, KeyError, ValueError, TypeError) as err:
            raise ValueError(f"{seg_path}: no segmentation with outer and inner ({err})") from None
        if any(a.shape != (U, V, 3) or not np.all(np.isfinite(a)) for a in seg):
            raise ValueError(f"{seg_path}: outer and inner must be finite, of shape {(U, V, 3)}")
    elif (
        not (isinstance(thickness, (int, float)) and not isinstance(thickness, bool))
        or not 0 < thickness <= 300
    ):
        raise ValueError(f"{path}: frame 'camera0' needs 0 < thickness_mm <= 300")
    args = (forces, contacts, radius, seg, thickness)
    return Experiment(folder, n_cams, (U, V), target, views, *args)
