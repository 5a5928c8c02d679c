"""Axial strain along the pull, read straight from the DIC: where is the skin stiff?

Between the pads, the skin strip carries one pull force (in series, apart from what
leaks sideways into the surrounding skin), so along the pull axis the strain is low
where the skin is stiff and high where it is soft. This module reads that profile from
the measured displacements alone, with no model:

- each DIC column (points with one reference x) gives the median of u_x over y;
- the axial strain between neighbouring columns is the difference quotient
  d(median u_x) / dx [1];
- ``segment_strain`` averages it over x intervals [mm] (model frame).

It is the model-free check of the keloid study (``docs/realskin.md``): is the keloid
one stiffer material, or is it stiff in some places and not in others?

Run ``python -m experiments.realskin.strain [--case keloid] [--frames 14,42,70,84]``.
"""

from __future__ import annotations

import numpy as np

from experiments.command.options import Command
from experiments.realskin.data import SkinCase, load_case

SEGMENTS_MM = (29.6, 40.0, 50.0, 60.0, 70.4)
"""Default x edges [mm] (keloid model frame): the left lobe of the outline (pad edge to
40 mm, where the outline narrows to the band), the band in two halves, the right lobe."""


def column_profile(case: SkinCase, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Median u_x [mm] of every DIC column of one frame.

    Returns
    -------
    x : numpy.ndarray
        Column positions (C,) [mm], model frame, increasing.
    ux : numpy.ndarray
        Median over the column's points of the x displacement (C,) [mm].
    """
    if not 0 <= frame < case.dic_displacement_mm.shape[0]:
        raise ValueError(f"frame must be in [0, {case.dic_displacement_mm.shape[0] - 1}]")
    reference = case.dic_reference_mm[:, 0] + case.dic_to_model_mm[0]
    columns = np.unique(np.round(reference, 3))
    ux = case.dic_displacement_mm[frame, :, 0]
    medians = [np.nanmedian(ux[np.isclose(reference, c, atol=1e-3)]) for c in columns]
    return columns, np.array(medians)


def axial_strain(x: np.ndarray, ux: np.ndarray, window: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Difference quotients (ux[i + window] - ux[i]) / (x[i + window] - x[i]) [1] at the
    midpoints [mm]; ``window`` > 1 averages over that many column spacings (the keloid
    DIC has pairs of nearly equal columns, a subset-interpolation pattern)."""
    if window < 1 or window >= len(x):
        raise ValueError(f"window must be in [1, {len(x) - 1}] columns, got {window}")
    return 0.5 * (x[window:] + x[:-window]), (ux[window:] - ux[:-window]) / (
        x[window:] - x[:-window]
    )


def segment_strain(case: SkinCase, frame: int, edges=SEGMENTS_MM) -> np.ndarray:
    """Mean axial strain [1] in each interval of ``edges`` [mm] (model frame).

    The mean of the difference quotients over an interval is (up to the end columns)
    the displacement change across it divided by its length.
    """
    mid, strain = axial_strain(*column_profile(case, frame))
    edges = np.asarray(edges, dtype=float)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        inside = (mid > a) & (mid < b)
        out.append(float(np.mean(strain[inside])) if inside.any() else np.nan)
    return np.array(out)


def quarters(case: SkinCase) -> np.ndarray:
    """x edges [mm] cutting the DIC's x extent (model frame) into four equal parts."""
    x = case.dic_reference_mm[:, 0] + case.dic_to_model_mm[0]
    return np.linspace(x.min(), x.max(), 5)


def table(case: SkinCase, frames, edges=SEGMENTS_MM) -> str:
    """Markdown table: mean axial strain per segment and frame, and the pad travel."""
    head = [f"x {a:.1f}-{b:.1f} mm" for a, b in zip(edges[:-1], edges[1:])]
    rows = [
        "| frame | pad travel [mm] | " + " | ".join(head) + " |",
        "|" + "---|" * (len(head) + 2),
    ]
    for frame in frames:
        values = segment_strain(case, frame, edges)
        travel = -case.pad_displacement_mm[frame, 0]
        rows.append(f"| {frame} | {travel:.2f} | " + " | ".join(f"{v:.3f}" for v in values) + " |")
    return "\n".join(rows)


def figure(case: SkinCase, frames, path, window: int = 4, pads=None) -> None:
    """Axial strain along the pull per frame, over ``window`` column spacings (top), and
    the keloid outline, the pads (``pads``: two ``Rect``, default those of
    ``geometry.geo``) and the DIC points (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 5.5), sharex=True)
    for frame in frames:
        mid, strain = axial_strain(*column_profile(case, frame), window)
        travel = -case.pad_displacement_mm[frame, 0]
        top.plot(mid, strain, lw=1.2, label=f"frame {frame}, travel {travel:.1f} mm")
    top.set_ylabel("axial strain d u_x / d x [1]")
    top.set_title(f"{case.name}: strain along the pull (median u_x per column, {window} spacings)")
    top.legend(fontsize=8)
    top.grid(alpha=0.3)
    geometry = case.geometry
    if geometry.keloid is not None:
        outline = np.vstack([geometry.keloid, geometry.keloid[:1]])
        bottom.plot(outline[:, 0], outline[:, 1], "r-", lw=1.2, label="keloid outline")
    for pad in pads or (geometry.pad_moving, geometry.pad_fixed):
        bottom.add_patch(plt.Rectangle((pad.x0, pad.y0), pad.width, pad.height, fill=False, ec="k"))
    points = case.dic_reference_mm + case.dic_to_model_mm
    bottom.plot(points[:, 0], points[:, 1], ".", ms=1, color="0.5", label="DIC points")
    bottom.set_xlabel("x [mm]")
    bottom.set_ylabel("y [mm]")
    bottom.set_aspect("equal")
    bottom.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def build_parser(prog: str = "python -m experiments.realskin.strain"):
    """The options of ``dvs realskin strain``."""
    from experiments.command.options import make_parser, path_argument

    parser = make_parser(prog, __doc__.splitlines()[0])
    parser.add_argument(
        "--case", choices=("healthy", "keloid"), default="keloid", help="which measurement"
    )
    parser.add_argument("--frames", default="14,42,70,84", help="comma list of DIC frames")
    parser.add_argument(
        "--figure", type=path_argument, default=None, help="write the figure (PNG) here"
    )
    return parser


def work(args) -> int:
    """``dvs realskin strain [--case healthy] [--frames 14,42]``; exit 2 on bad input."""
    from experiments.command.options import (
        UsageError,
        check_output_file,
        parse_numbers,
    )

    frames = list(parse_numbers(args.frames, "--frames", int))
    if not frames:
        raise UsageError(f"--frames takes a comma list of integers, got {args.frames!r}")
    if args.figure is not None:
        check_output_file(args.figure, ".png", "--figure")
    case = load_case(args.case)
    edges = SEGMENTS_MM if args.case == "keloid" else quarters(case)
    print(table(case, frames, edges))
    if args.figure:
        from experiments.realskin.setup import pad_rects

        figure(case, frames, args.figure, pads=pad_rects(case))
    return 0


main = Command("experiments.realskin.strain", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
