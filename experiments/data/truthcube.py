"""Reader of the Truth Cube's bead file (``truth-cube/uniaxial_positions.csv``).

The Truth Cube (Kerdok et al., "Truth Cube: establishing physical standards for soft
tissue simulation", Medical Image Analysis 7(3), 2003): an 8 cm cube of RTV6166
silicone cast onto a rigid acrylic base, with 343 Teflon beads (7 x 7 x 7, nominally
1 cm apart) located by CT at rest and at 5 %, 12.5 % and 18.25 % nominal compression
by a flat plate. In the file's frame -z points up: the base is at the largest z and
the plate pushes towards +z. No force is recorded. The file comes from OpenSurgSim
(Apache-2.0, SimQuest Solutions); see docs/truthcube.md.

File layout: seven header lines, then one line per bead: ``i,j,k`` (1-based bead
index) and ``x, y, z`` [mm] for each of the four states, rest first.

``truth_cube_dataset`` poses it as a dataset (``dvs import truth-cube FILE --out X.npz``,
``experiments.truthcube.cubeimport``) (docs/formats.md,
"Measured experiments"): the beads as ``markers_rest``/``markers_loaded``, the plate's
nominal travel as ``plate_motion``, no force (``forces`` NaN), and the cube's faces
placed from the bead lattice (``cube_faces``); ``truth_cube_summary`` says what it holds
in one line.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.errors import DatasetError

NOMINAL_COMPRESSION = (0.05, 0.125, 0.1825)
"""The three loaded states' nominal compression, as a fraction of the cube's height [1]."""
CUBE_EDGE_MM = 80.0
"""The cube's nominal edge [mm]."""
FACE_GRID = 9
"""Points per side of the grids laid on the plate's face and the base."""
HEADER_LINES = 7
COLUMNS = 15  # i, j, k, then x, y, z of four states


@dataclass(frozen=True)
class TruthCube:
    """The beads of the Truth Cube, rest and three compressed states (file frame, mm).

    Attributes
    ----------
    index : numpy.ndarray
        (N, 3) integer bead index i, j, k (1-based, 1..7).
    rest : numpy.ndarray
        (N, 3) bead positions at rest [mm].
    loaded : numpy.ndarray
        (S, N, 3) bead positions in each compressed state [mm]; NaN where not located.
    compression : tuple of float
        Each state's nominal compression [1].
    """

    index: np.ndarray
    rest: np.ndarray
    loaded: np.ndarray
    compression: tuple = NOMINAL_COMPRESSION

    @property
    def n_beads(self) -> int:
        """Number of beads N."""
        return int(self.rest.shape[0])

    def plate_travel_mm(self) -> np.ndarray:
        """The plate's nominal travel in each state, compression x 80 mm, (S,) [mm]."""
        return np.asarray(self.compression) * CUBE_EDGE_MM


def read_truth_cube(path: str | os.PathLike) -> TruthCube:
    """Read ``uniaxial_positions.csv``.

    Raises
    ------
    DatasetError
        One line naming the file and what is wrong with it (a missing file, a line
        that is not 15 numbers, a bead index outside 1..7 or repeated, a position
        that is not finite at rest).
    """
    source = Path(path)
    if not source.is_file():
        raise DatasetError(f"{source}: no such file; give the Truth Cube's uniaxial_positions.csv")
    try:
        text = source.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as error:
        kind = error.__class__.__name__
        raise DatasetError(f"{source}: cannot be read as text ({kind})") from None
    rows = []
    for number, line in enumerate(text.splitlines()[HEADER_LINES:], start=HEADER_LINES + 1):
        fields = [f.strip() for f in line.split(",")]
        if not any(fields):
            continue
        if len(fields) < COLUMNS:
            raise DatasetError(
                f"{source}: line {number} has {len(fields)} fields, expected {COLUMNS} "
                "(i, j, k and x, y, z of four states)"
            )
        try:
            rows.append([float(f) if f else np.nan for f in fields[:COLUMNS]])
        except ValueError:
            raise DatasetError(f"{source}: line {number} is not {COLUMNS} numbers") from None
    if not rows:
        raise DatasetError(f"{source}: no bead lines after the {HEADER_LINES} header lines")
    table = np.array(rows)
    index = table[:, :3]
    if not np.all(np.isfinite(index)) or np.any(index % 1) or index.min() < 1 or index.max() > 7:
        raise DatasetError(f"{source}: bead indices must be integers 1..7")
    index = index.astype(int)
    if len({tuple(i) for i in index}) != len(index):
        raise DatasetError(f"{source}: a bead index (i, j, k) is repeated")
    positions = table[:, 3:].reshape(-1, 4, 3).transpose(1, 0, 2)
    if not np.all(np.isfinite(positions[0])):
        raise DatasetError(f"{source}: every bead needs a finite rest position (x0, y0, z0)")
    loaded = positions[1:].copy()
    loaded[~np.isfinite(loaded).all(axis=-1)] = np.nan  # a bead is located or not
    return TruthCube(index=index, rest=positions[0].copy(), loaded=loaded)


