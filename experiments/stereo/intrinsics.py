"""Camera intrinsics from a separate calibration: the ``--intrinsics`` file.

MultiDIC's own workflow: each camera's focal length, principal point and distortion
from many views of a checkerboard, then only its pose from the object or the rig. The
file is JSON (schema ``dvs-intrinsics/1``, docs/formats.md)::

    {"schema": "dvs-intrinsics/1",
     "cameras": [{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                  "dist": [k1, k2, p1, p2, k3, ...],
                  "image_size": [width, height]}, ...]}

in camera order (camera c of an experiment folder is entry c). ``dist`` follows
OpenCV's order and has 4, 5, 8, 12 or 14 coefficients.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .cameras import Camera

SCHEMA = "dvs-intrinsics/1"
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


def intrinsics_document(cameras) -> dict:
    """The JSON document of a sequence of ``Camera`` (their poses are not stored)."""
    return {
        "schema": SCHEMA,
        "cameras": [
            {
                "K": np.asarray(c.K, float).tolist(),
                "dist": np.asarray(c.dist, float).ravel().tolist(),
                "image_size": [int(v) for v in c.image_size],
            }
            for c in cameras
        ],
    }


def save_intrinsics(path, cameras) -> None:
    """Write the cameras' intrinsics to ``path`` (atomically)."""
    from experiments.output.atomic import atomic_write_json

    atomic_write_json(Path(path), intrinsics_document(cameras))


def load_intrinsics(path) -> list[Camera]:
    """The cameras of an intrinsics file, each at the identity pose.

    Raises
    ------
    ValueError
        One line naming what is wrong: unreadable or not JSON, another schema, or a
        camera whose K is not an upper-triangular 3 x 3 with positive focal lengths,
        whose distortion has the wrong length or is not finite, or whose image size
        is not two positive integers.
    """
    path = Path(path)
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"cannot read intrinsics file {path}: {error}") from None
    if not isinstance(document, dict) or document.get("schema") != SCHEMA:
        raise ValueError(f'{path} is not an intrinsics file (need "schema": "{SCHEMA}")')
    entries = document.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f'{path}: "cameras" must be a non-empty list')
    cameras = []
    for c, entry in enumerate(entries):
        try:
            K = np.asarray(entry["K"], dtype=float)
            dist = np.asarray(entry["dist"], dtype=float).ravel()
            size = tuple(int(v) for v in entry["image_size"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(
                f"{path}: camera {c} needs K (3 x 3), dist and image_size [width, height]"
            ) from None
        if (
            K.shape != (3, 3)
            or not np.all(np.isfinite(K))
            or K[0, 0] <= 0
            or K[1, 1] <= 0
            or not np.allclose(K[1:, 0], 0)
            or not np.allclose(K[2], [0, 0, 1])
        ):
            raise ValueError(f"{path}: camera {c}: K must be [[fx,s,cx],[0,fy,cy],[0,0,1]], f>0")
        if dist.size not in DISTORTION_LENGTHS or not np.all(np.isfinite(dist)):
            raise ValueError(
                f"{path}: camera {c}: dist needs {', '.join(map(str, DISTORTION_LENGTHS))} "
                f"finite coefficients, got {dist.size}"
            )
        if len(size) != 2 or min(size) <= 0:
            raise ValueError(f"{path}: camera {c}: image_size must be [width, height] > 0")
        cameras.append(Camera(K, dist, np.eye(3), np.zeros(3), size))
    return cameras
