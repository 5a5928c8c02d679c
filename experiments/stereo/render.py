"""Synthetic images of the forehead experiment: dotted skin, probe and chessboard.

One :class:`Renderer` per camera (the model is described in ``docs/reconstruction.md``):

- every pixel's ray comes from the camera's own lens model, so the images carry its
  distortion; sub-pixel samples (``s x s`` per pixel) use the local Jacobian of that map;
- the skin is lit by a field with a linear gradient and vignetting (the same at rest and
  under load);
- dots are material discs in the skin's tangent plane, deformed with the skin's surface
  deformation gradient, drawn by exact ray-plane intersection on the sub-pixel samples;
- the probe, in the loaded images only, is a dark cylinder from the loaded contact point
  along the outward direction of the force, supersampled too;
- the chessboard is box-filtered exactly over each pixel's footprint along its axes;
- then Gaussian blur, noise of variance ``read^2 + gain * signal`` [DN^2] and uint8.

:func:`write_synthetic_experiment` renders a whole experiment folder from the phantom of
:mod:`experiments.phantom.forehead` (naming in :mod:`.reconstruct`):
``python -m experiments.stereo.render FOLDER [--scale 0.5]``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from experiments.command.options import Command
from experiments.output.atomic import atomic_save_npz, atomic_write_bytes, atomic_write_text
from experiments.phantom.forehead import PhantomSettings
from experiments.stereo.imageops import _box_filter, _square_wave, _undistortion_map

from .cameras import Camera
from .rig import BoardTarget, PhantomScene, RigSettings, board_poses, default_rig, phantom_scene


@dataclass(frozen=True)
class RenderSettings:
    """Image formation; grey levels in DN of an 8-bit sensor.

    Attributes
    ----------
    supersample : int
        Sub-pixel samples per pixel side (dots and probe).
    blur_px : float
        Standard deviation of the Gaussian optical blur [px].
    read_noise, gain : float
        Noise standard deviation [DN] and variance per unit signal [DN] (shot noise).
    skin_level : float
        Skin grey level at full illumination [DN].
    dot_reflectance, probe_reflectance : float
        Reflectance of the ink and of the probe relative to the skin.
    gradient, vignetting : float
        Relative illumination change across one image width, and fall-off at the corners.
    dot_diameter_mm, probe_radius_mm, probe_length_mm : float
        Sizes of the dots and of the probe cylinder [mm].
    board_levels : tuple of float
        Reflectance of the board's black and white squares and of its background.
    """

    supersample: int = 4
    blur_px: float = 1.0
    read_noise: float = 1.5
    gain: float = 0.03
    skin_level: float = 200.0
    dot_reflectance: float = 0.3
    probe_reflectance: float = 0.35
    gradient: float = 0.2
    vignetting: float = 0.3
    dot_diameter_mm: float = 0.9
    probe_radius_mm: float = 1.5
    probe_length_mm: float = 60.0
    board_levels: tuple[float, float, float] = (0.08, 0.95, 0.2)

    def __post_init__(self) -> None:
        if self.supersample < 1 or self.blur_px < 0 or self.read_noise < 0 or self.gain < 0:
            raise ValueError("supersample must be >= 1 and blur and noise >= 0")
        if self.dot_diameter_mm <= 0 or self.probe_radius_mm <= 0 or self.probe_length_mm <= 0:
            raise ValueError("dot and probe sizes must be > 0 mm")


@dataclass(frozen=True)
class Probe:
    """A cylinder: tip point, unit axis pointing away from the skin, radius and length [mm]."""

    tip: np.ndarray
    axis: np.ndarray
    radius: float
    length: float


class Renderer:
    """Renders one camera's images; caches its pixel rays and illumination field.

    Parameters
    ----------
    camera : Camera
        The camera (with ``image_size``), world units mm.
    settings : RenderSettings, optional
        Image formation.
    """

    def __init__(self, camera: Camera, settings: RenderSettings | None = None) -> None:
        if camera.image_size is None:
            raise ValueError("the camera needs an image_size to render")
        self.camera, self.settings = camera, settings or RenderSettings()
        w, h = camera.image_size
        self.normalized = _undistortion_map(camera)
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        x, y = (uu - (w - 1) / 2) / w, (vv - (h - 1) / 2) / w
        corner2 = 0.25 * (1 + (h / w) ** 2)
        s = self.settings
        self.light = (1 - s.gradient * (0.8 * x + 0.6 * y)) * (
            1 - s.vignetting * (x**2 + y**2) / corner2
        )

    def _rays(self, box: tuple[int, int, int, int], ss: int) -> np.ndarray:
        """World ray directions at ``ss x ss`` samples per pixel of ``box`` = (x0, x1, y0, y1)."""
        x0, x1, y0, y1 = box
        m = self.normalized[y0:y1, x0:x1]
        gx = np.gradient(m, axis=1) if m.shape[1] > 1 else np.zeros_like(m)
        gy = np.gradient(m, axis=0) if m.shape[0] > 1 else np.zeros_like(m)
        off = (np.arange(ss) + 0.5) / ss - 0.5
        p = (
            m[:, None, :, None]
            + gy[:, None, :, None] * off[None, :, None, None, None]
            + gx[:, None, :, None] * off[None, None, None, :, None]
        )
        d = np.concatenate([p, np.ones(p.shape[:-1] + (1,))], axis=-1) @ self.camera.R
        return d.reshape((y1 - y0) * ss, (x1 - x0) * ss, 3)

    def _box(self, points: np.ndarray, margin: int = 3) -> tuple[int, int, int, int] | None:
        """Pixel box around the projections of ``points`` (n, 3), clipped; None if off-image."""
        if np.any(self.camera.depth(points) <= 0):
            w, h = self.camera.image_size
            return 0, w, 0, h
        uv = self.camera.project(points)
        w, h = self.camera.image_size
        x0, y0 = np.floor(uv.min(axis=0)).astype(int) - margin
        x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + margin + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        return (x0, x1, y0, y1) if x1 - x0 > 1 and y1 - y0 > 1 else None

    def _coverage(self, box, inside_fn) -> np.ndarray:
        ss = self.settings.supersample
        inside = inside_fn(self._rays(box, ss))
        x0, x1, y0, y1 = box
        return inside.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))

    def dot_coverage(self, centres: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """Fraction of each pixel covered by the dots, (h, w).

        Dot ``n`` is ``{centres[n] + a axes[n, :, 0] + b axes[n, :, 1] : a^2 + b^2 <= r^2}``
        with ``r`` half the dot diameter [mm]; ``axes`` (n, 3, 2) are the images of an
        orthonormal tangent basis under the skin's deformation.
        """
        w, h = self.camera.image_size
        cover = np.zeros((h, w))
        radius = 0.5 * self.settings.dot_diameter_mm
        origin = self.camera.center()
        phi = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        ring = np.stack([np.cos(phi), np.sin(phi)])
        for c, e in zip(np.asarray(centres, float), np.asarray(axes, float)):
            normal = np.cross(e[:, 0], e[:, 1])
            if normal @ (origin - c) <= 0:
                continue  # facing away from the camera
            box = self._box(c + radius * (e @ ring).T)
            if box is None:
                continue
            gram_inv = np.linalg.inv(e.T @ e)

            def inside(d, c=c, e=e, normal=normal, gram_inv=gram_inv):
                s = ((c - origin) @ normal) / (d @ normal)
                ab = ((origin + s[..., None] * d - c) @ e) @ gram_inv
                return (np.sum(ab**2, axis=-1) <= radius**2) & (s > 0)

            x0, x1, y0, y1 = box
            cover[y0:y1, x0:x1] = np.maximum(cover[y0:y1, x0:x1], self._coverage(box, inside))
        return cover

    def probe_coverage(self, probe: Probe) -> np.ndarray:
        """Fraction of each pixel covered by the probe cylinder (flat ends), (h, w)."""
        w, h = self.camera.image_size
        cover = np.zeros((h, w))
        a = np.asarray(probe.axis, float) / np.linalg.norm(probe.axis)
        u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        rim = probe.radius * (np.outer(np.cos(phi), u) + np.outer(np.sin(phi), np.cross(a, u)))
        ends = np.concatenate([probe.tip + rim, probe.tip + probe.length * a + rim])
        box = self._box(ends)
        if box is None:
            return cover
        w0 = self.camera.center() - probe.tip

        def inside(d):
            ad, aw = d @ a, w0 @ a
            dp, wp = d - ad[..., None] * a, w0 - aw * a
            qa, qb, qc = np.sum(dp**2, -1), 2 * (dp @ wp), wp @ wp - probe.radius**2
            disc = qb**2 - 4 * qa * qc
            root = np.sqrt(np.maximum(disc, 0.0))
            safe = np.maximum(qa, 1e-300)
            lo = np.where(qa > 1e-12, (-qb - root) / (2 * safe), -np.inf)
            hi = np.where(qa > 1e-12, (-qb + root) / (2 * safe), np.inf)
            radial = np.where(qa > 1e-12, disc >= 0, qc <= 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                s0, s1 = -aw / ad, (probe.length - aw) / ad
            flat = np.abs(ad) < 1e-12
            lo2 = np.where(flat, -np.inf, np.minimum(s0, s1))
            hi2 = np.where(flat, np.inf, np.maximum(s0, s1))
            axial = ~flat | ((aw >= 0) & (aw <= probe.length))
            start, stop = np.maximum(lo, lo2), np.minimum(hi, hi2)
            return radial & axial & (start <= stop) & (stop > 0)

        x0, x1, y0, y1 = box
        cover[y0:y1, x0:x1] = self._coverage(box, inside)
        return cover

    def skin(
        self,
        centres: np.ndarray,
        axes: np.ndarray,
        probe: Probe | None = None,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """uint8 image of the dotted skin (and the probe, if given)."""
        s = self.settings
        reflect = 1.0 - (1.0 - s.dot_reflectance) * self.dot_coverage(centres, axes)
        if probe is not None:
            cover = self.probe_coverage(probe)
            reflect = reflect * (1 - cover) + s.probe_reflectance * cover
        return self._finish(s.skin_level * self.light * reflect, rng)

    def board(
        self,
        pose: tuple[np.ndarray, np.ndarray],
        target: BoardTarget,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """uint8 image of the chessboard at ``pose`` = (R, t), ``X = R x_board + t`` [mm]."""
        R, t = (np.asarray(v, float) for v in pose)
        black, white, background = self.settings.board_levels
        reflect = np.full(self.light.shape, background)
        cols, rows = target.pattern
        m = target.margin_squares
        outline = (
            np.array(
                [[-1 - m, -1 - m], [cols + m, -1 - m], [cols + m, rows + m], [-1 - m, rows + m]]
            )
            * target.square_mm
        )
        box = self._box(np.column_stack([outline, np.zeros(4)]) @ R.T + t)
        if box is not None:
            x0, x1, y0, y1 = box
            norm = self.normalized[y0:y1, x0:x1]
            d = np.concatenate([norm, np.ones(norm.shape[:2] + (1,))], -1) @ self.camera.R
            origin, normal = self.camera.center(), R[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = ((t - origin) @ normal) / (d @ normal)
            local = (origin + s[..., None] * d - t) @ R / target.square_mm
            x = np.nan_to_num(local[..., 0]).astype(np.float32)
            y = np.nan_to_num(local[..., 1]).astype(np.float32)
            fx = np.abs(np.gradient(x, axis=0)) + np.abs(np.gradient(x, axis=1)) + 1e-9
            fy = np.abs(np.gradient(y, axis=0)) + np.abs(np.gradient(y, axis=1)) + 1e-9
            squares = _box_filter(x, -1, cols, fx) * _box_filter(y, -1, rows, fy)
            board = _box_filter(x, -1 - m, cols + m, fx) * _box_filter(y, -1 - m, rows + m, fy)
            board = np.where(np.isfinite(s) & (s > 0), board, 0.0)
            # The checker is evaluated inside the squares, so their outer edge stays sharp.
            xc = np.clip(x, -1 + fx / 2, cols - fx / 2)
            yc = np.clip(y, -1 + fy / 2, rows - fy / 2)
            checker = 0.5 + 0.5 * _square_wave(xc, fx) * _square_wave(yc, fy)
            face = white + squares * (black - white) * checker
            reflect[y0:y1, x0:x1] = background + board * (face - background)
        return self._finish(self.settings.skin_level * self.light * reflect, rng)

    def _finish(self, radiance: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        s = self.settings
        img = radiance.astype(np.float32)
        if s.blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), s.blur_px)
        rng = rng or np.random.default_rng(0)
        sigma = np.sqrt(s.read_noise**2 + s.gain * np.maximum(img, 0.0))
        img = img + sigma * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class SyntheticExperiment:
    """What :func:`write_synthetic_experiment` wrote, and the truth behind it."""

    folder: Path
    cameras: tuple[Camera, ...]
    scene: PhantomScene
    target: BoardTarget


def write_synthetic_experiment(
    folder,
    phantom: PhantomSettings | None = None,
    rig: RigSettings | None = None,
    render: RenderSettings | None = None,
    target: BoardTarget | None = None,
    n_boards: int = 12,
    seed: int = 0,
) -> SyntheticExperiment:
    """Render a complete experiment folder from the phantom (naming: :mod:`.reconstruct`).

    Writes ``cam{c}_rest.png``, ``cam{c}_load{k}.png``, ``cam{c}_board{j}.png``,
    ``segmentation.npz`` (the phantom's skin and inner surface at the markers'
    (u, v), in the phantom's frame) and ``experiment.json`` (loads in that frame).

    Parameters
    ----------
    folder : path-like
        Where to write (created if needed).
    phantom, rig, render : PhantomSettings, RigSettings, RenderSettings, optional
        The phantom (true parameters), the cameras and the image formation.
    target : BoardTarget, optional
        The calibration board.
    n_boards : int
        Board poses (:func:`.rig.board_poses`).
    seed : int
        Seed of the image noise (camera ``c`` draws from ``[seed, c]``).

    Raises
    ------
    ValueError
        If a board pose is not wholly inside some camera's image.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    render, target = render or RenderSettings(), target or BoardTarget()
    cameras = default_rig(rig)
    scene = phantom_scene(phantom)
    poses = board_poses(target, n_boards)
    for c, cam in enumerate(cameras):
        rng = np.random.default_rng([seed, c])
        view = Renderer(cam, render)
        images = {"rest": view.skin(scene.rest, scene.rest_axes, rng=rng)}
        for k, (tip, force) in enumerate(zip(scene.tips, scene.forces)):
            probe = Probe(
                tip, -force / np.linalg.norm(force), render.probe_radius_mm, render.probe_length_mm
            )
            images[f"load{k}"] = view.skin(scene.loaded[k], scene.loaded_axes[k], probe, rng)
        for j, (R, t) in enumerate(poses):
            corners = target.object_points() @ R.T + t
            if not np.all(cam.in_image(cam.project(corners), margin=-20 * render.blur_px)):
                raise ValueError(f"board pose {j} is not wholly inside camera {c}'s image")
            images[f"board{j}"] = view.board((R, t), target, rng)
        for name, image in images.items():
            png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1]
            atomic_write_bytes(folder / f"cam{c}_{name}.png", png.tobytes())
    u, v = scene.shape
    grid = (u, v, 3)
    atomic_save_npz(
        folder / "segmentation.npz", outer=scene.rest.reshape(grid), inner=scene.inner.reshape(grid)
    )
    loads = zip(scene.forces.tolist(), scene.contacts.tolist(), scene.probe_radius.tolist())
    spec = dict(
        schema="dvs-stereo-experiment/1",
        cameras=len(cameras),
        markers=[u, v],
        board=dict(pattern=list(target.pattern), square_mm=target.square_mm, views=n_boards),
        frame="segmentation",
        segmentation="segmentation.npz",
        loads=[dict(force_N=f, contact_mm=p, probe_radius_mm=r) for f, p, r in loads],
    )
    atomic_write_text(folder / "experiment.json", json.dumps(spec, indent=2) + "\n")
    return SyntheticExperiment(folder, cameras, scene, target)


