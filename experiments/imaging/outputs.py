"""What ``dvs image`` writes: image.json, the map and its uncertainty as PNG and VTU.

The map is sampled on a regular grid of the model's parameter cube and placed in
physical coordinates through the volume (x = sum_i N_i(u, v, w) P_i). The standard
deviation at a sample is that of s = log(E / E_ref), sqrt(phi^T C phi) with the
Laplace covariance C (docs/imaging.md); for small values it is the relative
standard deviation of E.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.imaging.mapping import Image

SCHEMA = "dvs-image/1"


def _physical(image: Image, points: np.ndarray) -> np.ndarray:
    model = image.field_problem.problem.model
    return np.asarray(model.volume.collocation(points) @ model.rest)


def layer_depths(image: Image) -> list[float]:
    """The w of the maps drawn: the skin for a surface field, each layer's nodes otherwise."""
    if image.field_problem.field.over == "surface":
        return [1.0]
    return sorted({float(w) for w in image.field_problem.field.nodes()[:, 2]})


def sample(image: Image, w: float, count: int = 61) -> dict:
    """E [kPa] and std of log E on a count x count grid of (u, v) at depth w."""
    u = np.linspace(0.0, 1.0, count)
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    points = np.column_stack([grid, np.full(len(grid), w)])
    fp = image.field_problem
    phi = fp.field.collocation(points)
    s = phi @ image.estimate.coefficients
    xyz = _physical(image, points)
    shape = (count, count)
    return {
        "x": xyz[:, 0].reshape(shape),
        "y": xyz[:, 1].reshape(shape),
        "E": (fp.reference_kpa * np.exp(s)).reshape(shape),
        "std": image.posterior.pointwise_std(phi).reshape(shape),
    }


def peak(image: Image, markers: np.ndarray | None = None) -> tuple[list[float], float]:
    """The stiffest point of the map, [x, y] [mm], and its E over the median.

    Sampled over every depth drawn; with ``markers`` (rest positions, (..., 3) [mm]) only
    within their x-y bounding box, where the data see the tissue (the margin beyond the
    markers is prior, not measurement).
    """
    samples = [sample(image, w) for w in layer_depths(image)]
    x, y, e = (np.concatenate([s[k].ravel() for s in samples]) for k in ("x", "y", "E"))
    inside = np.ones(x.size, dtype=bool)
    if markers is not None and np.isfinite(markers).any():
        markers = np.asarray(markers, dtype=float).reshape(-1, 3)
        low, high = np.nanmin(markers[:, :2], axis=0), np.nanmax(markers[:, :2], axis=0)
        inside = (x >= low[0]) & (x <= high[0]) & (y >= low[1]) & (y <= high[1])
        inside = inside if inside.any() else np.ones(x.size, dtype=bool)
    best = int(np.flatnonzero(inside)[np.argmax(e[inside])])
    return [float(x[best]), float(y[best])], float(e[best] / np.median(e[inside]))


def document(
    image: Image,
    dataset_path: str,
    markers: np.ndarray | None = None,
    model: dict | None = None,
    base_choice: dict | None = None,
) -> dict:
    """image.json (schema ``dvs-image/1``, docs/formats.md).

    ``model`` adds to the record's ``model`` (the volume imaged on and where it came
    from, ``experiments.imaging.command``); ``base_choice`` is step 0's record.
    """
    fp, estimate, posterior = image.field_problem, image.estimate, image.posterior
    nodes = fp.field.nodes()
    nodes_xyz = _physical(image, nodes)
    s = estimate.coefficients
    departure = (s - s.mean()) / np.maximum(posterior.std, 1e-300)
    strongest = int(np.argmax(np.abs(departure)))
    peak_mm, contrast = peak(image, markers)
    record = {
        "schema": SCHEMA,
        "dataset": dataset_path,
        "model": {
            "E_ref_kPa": fp.reference_kpa,
            "nu": fp.poisson,
            "homogeneous_fit": image.homogeneous,
            **(model or {}),
        },
        "field": {
            "over": fp.field.over,
            "shape": list(fp.field.shape),
            "degree": fp.field.degree,
            "nodes_uvw": nodes.tolist(),
            "nodes_xyz_mm": nodes_xyz.tolist(),
            "coefficients": s.tolist(),
            "E_kPa": (fp.reference_kpa * np.exp(s)).tolist(),
            "std_log_E": posterior.std.tolist(),
        },
        "field_choice": image.field_choice,
        "weight": {
            "rule": image.choice.rule,
            "beta_mm2": estimate.weight,
            "reached": image.choice.reached,
            "note": image.choice.note,
            "path": [[float(b), float(c)] for b, c in image.choice.path],
        },
        "residual": {
            "chi2": estimate.chi2,
            "n": fp.n_residuals,
            "chi2_over_n": estimate.chi2 / fp.n_residuals,
            "rms_um": estimate.rms_um,
            "noise_mm": fp.sigma,
        },
        "rms_mm": estimate.rms_um * 1e-3,
        "noise_rms_mm": fp.noise_rms_mm,
        "effective_dof": posterior.effective_dof,
        "peak_mm": peak_mm,
        "contrast": contrast,
        "laplace_rank": posterior.rank,
        "strongest_departure": {
            "node_xyz_mm": nodes_xyz[strongest].tolist(),
            "E_ratio_to_mean": float(np.exp(s[strongest] - s.mean())),
            "z": float(departure[strongest]),
            "significant": bool(abs(departure[strongest]) > 2.0),
        },
        "method": image.method,
        "regularizer": type(image.regularizer).__name__,
        "success": estimate.success,
        "message": estimate.message,
        "seconds": image.seconds,
    }
    if base_choice is not None:
        record["base_choice"] = base_choice
    return record


