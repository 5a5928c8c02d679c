"""The Truth Cube as a volume spline: its frame, its model and its load cases.

The cube (``experiments.data.truthcube``) is an 80 mm block of silicone bonded to a rigid
base and compressed by a flat plate. Its model:

- **Frame.** The model frame is the file frame turned 180 degrees about x (a proper
  rotation: x' = x - c_x, y' = -(y - c_y), z' = z_base - z), so that the base, at the
  file's largest z, is the face z' = 0 (w = 0) and the plate face is z' = 80 mm
  (w = 1). The cube is centred on the bead lattice's centre c with an 80 mm edge
  (**choice**: the beads sit about 1 cm inside the faces; the lattice's axes lie within
  1 degree of the file's, so the cube is not rotated).
- **Volume.** ``symbolic.continuum.box_volume`` with uniform knots: the geometry map
  is affine, so a bead's (u, v, w) is its rest position over the edge, exactly.
- **Boundary.** The base is bonded: the layer w = 0 is fixed (``fix_inner``). The
  plate is bonded too: a grid of points on w = 1 (more than the face has control
  points, so the whole face moves as one) has the prescribed displacement d = the
  plate's translation, all three components (``PrescribedDisplacement``).
- **Observations.** Every bead is a collocation row at its (u, v, w), observed in x, y
  and z (``LoadCase.rows``): interior points, not surface markers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from experiments.data.paths import shared_data_dir
from experiments.data.truthcube import CUBE_EDGE_MM, TruthCube, lattice_centre, read_truth_cube
from solvers.inverse.problem import LoadCase
from symbolic.constraints import BoundaryConditions
from symbolic.continuum import box_volume
from symbolic.continuum_model import ContinuumModel, NeoHookeanModel
from symbolic.loads import PrescribedDisplacement

YOUNG_KPA = 15.3
"""E [kPa], fixed: with a displacement-controlled plate and no force record the beads do
not depend on E (the value OpenSurgSim uses for RTV6166, with nu 0.499)."""

ENERGY_MODELS = {"linear": ContinuumModel, "neo-hookean": NeoHookeanModel}
"""The two energies of the study: small-strain linear elasticity and the compressible
neo-Hookean energy (docs/continuum.md, eq. C1 and C6)."""

TURN = np.diag([1.0, -1.0, -1.0])
"""File frame to model frame: 180 degrees about x (its own inverse)."""


def truth_cube_path():
    """The bead file in the shared data folder (``experiments.data.paths``)."""
    return shared_data_dir() / "truth-cube/uniaxial_positions.csv"


def load_truth_cube() -> TruthCube:
    """The Truth Cube's beads (``read_truth_cube`` of ``truth_cube_path``)."""
    return read_truth_cube(truth_cube_path())


@dataclass(frozen=True)
class CubeFrame:
    """Where the cube sits in the file frame.

    Attributes
    ----------
    origin : numpy.ndarray
        (c_x, c_y, z_base), the file-frame point that is the model's (0, 0, 0) [mm].
    edge : float
        The cube's edge [mm].
    """

    origin: np.ndarray
    edge: float = CUBE_EDGE_MM

    @classmethod
    def from_lattice(cls, rest: np.ndarray, edge: float = CUBE_EDGE_MM) -> CubeFrame:
        """The cube centred on the bead lattice's centre, base at the large-z end."""
        centre = lattice_centre(rest)
        return cls(np.array([centre[0], centre[1], centre[2] + 0.5 * edge]), float(edge))

    def to_model(self, points: np.ndarray) -> np.ndarray:
        """File-frame points (..., 3) [mm] in the model frame [mm]."""
        return (np.asarray(points, dtype=float) - self.origin) @ TURN

    def to_file(self, vectors: np.ndarray) -> np.ndarray:
        """Model-frame displacement vectors (..., 3) [mm] in the file frame."""
        return np.asarray(vectors, dtype=float) @ TURN

    def params(self, model_points: np.ndarray) -> np.ndarray:
        """(u, v, w) of model-frame points of the cube (the affine map's inverse)."""
        half = 0.5 * self.edge
        offset = np.array([half, half, 0.0])
        return (np.asarray(model_points, dtype=float) + offset) / self.edge


