"""VTK export: a well-formed unstructured grid whose data match the model."""

import xml.etree.ElementTree as ElementTree

import numpy as np

from experiments.export import write_vtu
from experiments.phantom.forehead import forehead_model, probe_loads
from solvers.equilibrium import EquilibriumSolver


def test_vtu_holds_the_deformed_volume(tmp_path):
    model = forehead_model()
    result = EquilibriumSolver(model).solve(model.generalized_force(probe_loads(model)[1]))
    path = write_vtu(tmp_path / "deformed.vtu", model.volume, result.positions, (5, 5, 2))
    piece = ElementTree.parse(path).getroot().find("UnstructuredGrid/Piece")
    assert piece.get("NumberOfPoints") == "50" and piece.get("NumberOfCells") == "16"
    arrays = {a.get("Name"): np.array(a.text.split(), dtype=float) for a in piece.iter("DataArray")}
    points = arrays["Points"].reshape(-1, 3)
    rest = arrays["rest_position"].reshape(-1, 3)
    assert np.allclose(points - rest, arrays["displacement"].reshape(-1, 3))
    assert arrays["connectivity"].max() == 49 and np.all(arrays["types"] == 12)
    # the largest displacement sits at the skin's centre, under the probe
    centre = np.argmax(arrays["displacement_magnitude"])
    assert np.allclose(rest[centre, :2], 0.0, atol=1e-9)
