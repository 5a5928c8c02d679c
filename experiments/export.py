"""Export the deformed volume to VTK (ParaView): an unstructured grid of hexahedra.

The volume is sampled on a regular (u, v, w) grid; each sample carries its
rest position, displacement [mm] and displacement magnitude. The file is VTK
XML (``.vtu``, ASCII), written atomically; no extra dependency is needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.atomic import atomic_write_text
from symbolic.volume import VolumeSpline

HEXAHEDRON = 12
"""VTK cell type of a linear hexahedron."""


def sample_grid(volume: VolumeSpline, counts=(21, 21, 3)) -> np.ndarray:
    """(u, v, w) parameters of a regular sampling grid, C order, shape (n, 3)."""
    axes = [np.linspace(0.0, 1.0, c) for c in counts]
    return volume.basis.grid_points(*axes)


def hexahedra(counts) -> np.ndarray:
    """Point indices of the hexahedral cells of a C-ordered (nu, nv, nw) grid, (cells, 8)."""
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


def _array(name: str, values: np.ndarray, components: int, kind: str = "Float64") -> str:
    flat = " ".join(f"{v:.9g}" for v in np.asarray(values).ravel())
    return (
        f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" '
        f'format="ascii">{flat}</DataArray>'
    )


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
    """
    if min(counts) < 2:
        raise ValueError("each sampling count must be >= 2")
    deformed = np.asarray(deformed, dtype=float)
    if deformed.shape != volume.control_points.shape:
        raise ValueError(f"deformed control points must have shape {volume.control_points.shape}")
    params = sample_grid(volume, counts)
    collocation = volume.collocation(params)
    rest = collocation @ volume.control_points
    moved = collocation @ deformed
    displacement = moved - rest
    cells = hexahedra(counts)
    offsets = 8 * np.arange(1, len(cells) + 1)
    text = f"""<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid>
<Piece NumberOfPoints="{len(moved)}" NumberOfCells="{len(cells)}">
<PointData Vectors="displacement">
{_array("displacement", displacement, 3)}
{_array("displacement_magnitude", np.linalg.norm(displacement, axis=1), 1)}
{_array("rest_position", rest, 3)}
</PointData>
<Points>
{_array("Points", moved, 3)}
</Points>
<Cells>
{_array("connectivity", cells, 1, "Int64")}
{_array("offsets", offsets, 1, "Int64")}
{_array("types", np.full(len(cells), HEXAHEDRON), 1, "UInt8")}
</Cells>
</Piece>
</UnstructuredGrid>
</VTKFile>
"""
    return atomic_write_text(path, text)
