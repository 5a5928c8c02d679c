"""Run the real-data checks of the stereo pipeline and write a figure.

Usage::

    python -m experiments.stereo.realcheck --out DIR [--data DIR]

1. OpenCV's stereo sample (13 chessboard pairs): corner detection, single
   and stereo calibration, triangulated neighbouring-corner distances.
2. MultiDIC's calibration cylinder (two views): dot detection and indexing,
   calibration from the known dots (DLT + distortion), triangulation against
   ``P3d`` (all dots, and a checkerboard hold-out), a spline surface fit.

Numbers are printed and saved to ``DIR/realcheck.json``; the figure
``DIR/realcheck.png`` shows the labelled dots and the reprojection
residuals. Both are written atomically (temporary file, then ``os.replace``).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from experiments.command.options import Command
from experiments.data.paths import shared_data_dir

from . import holdout
from . import multidic as md
from .calibration import DISTORTION_MODELS
from .chessboard import StereoBoardCalibration, calibrate_stereo_images
from .surface import fit_surface, grid_parameters, icp_to_surface
from .triangulation import triangulate

#: Chessboard inner corners of OpenCV's sample (columns, rows).
BOARD = (9, 6)
#: Bicubic control grid (along the cylinder axis i, around it j). Along i the
#: surface is straight, which the minimal 4 control points reproduce exactly;
#: around it, 6 control points approximate the ~110-degree arc of the
#: triangulated columns to 0.015 mm (max, on the exact cylinder), under a fifth
#: of the measurement noise, while keeping ~8 data points per control point.
SURFACE_GRID = (4, 6)


def read_image_list(data_dir: Path) -> tuple[list[Path], list[Path]]:
    """Left and right image paths from OpenCV's ``stereo_calib.xml`` (alternating)."""
    fs = cv2.FileStorage(str(data_dir / "stereo_calib.xml"), cv2.FILE_STORAGE_READ)
    node = fs.getNode("imagelist")
    names = [node.at(k).string() for k in range(node.size())]
    fs.release()
    if not names or len(names) % 2:
        raise ValueError("stereo_calib.xml must list left/right image pairs")
    return [data_dir / n for n in names[0::2]], [data_dir / n for n in names[1::2]]


def board_neighbour_distances(cal: StereoBoardCalibration) -> list[np.ndarray]:
    """Triangulated distances between neighbouring corners, per pair [squares]."""
    cols, rows = BOARD
    out = []
    for lc, rc in zip(cal.left_corners, cal.right_corners):
        P = triangulate([cal.stereo.left, cal.stereo.right], [lc, rc]).points
        P = P.reshape(rows, cols, 3)
        out.append(
            np.concatenate(
                [
                    np.linalg.norm(np.diff(P, axis=1), axis=2).ravel(),
                    np.linalg.norm(np.diff(P, axis=0), axis=2).ravel(),
                ]
            )
        )
    return out


def check_opencv_stereo(data_dir: Path) -> dict:
    """Calibrate OpenCV's stereo sample and measure the triangulated board."""
    left, right = read_image_list(data_dir)
    imgs_l = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in left]
    imgs_r = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in right]
    cal = calibrate_stereo_images(imgs_l, imgs_r, BOARD)
    dists = board_neighbour_distances(cal)
    d = np.concatenate(dists)
    return {
        "pairs": len(left),
        "pairs_detected": len(cal.left_corners),
        "pairs_skipped": {str(k): why for k, why in cal.skipped.items()},
        "left_rms_px": cal.left.rms,
        "right_rms_px": cal.right.rms,
        "stereo_rms_px": cal.stereo.rms,
        "baseline_squares": cal.stereo.baseline,
        "neighbour_mean_squares": float(d.mean()),
        "neighbour_pair_mean_max_dev": float(max(abs(x.mean() - 1.0) for x in dists)),
        "neighbour_rms_dev": float(np.sqrt(np.mean((d - 1.0) ** 2))),
        "neighbour_max_dev": float(np.abs(d - 1.0).max()),
        "neighbour_frac_over_2pct": float(np.mean(np.abs(d - 1.0) > 0.02)),
    }


