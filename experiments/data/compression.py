"""A recipe's silicone-phantom compression tests as a dataset (``dvs import compression``,
``experiments.phantoms.importer``).

The phantoms (Ecoflex cylinders, 50 mm across and 30 mm high; Queen Mary University of
London, "A database of silicone phantom materials for modeling human tissue mechanics
across varying stiffnesses"; see docs/experiments.md): each recipe's folder holds ten
tests, ``<recipe>_A1..A5.csv`` and ``<recipe>_B1..B5.csv``, each a metadata header, a
blank line and a table of time [s], compression [mm], load [N] and derived stresses.

The dataset (docs/formats.md, "Measured experiments"): the cylinder between its top
face (``outer_rest``, a grid over the disc) and its base (``inner_rest``); one load case
per sampled point of each test's curve, the plate moved down by the compression
(``plate_motion``) and its measured force (``forces``); ``specimen`` numbers the tests
(``specimen_names``). No marker is seen (``outer_loaded`` all NaN). ``compression_summary``
says what it holds in one line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.data.dataset import Dataset
from experiments.data.errors import DatasetError

GRID = 9
"""Points per side of the square grid mapped onto the top face (``disc_grid``)."""
COLUMNS = ("time", "compression", "load")  # the first three columns of the table [s, mm, N]
HEADER = re.compile(r"^\s*(Cylinder Diameter|Cylinder Height|Speed \(mm/min\))\s*:\s*([\d.]+)")


@dataclass(frozen=True)
class CompressionTest:
    """One compression test of one specimen.

    Attributes
    ----------
    name : str
        The specimen, e.g. "A1".
    diameter_mm, height_mm : float
        The cylinder's nominal size [mm].
    compression_mm : numpy.ndarray
        Plate travel from first contact [mm], (T,).
    load_n : numpy.ndarray
        Measured compressive load [N], (T,).
    """

    name: str
    diameter_mm: float
    height_mm: float
    compression_mm: np.ndarray
    load_n: np.ndarray


def read_test(path: Path) -> CompressionTest:
    """One test's CSV (metadata lines, then a header row and the numbers)."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    meta = {}
    start = None
    for number, line in enumerate(lines):
        match = HEADER.match(line)
        if match:
            meta[match.group(1)] = float(match.group(2))
        if line.lower().startswith("time"):
            start = number + 1
            break
    if start is None or len(meta) < 2:
        raise DatasetError(
            f"{path}: not a compression test (needs 'Cylinder Diameter', 'Cylinder Height' "
            "and a 'Time, Compression, Load' table)"
        )
    try:
        table = np.array(
            [[float(f) for f in line.split(",")[:3]] for line in lines[start:] if line.strip()]
        )
    except ValueError:
        raise DatasetError(f"{path}: the table holds a value that is not a number") from None
    if table.ndim != 2 or table.shape[0] < 10 or not np.isfinite(table).all():
        raise DatasetError(f"{path}: the table needs at least 10 complete rows of numbers")
    name = path.stem.rsplit("_", 1)[-1]
    return CompressionTest(
        name=name,
        diameter_mm=meta["Cylinder Diameter"],
        height_mm=meta["Cylinder Height"],
        compression_mm=table[:, 1],
        load_n=table[:, 2],
    )