def build_parser(prog: str = "python -m experiments.stereo.render"):
    """The options of ``dvs study render``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, "Render a synthetic forehead experiment for dvs reconstruct.")
    parser.add_argument("folder", type=path_argument, help="experiment folder to write")
    parser.add_argument("--scale", type=float, default=1.0, help="sensor binning, 0.1-2")
    parser.add_argument("--boards", type=int, default=12, help="board poses, 3-50")
    parser.add_argument("--seed", type=int, default=0, help="random seed (>= 0)")
    return parser


def work(args) -> int:
    """``dvs study render FOLDER [--scale S] [--boards N] [--seed N]``."""
    from experiments.command.options import UsageError, check_output_dir, check_seed

    if not 0.1 <= args.scale <= 2 or not 3 <= args.boards <= 50:
        raise UsageError("--scale must lie in [0.1, 2] and --boards in 3-50")
    check_seed(args.seed)
    check_output_dir(args.folder, "FOLDER")
    print(f"rendering {args.boards} board poses and the experiment into {args.folder}")
    rig = RigSettings(scale=args.scale)
    write_synthetic_experiment(args.folder, rig=rig, n_boards=args.boards, seed=args.seed)
    print(f"wrote {args.folder}")
    return 0


main = Command("experiments.stereo.render", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