@dataclass(frozen=True)
class CubeSettings:
    """The discretisation of the cube.

    Attributes
    ----------
    shape : tuple of int
        Control points along x, y, z (z: base to plate).
    degree : int
        Polynomial degree in every direction.
    plate_points : int
        Prescribed points per side of the plate face (plate_points^2 in all).
    """

    shape: tuple[int, int, int] = (6, 6, 6)
    degree: int = 2
    plate_points: int = 12

    def __post_init__(self) -> None:
        if min(self.shape) <= self.degree:
            raise ValueError(f"need more than degree {self.degree} control points per axis")
        if self.plate_points < max(self.shape[:2]):
            raise ValueError("plate_points must be at least the control points per face side")


def plate_uv(points: int) -> np.ndarray:
    """A points x points grid of (u, v) on the plate face, corners included, (m, 2)."""
    side = np.linspace(0.0, 1.0, points)
    uu, vv = np.meshgrid(side, side, indexing="ij")
    return np.column_stack([uu.ravel(), vv.ravel()])


def cube_model(
    settings: CubeSettings, energy: str = "linear", nu: float = 0.45, edge: float = CUBE_EDGE_MM
):
    """The cube's model in its model frame (module docstring).

    Parameters
    ----------
    settings : CubeSettings
        Control points and degree.
    energy : {"linear", "neo-hookean"}
        The energy (``ENERGY_MODELS``).
    nu : float
        Poisson's ratio [1] (E is ``YOUNG_KPA``).
    edge : float
        The cube's edge [mm].

    Returns
    -------
    ContinuumModel or NeoHookeanModel
    """
    if energy not in ENERGY_MODELS:
        raise ValueError(f"energy must be one of {sorted(ENERGY_MODELS)}, got {energy!r}")
    half = 0.5 * edge
    degrees = (settings.degree,) * 3
    volume = box_volume((edge, edge, edge), settings.shape, degrees, (-half, -half, 0.0))
    return ENERGY_MODELS[energy](
        volume,
        {"E": YOUNG_KPA, "nu": nu},
        BoundaryConditions(fix_inner=True),
        prescribed=PrescribedDisplacement(plate_uv(settings.plate_points)),
    )


def plate_points(model) -> np.ndarray:
    """Rest positions of the prescribed points on the plate face (m, 3) [mm]."""
    volume = model.volume
    return volume.collocation(volume.outer_params(model.prescribed.uv)) @ model.rest


def plate_displacement(model, plate) -> np.ndarray:
    """d of every prescribed point, (m, 3) [mm].

    ``plate`` is the plate's translation t (3,) [mm] (a bonded plate: the face moves
    with it), or (t, b) (4,): the face also stretches laterally by b [1] about the
    cube's axis, d_i = t + b (x_i, y_i, 0) (a plate the silicone slips along, b = 0
    bonded; ``experiments.truthcube.cubefit``).
    """
    plate = np.asarray(plate, dtype=float).reshape(-1)
    count = model.prescribed.uv.shape[0]
    displacement = np.tile(plate[:3].reshape(1, 3), (count, 1))
    if plate.size == 4:
        displacement[:, :2] += plate[3] * plate_points(model)[:, :2]
    return displacement