def index_check(view: md.LabelledView, grid: np.ndarray, tol_px: float = 3.0) -> dict:
    """Visible dots found, and held-out reprojection of every labelled dot.

    Each labelled dot is checked against a camera calibrated on the other
    checkerboard half of the dots only, so its own (possibly wrong) label
    cannot pull the calibration towards it.
    """
    normals = md.grid_normals(grid)
    cam = view.camera
    have = np.all(np.isfinite(view.pixel_grid(grid.shape[:2])), axis=2)
    vis = md.visible_mask(cam, grid, normals)
    frac = md.estimate_dot_fraction(view, grid)
    full = md.fully_visible_mask(cam, grid, normals, frac)
    ii, jj = np.indices(grid.shape[:2])
    even = (ii + jj) % 2 == 0
    pix = view.pixel_grid(grid.shape[:2])
    good = np.zeros(grid.shape[:2], dtype=bool)
    for train in (even, ~even):
        held = md.calibrate_subset(view, grid, train).camera
        test = ~train & have
        err = np.linalg.norm(pix[test] - held.project(grid[test]), axis=1)
        good[test] = err < tol_px
    return {
        "detected": int(view.dots.centers.shape[0]),
        "labelled": int(have.sum()),
        "visible": int(vis.sum()),
        "visible_labelled_ok": int((vis & have & good).sum()),
        "visible_frac": float((vis & have & good).sum() / vis.sum()),
        "fully_visible": int(full.sum()),
        "fully_visible_frac": float((full & have & good).sum() / full.sum()),
        "labelled_not_visible": int((have & ~vis).sum()),
        "holdout_reproj_ok_frac": float(good[have].mean()),
        "dot_fraction": frac,
        "calib_rms_px": view.labelling.calibration.rms,
        "dlt_rms_px": view.labelling.calibration.dlt_rms,
        "equivalent_labellings": view.labelling.n_equivalent,
    }


def check_multidic(data_dir: Path) -> tuple[dict, dict]:
    """Label both views, calibrate, triangulate and fit a surface; numbers and artefacts."""
    grid = md.load_grid(data_dir)
    names = ("201", "202")
    views = tuple(md.load_view(data_dir / f"{n}.jpg", grid) for n in names)
    out = {n: index_check(v, grid) for n, v in zip(names, views)}
    reports = [md.calibration_report(v, grid) for v in views]
    for name, report in zip(names, reports):
        out[name]["calibration"] = report
    stereo = holdout.stereo_check(views, (views[0].camera, views[1].camera), grid)
    hold = holdout.holdout_check(views, grid)
    flags = tuple(DISTORTION_MODELS[r["model"]] for r in reports)
    spatial = holdout.spatial_holdout_check(views, grid, flags)
    ij = np.argwhere(stereo.mask)
    uv = grid_parameters(ij)
    surf = fit_surface(stereo.triangulation.points, uv, SURFACE_GRID)
    ref = fit_surface(grid[stereo.mask], uv, SURFACE_GRID)
    _, _, icp_rms = icp_to_surface(stereo.triangulation.points, ref, uv)
    out["stereo"] = {
        "n_dots": int(stereo.mask.sum()),
        "rms_3d_mm": stereo.rms,
        "max_3d_mm": float(np.linalg.norm(stereo.errors, axis=1).max()),
        "triangulation_rms_px": stereo.triangulation.rms,
        "sigma_px": stereo.triangulation.sigma,
        "mean_std_mm": stereo.triangulation.std.mean(axis=0).tolist(),
        "spatial_holdout_blocks_rms_3d_mm": spatial["blocks_rms"],
        "spatial_holdout_ends_rms_3d_mm": spatial["ends_rms"],
        "interleaved_holdout_rms_3d_mm": hold["rms"],
        "holdout_fold_rms_mm": hold["fold_rms"],
        "holdout_n": hold["n"],
        "holdout_reproj_rms_px": hold["reproj_rms"],
        "surface_grid": list(SURFACE_GRID),
        "surface_rms_mm": surf.rms,
        "surface_max_mm": surf.max,
        "icp_to_true_surface_rms_mm": icp_rms,
    }
    images = {n: data_dir / f"{n}.jpg" for n in names}
    return out, {"grid": grid, "views": dict(zip(names, views)), "stereo": stereo, "images": images}


