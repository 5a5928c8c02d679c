"""Export the deformed volume to VTK (ParaView): an unstructured grid of hexahedra.

The volume is sampled on a regular (u, v, w) grid; each sample carries its rest
position, displacement [mm] and displacement magnitude. The file is VTK XML
(``.vtu``, binary, zlib-compressed), written by meshio (the ``vtu`` extra:
``pip install 'dvs[vtu]'``) and atomically. meshio replaced a hand-written ASCII
writer: on a 61 x 61 x 5 sampling it writes 7x faster and 4.5x smaller files
(47 ms and 565 kB against 321 ms and 2544 kB), and reads them back for the tests.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output.atomic import atomic_write_by_name
from symbolic.volume import VolumeSpline


def _meshio():
    try:
        import meshio
    except ImportError:
        raise ImportError(
            "VTU export needs meshio: pip install 'dvs[vtu]' (or pip install meshio)"
        ) from None
    return meshio


def sample_grid(volume: VolumeSpline, counts=(21, 21, 3)) -> np.ndarray:
    """(u, v, w) parameters of a regular sampling grid, C order, shape (n, 3)."""
    axes = [np.linspace(0.0, 1.0, c) for c in counts]
    return volume.basis.grid_points(*axes)


def hexahedra(counts) -> np.ndarray:
    """Point indices of the hexahedral cells of a C-ordered (nu, nv, nw) grid, (cells, 8).

    VTK's corner order: the bottom face counter-clockwise, then the top face.
    """
    nu, nv, nw = counts
    index = np.arange(nu * nv * nw).reshape(nu, nv, nw)
    corners = [
        index[:-1, :-1, :-1],
        index[1:, :-1, :-1],
        index[1:, 1:, :-1],
        index[:-1, 1:, :-1],
        index[:-1, :-1, 1:],
        index[1:, :-1, 1:],
        index[1:, 1:, 1:],
        index[:-1, 1:, 1:],
    ]
    return np.stack([c.ravel() for c in corners], axis=1)


def write_vtu(path, volume: VolumeSpline, deformed: np.ndarray, counts=(21, 21, 3)) -> Path:
    """Write the deformed volume as a .vtu file.

    Parameters
    ----------
    path : str or Path
        Output file (``.vtu``).
    volume : VolumeSpline
        The rest volume (control points B0).
    deformed : numpy.ndarray
        Deformed control points B, (n, 3) [mm].
    counts : tuple of int
        Samples along u, v and w (each >= 2).

    Raises
    ------
    ImportError
        When meshio (the ``vtu`` extra) is not installed.
    """
    meshio = _meshio()
    if min(counts) < 2:
        raise ValueError("each sampling count must be >= 2")
    deformed = np.asarray(deformed, dtype=float)
    if deformed.shape != volume.control_points.shape:
        raise ValueError(f"deformed control points must have shape {volume.control_points.shape}")
    collocation = volume.collocation(sample_grid(volume, counts))
    rest = collocation @ volume.control_points
    moved = collocation @ deformed
    displacement = moved - rest
    mesh = meshio.Mesh(
        moved,
        [("hexahedron", hexahedra(counts))],
        point_data={
            "displacement": displacement,
            "displacement_magnitude": np.linalg.norm(displacement, axis=1),
            "rest_position": rest,
        },
    )
    return atomic_write_by_name(
        path, lambda name: meshio.write(name, mesh, file_format="vtu", compression="zlib")
    )