def read_recipe(folder: str | Path) -> tuple[str, list[CompressionTest]]:
    """The recipe's name (the folder's) and its tests, sorted by specimen name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder; give one recipe's folder of test CSVs")
    files = sorted(folder.glob(f"{folder.name}_*.csv"))
    if not files:
        raise DatasetError(f"{folder}: no {folder.name}_<specimen>.csv test files in it")
    tests = [read_test(f) for f in files]
    sizes = {(t.diameter_mm, t.height_mm) for t in tests}
    if len(sizes) != 1:
        raise DatasetError(f"{folder}: the tests give different cylinder sizes {sorted(sizes)}")
    return folder.name, tests


def force_noise(tests: list[CompressionTest]) -> float:
    """The load's noise [N]: the median over tests of the scatter of consecutive samples
    about a locally linear curve, std(second difference) / sqrt(6) (a second difference
    of independent noise has variance 6 sigma^2), over the first tenth of each test."""
    values = []
    for test in tests:
        early = test.load_n[: max(len(test.load_n) // 10, 10)]
        second = np.diff(early, 2)
        mad = np.median(np.abs(second - np.median(second))) * 1.4826
        values.append(mad / np.sqrt(6.0))
    return float(np.median(values))


def disc_grid(radius: float, z: float, points: int = GRID) -> np.ndarray:
    """A (points, points, 3) grid over the disc of ``radius`` at height ``z`` [mm]: the
    square [-1, 1]^2 mapped onto the disc (x = a sqrt(1 - b^2 / 2), y = b sqrt(1 - a^2/2))."""
    a, b = np.meshgrid(np.linspace(-1, 1, points), np.linspace(-1, 1, points), indexing="ij")
    x = a * np.sqrt(1.0 - b**2 / 2.0)
    y = b * np.sqrt(1.0 - a**2 / 2.0)
    return np.stack([radius * x, radius * y, np.full_like(x, z)], axis=-1)


def compression_dataset(
    recipe: str, tests: list[CompressionTest], samples: int = 15, strain: float = 0.5
) -> Dataset:
    """The tests' curves sampled at ``samples`` compressions up to ``strain`` x height.

    Each sample is one load case: the plate moved by (0, 0, -c) [mm], its force on the
    tissue (0, 0, -F) [N] (the load pushes the top face down), the specimen's number.
    Samples start at 2 % of ``strain`` (the contact's first, noisiest part excluded).
    """
    if not 0.0 < strain < 1.0 or samples < 1 or samples * len(tests) > 200:
        raise DatasetError(
            f"{samples} samples of {len(tests)} tests up to strain {strain}: give 0 < strain "
            "< 1 and at most 200 load cases in all"
        )
    height, radius = tests[0].height_mm, tests[0].diameter_mm / 2.0
    levels = np.linspace(0.02, 1.0, samples) * strain * height
    motion, forces, specimen = [], [], []
    for number, test in enumerate(tests):
        reach = np.maximum.accumulate(test.compression_mm)
        if reach[-1] < levels[-1]:
            raise DatasetError(
                f"test {test.name} reaches {reach[-1]:.3g} mm, short of {levels[-1]:.3g} mm; "
                "lower --strain"
            )
        first = np.unique(reach, return_index=True)[1]  # the plate's advance, no stall
        load = np.interp(levels, reach[first], test.load_n[first])
        motion += [[0.0, 0.0, -c] for c in levels]
        forces += [[0.0, 0.0, -f] for f in load]
        specimen += [number] * samples
    outer = disc_grid(radius, height)
    centre = outer[GRID // 2, GRID // 2]
    k_count = len(motion)
    return Dataset(
        outer_rest=outer,
        inner_rest=disc_grid(radius, 0.0),
        forces=np.array(forces),
        contacts=np.tile(centre, (k_count, 1)),
        outer_loaded=np.full((k_count, GRID, GRID, 3), np.nan),
        plate_motion=np.array(motion),
        specimen=np.array(specimen),
        force_noise_n=force_noise(tests),
        extra={
            "specimen_names": np.array([t.name for t in tests]),
            "source": np.array(f"phantom-compression {recipe}"),
        },
    )


def compression_summary(
    recipe: str, tests: list[CompressionTest], samples: int, strain: float, dataset: Dataset
) -> str:
    """One line of what ``compression_dataset`` holds: the recipe, its tests, the
    ``samples`` points on each curve up to ``strain`` x the height [mm], and the force
    noise [N]."""
    return (
        f"{recipe}, {len(tests)} tests x {samples} points (compression to "
        f"{strain:g} x {tests[0].height_mm:g} mm); force noise "
        f"{dataset.force_noise_n:.3g} N"
    )