def _write_atomic(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def make_figure(artefacts: dict, path: Path, scale: float = 0.25) -> None:
    """Labelled dots on downscaled images, residuals, and the 3D error map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid, views = artefacts["grid"], artefacts["views"]
    fig, axes = plt.subplots(2, 3, figsize=(15, 11))
    for col, (name, view) in enumerate(views.items()):
        img = cv2.imread(str(artefacts["images"][name]))
        small = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        ax = axes[0, col]
        ax.imshow(cv2.cvtColor(small, cv2.COLOR_BGR2RGB))
        lab = view.labelling.labelled
        ij, pts = view.labelling.ij[lab], view.dots.centers[lab] * scale
        ax.scatter(pts[:, 0], pts[:, 1], c=ij[:, 1], cmap="tab20", s=6, vmin=0, vmax=19)
        for (i, j), p in zip(ij, pts):
            if i % 4 == 0 or i == grid.shape[0] - 1:
                ax.text(p[0], p[1] - 4, f"{i},{j}", fontsize=4.5, color="red", ha="center")
        unl = view.dots.centers[~lab] * scale
        ax.scatter(unl[:, 0], unl[:, 1], marker="x", c="cyan", s=6, linewidths=0.5)
        ax.set_title(f"{name}.jpg: (i,j) of labelled dots (x: unlabelled blobs)", fontsize=9)
        ax.axis("off")
        res = view.labelling.calibration.residuals
        ax = axes[1, col]
        full = view.dots.centers[lab]
        q = ax.quiver(
            full[:, 0],
            full[:, 1],
            res[:, 0],
            res[:, 1],
            angles="xy",
            scale_units="xy",
            scale=1 / 200.0,
            width=0.003,
        )
        ax.quiverkey(q, 0.7, 0.06, 1.0, "1 px (drawn x200)", labelpos="E")
        ax.set_xlim(0, view.image_size[0])
        ax.set_ylim(view.image_size[1], 0)
        ax.set_aspect("equal")
        ax.set_title(
            f"{name}: reprojection residuals, RMS {view.labelling.calibration.rms:.2f} px",
            fontsize=9,
        )
    stereo = artefacts["stereo"]
    err = np.full(grid.shape[:2], np.nan)
    err[stereo.mask] = np.linalg.norm(stereo.errors, axis=1)
    ax = axes[0, 2]
    im = ax.imshow(err, origin="lower", cmap="viridis")
    fig.colorbar(im, ax=ax, label="|triangulated - P3d| [mm]")
    ax.set_xlabel("j (column)")
    ax.set_ylabel("i (row, up)")
    ax.set_title(f"3D error, RMS {stereo.rms:.3f} mm", fontsize=9)
    ax = axes[1, 2]
    for name, view in views.items():
        lab = view.labelling.labelled
        ij = view.labelling.ij[lab]
        X = grid[ij[:, 0], ij[:, 1]]
        ray = view.camera.center() - X
        n = md.grid_normals(grid)[ij[:, 0], ij[:, 1]]
        ang = np.degrees(np.arccos(np.einsum("nk,nk->n", n, ray) / np.linalg.norm(ray, axis=1)))
        ax.scatter(
            ang, np.linalg.norm(view.labelling.calibration.residuals, axis=1), s=6, label=name
        )
    ax.set_xlabel("angle between dot normal and viewing ray [deg]")
    ax.set_ylabel("reprojection residual [px]")
    ax.legend()
    fig.tight_layout()
    _write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=130))
    plt.close(fig)


def build_parser(prog: str = "python -m experiments.stereo.realcheck"):
    """The options of ``dvs study realcheck``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument("--out", type=path_argument, required=True, help="output directory")
    parser.add_argument("--data", type=path_argument, default=None, help="shared data directory")
    return parser


def work(args) -> int:
    """``dvs study realcheck --out DIR``: realcheck.json and realcheck.png."""
    from experiments.command.options import UsageError, check_output_dir

    data = args.data or shared_data_dir()
    if not data.is_dir():
        raise UsageError(f"real data not found at {data}; give --data DIR")
    check_output_dir(args.out)
    args.out.mkdir(parents=True, exist_ok=True)
    cv = check_opencv_stereo(data / "opencv-stereo")
    print(
        f"opencv-stereo: {cv['pairs_detected']}/{cv['pairs']} pairs detected; RMS left "
        f"{cv['left_rms_px']:.3f} px, right {cv['right_rms_px']:.3f} px, stereo "
        f"{cv['stereo_rms_px']:.3f} px"
    )
    print(
        f"opencv-stereo: neighbouring corners {cv['neighbour_mean_squares']:.4f} squares "
        f"apart (RMS deviation {100 * cv['neighbour_rms_dev']:.2f}%, worst pair mean "
        f"{100 * cv['neighbour_pair_mean_max_dev']:.2f}%, max single "
        f"{100 * cv['neighbour_max_dev']:.1f}%, {100 * cv['neighbour_frac_over_2pct']:.1f}% "
        "of distances off by > 2%)"
    )
    mdr, artefacts = check_multidic(data / "multidic-calibration-object")
    for name in ("201", "202"):
        r = mdr[name]
        print(
            f"multidic {name}: {r['visible_labelled_ok']}/{r['visible']} visible dots "
            f"detected and correctly indexed ({100 * r['visible_frac']:.1f}%); whole dot "
            f"facing: {100 * r['fully_visible_frac']:.1f}% of {r['fully_visible']}; "
            f"calibration RMS {r['calib_rms_px']:.3f} px (DLT {r['dlt_rms_px']:.2f} px)"
        )
    for name in ("201", "202"):
        c = mdr[name]["calibration"]
        print(
            f"multidic {name}: lens model {c['model']} (spatial hold-out); principal point "
            f"({c['principal_point_px'][0]:.0f}, {c['principal_point_px'][1]:.0f}) px, "
            "spatial std ({:.1f}, {:.1f}) px [covariance ({:.1f}, {:.1f}), half the "
            "ends' difference ({:.1f}, {:.1f})]".format(
                *c["principal_point_std_px"],
                *c["principal_point_cov_std_px"],
                *c["principal_point_half_spread_px"],
            )
        )
        if c["warning"]:
            print(f"warning: multidic {name}: {c['warning']}")
    s = mdr["stereo"]
    print(
        f"multidic stereo, {s['n_dots']} dots: RMS 3D error {s['rms_3d_mm']:.4f} mm "
        f"in-sample (max {s['max_3d_mm']:.3f} mm); spatial hold-out "
        f"{s['spatial_holdout_blocks_rms_3d_mm']:.4f} mm (one of 12 blocks left out at a "
        f"time), {s['spatial_holdout_ends_rms_3d_mm']:.4f} mm (one end from the other); "
        f"interleaved halves {s['interleaved_holdout_rms_3d_mm']:.4f} mm"
    )
    print(
        f"multidic surface: bicubic {s['surface_grid'][0]}x{s['surface_grid'][1]} fit "
        f"residual RMS {s['surface_rms_mm']:.4f} mm (max {s['surface_max_mm']:.3f} mm); "
        f"ICP to the true surface RMS {s['icp_to_true_surface_rms_mm']:.4f} mm"
    )
    numbers = {"opencv_stereo": cv, "multidic": mdr}
    _write_atomic(
        args.out / "realcheck.json", lambda fh: fh.write(json.dumps(numbers, indent=2).encode())
    )
    make_figure(artefacts, args.out / "realcheck.png")
    print(f"wrote {args.out / 'realcheck.json'} and {args.out / 'realcheck.png'}")
    return 0


main = Command("experiments.stereo.realcheck", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