@dataclass(frozen=True)
class CubeData:
    """The beads in the model frame.

    Attributes
    ----------
    frame : CubeFrame
        The cube's placement.
    rest : numpy.ndarray
        (N, 3) rest positions [mm].
    loaded : numpy.ndarray
        (S, N, 3) loaded positions [mm] (NaN: not located).
    params : numpy.ndarray
        (N, 3) (u, v, w) of the beads.
    labels : list of str
        One per state, e.g. "12.5 %".
    nominal_travel : numpy.ndarray
        (S,) the plate's nominal travel, compression x 80 mm [mm].
    """

    frame: CubeFrame
    rest: np.ndarray
    loaded: np.ndarray
    params: np.ndarray
    labels: list
    nominal_travel: np.ndarray

    @classmethod
    def of(cls, cube: TruthCube) -> CubeData:
        """The Truth Cube's beads placed in the model frame."""
        frame = CubeFrame.from_lattice(cube.rest)
        rest = frame.to_model(cube.rest)
        labels = [f"{100 * c:g} %" for c in cube.compression]
        params = frame.params(rest)
        if np.any(params <= 0) or np.any(params >= 1):
            raise ValueError("a bead lies outside the 80 mm cube placed on the lattice")
        travel = cube.plate_travel_mm()
        return cls(frame, rest, frame.to_model(cube.loaded), params, labels, travel)

    @property
    def displacement(self) -> np.ndarray:
        """(S, N, 3) measured bead displacements [mm]."""
        return self.loaded - self.rest[None]

    def subset(self, beads: np.ndarray) -> CubeData:
        """The same data on a selection of beads (an index array or a mask)."""
        return CubeData(
            self.frame,
            self.rest[beads],
            self.loaded[:, beads],
            self.params[beads],
            self.labels,
            self.nominal_travel,
        )


def bead_rows(model, params: np.ndarray) -> sp.csr_matrix:
    """Collocation rows J at the beads' (u, v, w) on the free control points, (N, n_free)."""
    return model.volume.collocation(np.asarray(params, dtype=float))[:, model.free].tocsr()


def load_cases(model, data: CubeData, translations: np.ndarray, states=None) -> list[LoadCase]:
    """One ``LoadCase`` per state: the plate prescribed, every located bead observed.

    Parameters
    ----------
    model : ContinuumModel
        The cube's model.
    data : CubeData
        The beads.
    translations : numpy.ndarray
        (S, 3) the plate's translation in each state, model frame [mm], or (S, 4) with
        the face's lateral stretch (``plate_displacement``).
    states : list of int, optional
        Which states (default all).
    """
    states = list(range(data.loaded.shape[0]) if states is None else states)
    rows_all = bead_rows(model, data.params)
    rest_points = model.volume.collocation(data.params) @ model.rest
    cases = []
    for k in states:
        seen = np.all(np.isfinite(data.loaded[k]), axis=1)
        cases.append(
            LoadCase(
                force=np.zeros((model.n_free, 3)),
                rows=rows_all[seen],
                offset=rest_points[seen] - data.loaded[k][seen],
                weights=np.ones(int(seen.sum())),
                prescribed=plate_displacement(model, translations[k]),
                rest_points=rest_points[seen],
                label=data.labels[k],
                marker_index=np.flatnonzero(seen),
            )
        )
    return cases


def lattice_scatter(cube_index: np.ndarray, rest: np.ndarray, order: int = 2) -> np.ndarray:
    """RMS scatter [mm] per component of the rest beads about a smooth map of the bead
    index: a polynomial of total degree ``order`` in (i, j, k) fitted by least squares,
    its residual's RMS with the fitted coefficients' degrees of freedom removed, (3,).

    This is bead placement in the cast plus CT localisation: an upper bound on the
    localisation noise of a bead coordinate.
    """
    index = np.asarray(cube_index, dtype=float)
    index = (index - index.mean(axis=0)) / max(index.std(), 1e-12)
    columns = [np.ones(len(index))]
    for i in range(3):
        columns.append(index[:, i])
    if order >= 2:
        for i in range(3):
            for j in range(i, 3):
                columns.append(index[:, i] * index[:, j])
    design = np.column_stack(columns)
    coefficients, *_ = np.linalg.lstsq(design, rest, rcond=None)
    residual = rest - design @ coefficients
    dof = len(index) - design.shape[1]
    return np.sqrt(np.sum(residual**2, axis=0) / dof)
