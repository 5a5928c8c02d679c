"""Loader for the two-pad extensometer measurements of in vivo skin (``skin-extensometer``).

Two 8 x 8 mm pads are glued on the skin; the moving pad travels along -x, the other is
fixed, a 2D DIC tracks the skin between them and a sensor records the x force at the
moving pad. Data: ``aflahelouneg/inverse_identification_soft_tissue`` (MIT, (c) 2018
Danas Sutula), read from ``shared_data_dir()``; see ``docs/realskin-data.md``.

Frames (units mm, N):

* DIC frame: origin at the moving pad's reference point at frame 0, x from the moving
  to the fixed pad, y in the image plane. All ``.out`` positions use it.
* Model frame: the gmsh coordinates of ``geometry.geo`` (rectangle [0, 100] x [-5, 45],
  pads centred on y = 20, symmetric about x = 50). ``x_model = x_dic + dic_to_model_mm``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.command.options import Command
from experiments.data.errors import DatasetError, one_line
from experiments.data.paths import shared_data_dir
from experiments.realskin.dicnoise import (
    _MAD,
    spatial_noise_per_frame,
    spurious_points,
)
from experiments.realskin.geometry import SkinGeometry, geometry_from_geo, points_in_polygon

CASES = ("healthy", "keloid")


# ------------------------------------------------------------------------ force record
def _pava(values: np.ndarray) -> np.ndarray:
    """Non-decreasing least-squares fit of a sequence (pool-adjacent-violators)."""
    means: list[float] = []
    sizes: list[int] = []
    for v in values:
        means.append(float(v))
        sizes.append(1)
        while len(means) > 1 and means[-2] > means[-1]:
            n = sizes[-2] + sizes[-1]
            means[-2:] = [(means[-2] * sizes[-2] + means[-1] * sizes[-1]) / n]
            sizes[-2:] = [n]
    return np.repeat(means, sizes)


def force_at_travel(ux_mm: np.ndarray, fx_n: np.ndarray, ux_query_mm: np.ndarray) -> np.ndarray:
    """Force of the record at given moving-pad displacements.

    Rule: keep only samples whose travel -ux exceeds every earlier sample (drops stalls
    and reversals), make the force magnitude non-decreasing in travel by isotonic
    (pool-adjacent-violators) regression, which replaces short relaxation dips by their
    mean, then interpolate linearly. Queries outside the record's travel give NaN.

    Parameters
    ----------
    ux_mm, fx_n : ndarray (N,)
        The record: pad displacement [mm] (negative, along -x) and x force [N].
    ux_query_mm : ndarray (Q,)
        Pad displacements [mm] at which the force is wanted.

    Returns
    -------
    ndarray (Q,)
        Force [N] (negative in tension), NaN outside the record.
    """
    travel = -np.asarray(ux_mm, dtype=float)
    force = np.asarray(fx_n, dtype=float)
    ahead = travel > np.concatenate(([-np.inf], np.maximum.accumulate(travel)[:-1]))
    travel, magnitude = travel[ahead], _pava(-force[ahead])
    return -np.interp(
        -np.asarray(ux_query_mm, dtype=float), travel, magnitude, left=np.nan, right=np.nan
    )


# -------------------------------------------------------------------- DIC point quality


# ----------------------------------------------------------------------------- the case
@dataclass
class SkinCase:
    """One extensometer measurement. Positions in the DIC frame [mm], forces [N].

    Attributes
    ----------
    name : str
        "healthy" or "keloid".
    dic_positions_mm : ndarray (F, P, 2)
        DIC point positions per frame; frame 0 is the reference (a regular grid).
    pad_moving_mm, pad_fixed_mm : ndarray (F, 2)
        Reference point of each pad per frame (``xt_pad_mov.out``, ``xt_pad_fix.out``);
        the moving one starts at (0, 0), so it is also the pad displacement.
    force_ux_mm, force_fx_n : ndarray (N,)
        Force record: moving-pad displacement [mm] (negative) and x force [N] (negative).
    force_at_frame_n : ndarray (F,)
        Force synchronised to each frame by :func:`force_at_travel`; NaN beyond the record.
    geometry : SkinGeometry
        Model-frame geometry from ``geometry.geo``.
    dic_to_model_mm : ndarray (2,)
        Offset mapping DIC to model coordinates; see :func:`dic_to_model_offset`.
    spurious : ndarray (P,) of bool
        Points discarded by :func:`spurious_points`.
    geometry_text : str
        The text of ``geometry.geo`` that ``geometry`` was read from ("" if not given).
    """

    name: str
    dic_positions_mm: np.ndarray
    pad_moving_mm: np.ndarray
    pad_fixed_mm: np.ndarray
    force_ux_mm: np.ndarray
    force_fx_n: np.ndarray
    force_at_frame_n: np.ndarray
    geometry: SkinGeometry
    dic_to_model_mm: np.ndarray
    spurious: np.ndarray
    geometry_text: str = ""

    @property
    def n_frames(self) -> int:
        return self.dic_positions_mm.shape[0]

    @property
    def n_points(self) -> int:
        return self.dic_positions_mm.shape[1]

    @property
    def dic_reference_mm(self) -> np.ndarray:
        """Reference positions (P, 2) [mm], DIC frame (= frame 0)."""
        return self.dic_positions_mm[0]

    @property
    def dic_displacement_mm(self) -> np.ndarray:
        """Displacements (F, P, 2) [mm] relative to frame 0."""
        return self.dic_positions_mm - self.dic_positions_mm[0]

    @property
    def dic_reference_model_mm(self) -> np.ndarray:
        """Reference positions (P, 2) [mm] in the model (gmsh) frame."""
        return self.dic_reference_mm + self.dic_to_model_mm

    @property
    def pad_displacement_mm(self) -> np.ndarray:
        """Moving-pad displacement (F, 2) [mm] relative to frame 0."""
        return self.pad_moving_mm - self.pad_moving_mm[0]

    @property
    def force_valid(self) -> np.ndarray:
        """Frames (F,) whose pad displacement lies inside the force record."""
        return np.isfinite(self.force_at_frame_n)

    def frames_for_fit(self, n: int) -> np.ndarray:
        """``n`` frame indices with a valid force, spread evenly in pad travel
        (targets ``s_max i / n``, i = 1..n, nearest frame each); excludes frame 0."""
        travel = -self.pad_displacement_mm[:, 0]
        valid = np.flatnonzero(self.force_valid & (np.arange(self.n_frames) > 0))
        targets = np.linspace(travel[valid].max() / n, travel[valid].max(), n)
        picked = np.unique(valid[np.abs(travel[valid][None] - targets[:, None]).argmin(1)])
        if len(picked) != n:
            raise ValueError(f"only {len(picked)} distinct frames for n={n}; ask for fewer")
        return picked

    def fit_subset(self, n: int) -> dict:
        """Arrays for a model fit on ``frames_for_fit(n)``, spurious points removed:
        ``frames``, ``reference_model_mm`` (P', 2), ``displacement_mm`` (n, P', 2),
        ``pad_displacement_mm`` (n, 2) and ``force_n`` (n,)."""
        frames, keep = self.frames_for_fit(n), ~self.spurious
        return {
            "frames": frames,
            "reference_model_mm": self.dic_reference_model_mm[keep],
            "displacement_mm": self.dic_displacement_mm[frames][:, keep],
            "pad_displacement_mm": self.pad_displacement_mm[frames],
            "force_n": self.force_at_frame_n[frames],
        }


def dic_to_model_offset(
    pad_moving0: np.ndarray, pad_fixed0: np.ndarray, geometry: SkinGeometry
) -> np.ndarray:
    """Offset [mm] putting the pads' frame-0 reference points symmetric about the middle
    of the modelled pads (x) and the moving pad's reference point on its centre line (y)."""
    pads_mid = 0.5 * (geometry.pad_moving.x1 + geometry.pad_fixed.x0)
    pad_y = 0.5 * (geometry.pad_moving.y0 + geometry.pad_moving.y1)
    return np.array([pads_mid - 0.5 * (pad_moving0[0] + pad_fixed0[0]), pad_y - pad_moving0[1]])