def lattice_centre(rest: np.ndarray) -> np.ndarray:
    """The bead lattice's centre [mm]: the mean rest position (for the full 7 x 7 x 7
    lattice, also an affine map of the bead index evaluated at (4, 4, 4))."""
    return np.asarray(rest, dtype=float).mean(axis=0)


def cube_faces(cube: TruthCube, points: int = FACE_GRID) -> tuple[np.ndarray, np.ndarray]:
    """Grids (points, points, 3) [mm] on the plate's face and on the base.

    **Choice**: the cube is centred on the bead lattice, its edges along x, y, z and
    ``CUBE_EDGE_MM`` long: the beads sit nominally 1 cm inside the faces, and the file
    gives no face. The base (bonded to the acrylic) is at the larger z, the plate's
    face 80 mm above it (the file's -z is up).
    """
    centre = lattice_centre(cube.rest)
    half = CUBE_EDGE_MM / 2.0
    axis = np.linspace(-half, half, points)
    x, y = np.meshgrid(centre[0] + axis, centre[1] + axis, indexing="ij")
    plate = np.stack([x, y, np.full_like(x, centre[2] - half)], axis=-1)
    base = np.stack([x, y, np.full_like(x, centre[2] + half)], axis=-1)
    return plate, base


def truth_cube_dataset(cube: TruthCube) -> Dataset:
    """The cube as a dataset: three load cases, the plate moved +z by its nominal travel,
    no force measured, the beads observed."""
    plate, base = cube_faces(cube)
    k_count = cube.loaded.shape[0]
    travel = cube.plate_travel_mm()
    centre = plate[FACE_GRID // 2, FACE_GRID // 2]
    return Dataset(
        outer_rest=plate,
        inner_rest=base,
        forces=np.full((k_count, 3), np.nan),
        contacts=np.tile(centre, (k_count, 1)),
        outer_loaded=np.full((k_count, *plate.shape), np.nan),
        plate_motion=np.column_stack([np.zeros(k_count), np.zeros(k_count), travel]),
        markers_rest=cube.rest,
        markers_loaded=cube.loaded,
        extra={
            "source": np.array("truth-cube uniaxial_positions.csv (Kerdok et al. 2003)"),
            "bead_index": cube.index,
        },
    )


def truth_cube_summary(cube: TruthCube) -> str:
    """One line of what ``truth_cube_dataset`` holds: the beads, the compressed states
    with the bead positions located in them, and the plate's nominal travel [mm]."""
    located = int(np.isfinite(cube.loaded).all(axis=-1).sum())
    return (
        f"{cube.n_beads} beads, {cube.loaded.shape[0]} compressed states ({located} bead "
        f"positions located), plate travel "
        f"{', '.join(f'{t:g}' for t in cube.plate_travel_mm())} mm"
    )


def cube_from_dataset(dataset: Dataset) -> TruthCube:
    """The beads of a dataset written by ``truth_cube_dataset`` (its ``bead_index`` extra,
    markers and plate motion); a one-line DatasetError for any other dataset."""
    index = dataset.extra.get("bead_index")
    if dataset.markers_rest is None or dataset.plate_motion is None or index is None:
        raise DatasetError(
            "not a Truth Cube dataset (needs markers_rest, plate_motion and bead_index); "
            "write it with dvs import truth-cube"
        )
    index = np.asarray(index)
    if index.shape != dataset.markers_rest.shape or index.dtype.kind not in "iu":
        raise DatasetError("bead_index: must be whole numbers of the markers' shape (N, 3)")
    compression = tuple(float(c) for c in dataset.plate_motion[:, 2] / CUBE_EDGE_MM)
    return TruthCube(
        index=index.astype(int),
        rest=np.asarray(dataset.markers_rest, dtype=float),
        loaded=np.asarray(dataset.markers_loaded, dtype=float),
        compression=compression,
    )
