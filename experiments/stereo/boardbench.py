"""Chessboard detection benchmark: time and corner accuracy, old and new side by side.

Usage::

    python -m experiments.stereo.boardbench [--data DIR] [--full-size-images N]

``find_corners`` (scaled-down classic detection, refinement at full size with a window
scaled to the squares) against the detector it replaced (``legacy_corners``:
``findChessboardCornersSB`` with exhaustive search in accuracy mode at full size, the
classic detector where it fails, then an 11 x 11 ``cornerSubPix`` window), measured in one run:

1. OpenCV's stereo sample (26 images, 640 x 480): seconds per 25 images, and the
   single-camera calibration RMS of each camera with each detector [px].
2. The same images upscaled 5x (3200 x 2400, the size of the MultiDIC cameras):
   seconds per 25 images (the old detector on ``N`` images only, scaled to 25).
3. Rendered boards of the virtual rig (``experiments.stereo.render``), where the true
   corners are known: RMS and largest corner error [px] of each detector.

Targets: at most 5 s per 25 full-size images; corners not less accurate
than the old detector's on the rendered boards; RMS < 0.5 px on OpenCV's sample.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from experiments.command.options import Command
from experiments.data.paths import shared_data_dir

from .calibration import calibrate_camera
from .chessboard import board_points, find_corners
from .dots import to_gray

TARGET_SECONDS_PER_25 = 5.0
"""Largest detection time per 25 full-size images [s]."""


def legacy_corners(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """The detector ``find_corners`` replaced: exhaustive accuracy-mode SB at full size
    (the classic detector where it fails), a fixed 11 x 11 refinement window."""
    gray = to_gray(image)
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, corners = cv2.findChessboardCornersSB(gray, pattern, flags=flags)
    if not ok:
        classic = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, corners = cv2.findChessboardCorners(gray, pattern, flags=classic)
    if not ok:
        raise ValueError(f"no {pattern[0]}x{pattern[1]} chessboard found in the image")
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(np.float64)


DETECTORS = {"new": find_corners, "old": legacy_corners}


def timed(detector, images, pattern) -> tuple[list, float]:
    """Corners of every image and the seconds per 25 images."""
    begin = time.perf_counter()
    corners = [detector(image, pattern) for image in images]
    return corners, 25.0 * (time.perf_counter() - begin) / len(images)


def opencv_sample(data: Path, full_size_images: int = 2) -> dict:
    """Rows 1 and 2 of the module docstring."""
    from .realcheck import BOARD, read_image_list

    left, right = read_image_list(data)
    images = {
        side: [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
        for side, paths in (("left", left), ("right", right))
    }
    every = images["left"] + images["right"]
    h, w = every[0].shape
    out = {"images": len(every), "size": [w, h]}
    for name, detector in DETECTORS.items():
        _, seconds = timed(detector, every, BOARD)
        rms = {}
        for side, views in images.items():
            corners = [detector(image, BOARD) for image in views]
            objects = [board_points(BOARD)] * len(views)
            rms[side] = calibrate_camera(objects, corners, (w, h)).rms
        out[name] = {"seconds_per_25": seconds, "rms_px": rms}
    big = [cv2.resize(im, (5 * w, 5 * h), interpolation=cv2.INTER_CUBIC) for im in every]
    out["full_size"] = {"size": [5 * w, 5 * h]}
    _, out["full_size"]["new_seconds_per_25"] = timed(find_corners, big, BOARD)
    count = max(1, min(int(full_size_images), len(big)))
    _, out["full_size"]["old_seconds_per_25"] = timed(legacy_corners, big[:count], BOARD)
    out["full_size"]["old_images_timed"] = count
    return out


def rendered_boards(views: int = 6, seed: int = 0) -> dict:
    """Row 3: corner errors against the truth on rendered boards of the virtual rig."""
    from .render import Renderer
    from .rig import BoardTarget, board_poses, default_rig

    target = BoardTarget()
    errors = {name: [] for name in DETECTORS}
    rng = np.random.default_rng(seed)
    for camera in default_rig():
        renderer = Renderer(camera)
        for R, t in board_poses(target, views):
            image = renderer.board((R, t), target, rng)
            truth = camera.project(target.object_points() @ R.T + t)
            for name, detector in DETECTORS.items():
                found = detector(image, target.pattern)
                if np.linalg.norm(found[0] - truth[0]) > np.linalg.norm(found[-1] - truth[0]):
                    found = found[::-1]
                errors[name].append(np.linalg.norm(found - truth, axis=1))
    return {
        name: {
            "rms_px": float(np.sqrt(np.mean(np.concatenate(e) ** 2))),
            "max_px": float(np.concatenate(e).max()),
        }
        for name, e in errors.items()
    }


def report(sample: dict, rendered: dict) -> list[str]:
    """The benchmark's lines, with the targets checked."""
    full = sample["full_size"]
    lines = [
        f"opencv sample ({sample['images']} images, {sample['size'][0]} x {sample['size'][1]}): "
        f"{sample['new']['seconds_per_25']:.2f} s per 25 images (old "
        f"{sample['old']['seconds_per_25']:.2f} s, "
        f"{sample['old']['seconds_per_25'] / sample['new']['seconds_per_25']:.0f}x)",
        "  single-camera RMS: new left {:.3f} right {:.3f} px; old left {:.3f} right {:.3f} "
        "px".format(*sample["new"]["rms_px"].values(), *sample["old"]["rms_px"].values()),
        f"full size ({full['size'][0]} x {full['size'][1]}): {full['new_seconds_per_25']:.2f} s "
        f"per 25 images (old {full['old_seconds_per_25']:.0f} s, from "
        f"{full['old_images_timed']} images; "
        f"{full['old_seconds_per_25'] / full['new_seconds_per_25']:.0f}x)",
        f"rendered boards: corner error RMS new {rendered['new']['rms_px']:.4f} px (max "
        f"{rendered['new']['max_px']:.3f}), old {rendered['old']['rms_px']:.4f} px (max "
        f"{rendered['old']['max_px']:.3f})",
    ]
    checks = {
        "full-size time <= 5 s per 25": full["new_seconds_per_25"] <= TARGET_SECONDS_PER_25,
        "opencv RMS < 0.5 px": max(sample["new"]["rms_px"].values()) < 0.5,
        "rendered corners no less accurate": rendered["new"]["rms_px"]
        <= rendered["old"]["rms_px"] * 1.05,
    }
    lines += [f"target {name}: {'met' if ok else 'MISSED'}" for name, ok in checks.items()]
    return lines


def build_parser(prog: str = "python -m experiments.stereo.boardbench"):
    """The options of the benchmark."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--data", type=path_argument, default=None, help="shared data directory")
    parser.add_argument(
        "--full-size-images", type=int, default=2, help="images the old detector times at 3200 px"
    )
    return parser


def work(args) -> int:
    """Print the benchmark; exit 0 (the targets are reported, not enforced)."""
    from experiments.command.options import UsageError

    if not 1 <= args.full_size_images <= 26:  # the options first, then the data
        raise UsageError("--full-size-images must lie in 1-26")
    data = (args.data or shared_data_dir()) / "opencv-stereo"
    if not data.is_dir():
        raise UsageError(f"OpenCV's stereo sample not found at {data}; give --data DIR")
    sample = opencv_sample(data, args.full_size_images)
    rendered = rendered_boards()
    for line in report(sample, rendered):
        print(line, flush=True)
    return 0


main = Command("experiments.stereo.boardbench", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