def plot_maps(image: Image, markers: np.ndarray, path_map: Path, path_std: Path) -> None:
    """map.png (E [kPa]) and std.png (std of log E), one panel per depth drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, Normalize

    from experiments.output.atomic import atomic_savefig

    depths = layer_depths(image)
    samples = [sample(image, w) for w in depths]
    for path, key, label, cmap in (
        (path_map, "E", "E [kPa] (log scale)", "viridis"),
        (path_std, "std", "std of log E (relative std of E)", "magma"),
    ):
        fig, axes = plt.subplots(1, len(depths), figsize=(4.6 * len(depths), 4.0), squeeze=False)
        low = min(float(s[key].min()) for s in samples)
        high = max(float(s[key].max()) for s in samples)
        norm = LogNorm(low, max(high, low * 1.01)) if key == "E" else Normalize(low, high)
        for ax, w, values in zip(axes[0], depths, samples):
            mesh = ax.pcolormesh(
                values["x"], values["y"], values[key], shading="gouraud", cmap=cmap, norm=norm
            )
            ax.plot(markers[..., 0].ravel(), markers[..., 1].ravel(), "k.", ms=2)
            ax.set_aspect("equal")
            ax.set_xlabel("x [mm]")
            ax.set_ylabel("y [mm]")
            ax.set_title("skin (w = 1)" if w == 1.0 else f"layer w = {w:.2f}")
            fig.colorbar(mesh, ax=ax, label=label, shrink=0.85)
        fig.suptitle(
            f"field {'x'.join(map(str, image.field_choice['shape']))} "
            f"({image.field_choice['rule']}), {image.method}, "
            f"beta {image.estimate.weight:.3g} mm^2 ({image.choice.rule})\n"
            f"{image.posterior.effective_dof:.1f} effective dof, "
            f"chi2/n {image.estimate.chi2 / image.field_problem.n_residuals:.2f}",
            fontsize=10,
        )
        fig.tight_layout()
        atomic_savefig(fig, path, dpi=120)
        plt.close(fig)


def write_vtu(image: Image, path: Path, count: tuple[int, int, int] = (41, 41, 5)) -> bool:
    """map.vtu: hexahedra over the volume with E, log E / E_ref and its std (meshio).

    Returns False (and writes nothing) when meshio is not installed (``pip install
    dvs[vtu]``).
    """
    try:
        import meshio
    except ImportError:
        return False
    from experiments.output.atomic import atomic_write_by_name

    axes = [np.linspace(0.0, 1.0, n) for n in count]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    fp = image.field_problem
    phi = fp.field.collocation(points)
    s = phi @ image.estimate.coefficients
    index = np.arange(len(points)).reshape(count)
    corners = [
        index[i : i + count[0] - 1, j : j + count[1] - 1, k : k + count[2] - 1]
        for i, j, k in ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
    ]
    upper = [c + 1 for c in corners]  # the same corners one step up in w
    cells = np.stack([c.ravel() for c in corners + upper], axis=1)
    mesh = meshio.Mesh(
        _physical(image, points),
        [("hexahedron", cells)],
        point_data={
            "E_kPa": fp.reference_kpa * np.exp(s),
            "log_E_ratio": s,
            "std_log_E": image.posterior.pointwise_std(phi),
        },
    )
    atomic_write_by_name(path, lambda target: meshio.write(target, mesh, file_format="vtu"))
    return True