def dic_noise_mm(case: SkinCase, method: str = "spatial") -> float:
    """DIC noise estimate [mm] over the non-spurious points.

    ``"spatial"``: median over frames 1..F-1 of :func:`spatial_noise_per_frame`.
    ``"temporal"``: 1.4826 MAD / sqrt(6) of second differences over frames (temporal
    jitter; the trajectories in the files are smooth in time, so this is far smaller).
    """
    keep = ~case.spurious
    disp = case.dic_displacement_mm[:, keep]
    if method == "spatial":
        return float(np.median(spatial_noise_per_frame(case.dic_reference_mm[keep], disp)[1:]))
    if method == "temporal":
        return float(_MAD * np.median(np.abs(np.diff(disp[1:], n=2, axis=0))) / math.sqrt(6))
    raise ValueError(f"unknown method {method!r}; use 'spatial' or 'temporal'")


_FILES = (
    "displacement/xt_pad_mov.out",
    "displacement/xt_pad_fix.out",
    "reactionforce/ux_pad_mov.out",
    "reactionforce/fx_pad_mov.out",
    "geometry.geo",
)
_DIC = "displacement/xt_dic_*.out"


def _missing(base: Path) -> list[str]:
    """The files of a case folder that are not there (``_FILES`` and the DIC frames)."""
    missing = [f for f in _FILES if not (base / f).is_file()]
    return missing + ([] if any(base.glob(_DIC)) else [_DIC])


