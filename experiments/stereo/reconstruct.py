"""Images of a multi-camera experiment -> dataset v1 (``python -m experiments.stereo.reconstruct``).

The folder's layout and ``experiment.json`` are described in ``experiments.stereo.experiment``.
Forces and contacts are given in the output frame. The pipeline (calibration, dots with a
clean surround, grid indexing, guided matching of the loaded dots, triangulation with
verification) and the frames are described in ``docs/reconstruction.md``. In short, frame
``"segmentation"`` registers the rest markers rigidly (Kabsch) onto the segmentation's
``outer`` and takes ``inner_rest`` from it, since no camera sees the inner surface; in the
synthetic check that segmentation is the phantom itself. Frame ``"camera0"`` keeps camera 0's
frame and offsets the rest grid by ``thickness_mm`` along its inward normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from experiments.command.options import Command
from experiments.data.dataset import Dataset, save_dataset, validate
from experiments.stereo.correspondence import (
    label_rest,
    match_loaded,
)

from .cameras import Camera
from .dots import detect_dots, to_gray
from .experiment import read_experiment
from .rig import RigCalibration, calibrate_rig
from .surface import rigid_align
from .triangulation import triangulate


@dataclass(frozen=True)
class ReconstructSettings:
    """Thresholds of the reconstruction.

    Attributes
    ----------
    ring_spread : float
        Largest spread (1st to 99th percentile, relative to the median) of the grey levels in
        the ring from 1.5 r + 2 to 3 r + 2 px around a dot of radius r [px].
    label_px : float
        Largest median epipolar distance of a grid labelling against camera 0 [px].
    match_tol : float
        A loaded dot must lie within this many local dot spacings of its rest position.
    reject_px, reject_factor : float
        An observation is dropped when its reprojection residual exceeds both ``reject_px``
        [px] and ``reject_factor`` times the median residual.
    max_displacement : float
        Largest displacement under load, in marker spacings.
    min_ray_angle : float
        Smallest angle between two cameras' rays at the working distance [deg].
    """

    ring_spread: float = 0.25
    label_px: float = 2.0
    match_tol: float = 0.25
    reject_px: float = 0.3
    reject_factor: float = 6.0
    max_displacement: float = 0.5
    min_ray_angle: float = 1.0


def detect_markers(image: np.ndarray, ring_spread: float = 0.25) -> np.ndarray:
    """Centres (n, 2) [px] of dark dots surrounded by clean skin (:func:`.dots.detect_dots`).

    A dot is kept when the grey levels in the ring from ``1.5 r + 2`` to ``3 r + 2`` px
    (``r`` its equivalent radius) spread by at most ``ring_spread`` of their median
    (1st to 99th percentile): dots covered, cut or touched by the probe, or next to any other
    large structure, are dropped instead of being measured with a biased centre.
    """
    gray = to_gray(image)
    dots = detect_dots(gray)
    h, w = gray.shape
    keep = np.zeros(len(dots.areas), dtype=bool)
    for n, (centre, area) in enumerate(zip(dots.centers, dots.areas)):
        r = np.sqrt(area / np.pi)
        r_in, r_out = 1.5 * r + 2, 3 * r + 2
        x0, y0 = (max(int(v - r_out), 0) for v in centre)
        x1, y1 = min(int(centre[0] + r_out) + 2, w), min(int(centre[1] + r_out) + 2, h)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        dist = np.hypot(xx - centre[0], yy - centre[1])
        ring = gray[y0:y1, x0:x1][(dist >= r_in) & (dist <= r_out)].astype(float)
        if ring.size:
            lo, med, hi = np.percentile(ring, [1, 50, 99])
            keep[n] = hi - lo <= ring_spread * med
    return dots.centers[keep]


def triangulate_markers(
    cameras: tuple[Camera, ...], obs: np.ndarray, settings: ReconstructSettings
) -> tuple:
    """Triangulate markers seen in >= 2 views, dropping observations off their reprojection.

    ``obs`` (C, n, 2) [px], NaN = not seen. Returns ``points`` (n, 3) [mm] (NaN where fewer
    than two consistent views remain), the observations used (C, n, 2) [px], ``std`` (n,)
    predicted standard deviation per axis [mm], the RMS reprojection error [px] and the
    number of observations dropped.
    """
    obs = np.array(obs, dtype=float)
    n = obs.shape[1]
    dropped = 0
    while True:
        seen = np.all(np.isfinite(obs), axis=2)
        idx = np.flatnonzero(seen.sum(axis=0) >= 2)
        points, std = np.full((n, 3), np.nan), np.full(n, np.nan)
        obs[:, seen.sum(axis=0) < 2] = np.nan
        if idx.size == 0:
            return points, obs, std, float("nan"), dropped
        tri = triangulate(cameras, [o[idx] for o in obs], min_ray_angle=settings.min_ray_angle)
        res = np.linalg.norm(tri.residuals, axis=2)
        limit = max(settings.reject_px, settings.reject_factor * float(np.nanmedian(res)))
        if np.nanmax(res) <= limit:
            points[idx], std[idx] = tri.points, np.sqrt(np.mean(tri.std**2, axis=1))
            return points, obs, std, tri.rms, dropped
        c, p = np.unravel_index(np.nanargmax(res), res.shape)
        if seen[:, idx[p]].sum() > 2:
            obs[c, idx[p]] = np.nan
            dropped += 1
        else:
            dropped += int(seen[:, idx[p]].sum())
            obs[:, idx[p]] = np.nan


@dataclass(frozen=True)
class Reconstruction:
    """The dataset and how it was measured.

    Attributes
    ----------
    dataset : Dataset
        Format v1, in the experiment's frame [mm, N]. Extra key ``marker_std_mm``
        (K + 1, U, V): each marker's predicted standard deviation per axis, rest first [mm].
    calibration : RigCalibration
        The rig used.
    observations : numpy.ndarray
        (K + 1, C, U * V, 2) pixels used per image set (rest first), camera and marker;
        NaN where not used.
    reprojection_rms_px : numpy.ndarray
        (K + 1,) RMS reprojection error per image set, rest first [px].
    dropped : int
        Observations (and loaded markers) dropped by the consistency checks.
    registration_rms_mm : float or None
        RMS distance of the registered rest markers from the segmentation's [mm].
    """

    dataset: Dataset
    calibration: RigCalibration
    observations: np.ndarray
    reprojection_rms_px: np.ndarray
    dropped: int
    registration_rms_mm: float | None

    @property
    def views(self) -> np.ndarray:
        """(K + 1, U, V) number of cameras used per marker, rest first (0 = NaN)."""
        used = np.isfinite(self.observations[..., 0]).sum(axis=1)
        return used.reshape(-1, *self.dataset.marker_shape)


def reconstruct(
    folder,
    calibration: RigCalibration | None = None,
    settings: ReconstructSettings | None = None,
    progress=None,
    intrinsics=None,
) -> Reconstruction:
    """Reconstruct a dataset v1 from an experiment folder (see the module docstring).

    Parameters
    ----------
    folder : path-like
        The experiment folder.
    calibration : RigCalibration, optional
        A ready calibration; by default the rig is calibrated from the board images.
    settings : ReconstructSettings, optional
        Thresholds.
    progress : callable, optional
        Receives one-line progress messages.
    intrinsics : sequence of Camera, optional
        Each camera's K and distortion from a separate calibration
        (``experiments.stereo.intrinsics.load_intrinsics``); the board images then
        give only the poses.

    Raises
    ------
    ValueError
        For missing images, no detectable grid, a calibration that does not match the
        images, degenerate camera geometry, or markers missing at rest.
    """
    s, say = settings or ReconstructSettings(), progress or (lambda msg: None)
    exp = read_experiment(folder)
    C, (U, V) = exp.n_cameras, exp.shape
    if calibration is None:
        fixed = "" if intrinsics is None else " (intrinsics given: poses only)"
        say(f"calibrating {C} cameras from {exp.n_boards} board views{fixed}")
        boards = [[exp.image(c, f"board{j}") for j in range(exp.n_boards)] for c in range(C)]
        calibration = calibrate_rig(boards, exp.target, intrinsics=intrinsics)
    cams = calibration.cameras
    if len(cams) != C:
        raise ValueError(f"the calibration has {len(cams)} cameras, the experiment {C}")
    calibration.check_geometry(s.min_ray_angle)
    results, rest_obs = [], None
    for name in ["rest", *(f"load{k}" for k in range(len(exp.forces)))]:
        say(f"{name}: detecting, indexing and triangulating the markers")
        images = [exp.image(c, name, cam.image_size) for c, cam in enumerate(cams)]
        centres = [detect_markers(image, s.ring_spread) for image in images]
        if rest_obs is None:
            names = [f"cam{c}_rest.png" for c in range(C)]
            obs = rest_obs = label_rest(centres, cams, exp.shape, s.label_px, names)
        else:
            obs = np.stack([match_loaded(centres[c], rest_obs[c], s.match_tol) for c in range(C)])
        results.append(triangulate_markers(cams, obs, s))
    points, used, stds, rms, dropped = zip(*results)
    rest = points[0].reshape(U, V, 3)
    if np.isnan(rest).any():
        lost = [tuple(int(v) for v in ij) for ij in np.argwhere(np.isnan(rest[..., 0]))]
        raise ValueError(
            f"markers {lost} were not reconstructed at rest: every marker must be "
            "seen by two cameras in the rest images"
        )
    spacing = min(np.linalg.norm(np.diff(rest, axis=a), axis=-1).min() for a in (0, 1))
    loaded = np.stack(points[1:]).reshape(-1, U, V, 3)
    moved = np.linalg.norm(loaded - rest, axis=-1) > s.max_displacement * spacing
    loaded[moved] = np.nan
    used = np.stack(used)
    used[1:].transpose(0, 2, 1, 3)[moved.reshape(len(moved), -1)] = np.nan
    reg = None
    if exp.segmentation is not None:
        outer, inner = exp.segmentation
        _, R, t = rigid_align(rest.reshape(-1, 3), outer.reshape(-1, 3))
        rest, loaded = rest @ R.T + t, loaded @ R.T + t
        reg = float(np.sqrt(np.mean(np.sum((rest - outer) ** 2, axis=-1))))
    else:
        normal = np.cross(np.gradient(rest, axis=0), np.gradient(rest, axis=1))
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        normal *= np.sign(np.sum(normal * -rest, axis=-1, keepdims=True))  # towards camera 0
        inner = rest - exp.thickness_mm * normal
    std = np.stack(stds).reshape(-1, U, V)
    std[1:][moved] = np.nan
    noise = float(np.sqrt(np.nanmean(std**2)))
    args = (exp.forces, exp.contacts, loaded, noise, exp.probe_radius)
    dataset = Dataset(rest, inner, *args, extra={"marker_std_mm": std})
    validate(dataset)
    return Reconstruction(
        dataset, calibration, used, np.array(rms), sum(dropped) + int(moved.sum()), reg
    )


def build_parser(prog: str = "python -m experiments.stereo.reconstruct"):
    """The options of ``dvs reconstruct``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "Reconstruct a dataset from the images of an experiment.")
    parser.add_argument(
        "folder", type=path_argument, help="experiment folder (docs/reconstruction.md)"
    )
    parser.add_argument(
        "--out", type=path_argument, required=True, help="dataset file to write (.npz)"
    )
    parser.add_argument(
        "--intrinsics",
        type=path_argument,
        default=None,
        help="JSON of each camera's K and distortion from a separate calibration "
        "(docs/formats.md); the board images then give only the poses",
    )
    return parser


def work(args) -> int:
    """``dvs reconstruct FOLDER --out FILE.npz [--intrinsics FILE]``; exit 2 on bad input."""
    from experiments.command.options import check_output_file

    check_output_file(args.out, ".npz")
    intrinsics = None
    if args.intrinsics is not None:
        from .intrinsics import load_intrinsics

        intrinsics = load_intrinsics(args.intrinsics)
    try:
        rec = reconstruct(
            args.folder, progress=lambda m: print(m, flush=True), intrinsics=intrinsics
        )
    except cv2.error as error:
        raise ValueError(" ".join(str(error).split())) from None
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_dataset(args.out, rec.dataset)
    seen = rec.views[1:].astype(bool).sum(axis=(1, 2)).tolist()
    reg = rec.registration_rms_mm
    registration = "" if reg is None else f", rest markers {reg * 1e3:.1f} um from segmentation"
    print(
        f"wrote {args.out}: {rec.views.shape[1]} x {rec.views.shape[2]} markers, seen under "
        f"load {seen}, reprojection RMS {np.round(rec.reprojection_rms_px, 3).tolist()} px"
        + registration
    )
    return 0


main = Command("experiments.stereo.reconstruct", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