def _table(path: Path, columns: int) -> np.ndarray:
    """A whitespace-separated table of numbers with ``columns`` columns, (rows, columns).

    Raises
    ------
    DatasetError
        One line naming the file: not text, not numbers, no rows or other columns.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: refused below
            values = np.loadtxt(path, ndmin=2)
    except (ValueError, OSError) as error:
        raise DatasetError(f"{path}: not a table of numbers ({one_line(error)})") from None
    if values.shape[0] < 1 or values.shape[1] != columns:
        raise DatasetError(
            f"{path}: {values.shape[0]} rows of {values.shape[1]} numbers; expected rows of "
            f"{columns} (docs/realskin-data.md)"
        )
    return values


def read_case(folder: str | Path, name: str | None = None) -> SkinCase:
    """One extensometer case from its folder (``dvs import extensometer DIR``).

    Parameters
    ----------
    folder : str or Path
        The case's folder: ``displacement/``, ``reactionforce/`` and ``geometry.geo``
        (docs/realskin-data.md, "Files as found").
    name : str, optional
        The case's name; default the folder's name.

    Returns
    -------
    SkinCase

    Raises
    ------
    DatasetError
        One line naming the folder or file: a missing file, DIC frames not numbered
        0..F-1, a file that is not a table of numbers of the right width, counts that
        do not match, non-finite pad or force values, a geometry that cannot be read.
    """
    base = Path(folder)
    if not base.is_dir():
        raise DatasetError(f"{base}: not a folder; give one case's folder, e.g. .../healthy")
    missing = _missing(base)
    if missing:
        raise DatasetError(f"{base}: missing {', '.join(missing)} (docs/realskin-data.md)")
    dic_files = sorted(base.glob(_DIC))
    numbers = [f.stem.rsplit("_", 1)[1] for f in dic_files]
    if numbers != [f"{n:04d}" for n in range(len(dic_files))]:
        raise DatasetError(f"{base}: DIC frames are not numbered 0000..F-1; restore the files")
    frames = [_table(f, 2) for f in dic_files]
    if len({f.shape for f in frames}) != 1:
        raise DatasetError(f"{base}: the DIC frames hold different numbers of points")
    positions = np.stack(frames)
    pad_mov, pad_fix = (_table(base / f, 2) for f in _FILES[:2])
    ux, fx = (_table(base / f, 1)[:, 0] for f in _FILES[2:4])
    if not len(pad_mov) == len(pad_fix) == len(positions) or len(ux) != len(fx):
        raise DatasetError(f"{base}: pad or force files do not match the frames; restore them")
    if not all(np.isfinite(a).all() for a in (pad_mov, pad_fix, ux, fx)):
        raise DatasetError(f"{base}: a pad position or force sample is NaN or infinite")
    geo = base / "geometry.geo"
    try:
        text = geo.read_text(encoding="utf-8")
        geometry = geometry_from_geo(text)
    except (ValueError, KeyError, IndexError, TypeError, SyntaxError, OSError) as error:
        raise DatasetError(f"{geo}: not the region and pads in gmsh ({one_line(error)})") from None
    return SkinCase(
        name=base.name if name is None else name,
        dic_positions_mm=positions,
        pad_moving_mm=pad_mov,
        pad_fixed_mm=pad_fix,
        force_ux_mm=ux,
        force_fx_n=fx,
        force_at_frame_n=force_at_travel(ux, fx, pad_mov[:, 0] - pad_mov[0, 0]),
        geometry=geometry,
        dic_to_model_mm=dic_to_model_offset(pad_mov[0], pad_fix[0], geometry),
        spurious=spurious_points(positions[0], positions - positions[0]),
        geometry_text=text,
    )


def load_case(name: str, root: Path | None = None) -> SkinCase:
    """Load one extensometer case of the shared data sets.

    Parameters
    ----------
    name : {"healthy", "keloid"}
        The case; files are read from ``root/skin-extensometer/<name>`` (``read_case``).
    root : Path, optional
        Directory of the shared data sets; default ``shared_data_dir()``.

    Returns
    -------
    SkinCase

    Raises
    ------
    ValueError
        Unknown name, missing files or inconsistent frame/sample counts.
    """
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}; use one of {', '.join(CASES)}")
    base = Path(root if root is not None else shared_data_dir()) / "skin-extensometer" / name
    missing = _missing(base)
    if missing:
        raise ValueError(
            f"missing {', '.join(missing)} in {base}; set DVS_SHARED_DATA (or pass "
            "root=) to the directory that holds skin-extensometer/"
        )
    return read_case(base, name)


def summary(case: SkinCase) -> str:
    """A few lines with the numbers quoted in ``docs/realskin-data.md``."""
    g, ref, keep = case.geometry, case.dic_reference_model_mm, ~case.spurious
    travel, force = -case.force_ux_mm, -case.force_fx_n
    i, last = int(np.argmax(force)), np.flatnonzero(case.force_valid)[-1]
    first = (travel > 0) & (travel <= 0.2 * travel.max())
    early = np.median(force[first] / travel[first])
    separation = case.pad_fixed_mm[0, 0] - case.pad_moving_mm[0, 0]
    noise = spatial_noise_per_frame(case.dic_reference_mm[keep], case.dic_displacement_mm[:, keep])
    typical = np.median(np.linalg.norm(case.dic_displacement_mm[-1, keep], axis=1))
    out = [
        f"{case.name}: {case.n_frames} frames x {case.n_points} points, spurious "
        f"{case.spurious.sum()} ({100 * case.spurious.mean():.1f} %)",
        f"  force: {len(force)} samples, max {force[i]:.4f} N at travel {travel[i]:.3f} mm; "
        f"secant {early:.4f} (first 20 %) -> {force[-1] / travel[-1]:.4f} N/mm (end)",
        f"  DIC pad travel {-case.pad_displacement_mm[-1, 0]:.3f} mm; frames with force "
        f"{case.force_valid.sum()}/{case.n_frames} (last: frame {last}, "
        f"{-case.force_at_frame_n[last]:.4f} N)",
        f"  noise {np.median(noise[1:]):.4f} mm (median frame), {noise[-1]:.4f} mm (last), "
        f"jitter {dic_noise_mm(case, 'temporal'):.5f} mm; median |u| last {typical:.3f} mm",
        f"  pads {g.pad_moving.width:g} x {g.pad_moving.height:g} mm, gap {g.pad_gap_mm:.3f} mm"
        f" (geo) vs separation {separation:.3f} mm (data)",
        f"  region {g.region.width:g} x {g.region.height:g} mm; DIC->model offset "
        f"({case.dic_to_model_mm[0]:.3f}, {case.dic_to_model_mm[1]:.3f}) mm;"
        f" DIC in model x {ref[:, 0].min():.2f}..{ref[:, 0].max():.2f}, "
        f"y {ref[:, 1].min():.2f}..{ref[:, 1].max():.2f} mm",
    ]
    if g.keloid is not None:
        inside = 100 * points_in_polygon(ref, g.keloid).mean()
        out.append(
            f"  keloid: {len(g.keloid)} vertices, x {g.keloid[:, 0].min():.2f}.."
            f"{g.keloid[:, 0].max():.2f} mm; {inside:.0f} % of DIC points inside"
        )
    return "\n".join(out)


def build_parser(prog: str = "python -m experiments.realskin.data"):
    """The options of ``dvs realskin data``."""
    from experiments.command.options import make_parser

    parser = make_parser(prog, "Summary of the extensometer measurements (docs/realskin-data.md).")
    parser.add_argument("--case", choices=CASES, action="append", help="repeatable; default both")
    return parser


def work(args) -> int:
    """Print :func:`summary` for the cases (``dvs realskin data``)."""

    for name in args.case or CASES:
        print(summary(load_case(name)))
    return 0


main = Command("experiments.realskin.data", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
