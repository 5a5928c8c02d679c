"""VTK export: a well-formed unstructured grid whose data match the model."""

import builtins

import numpy as np
import pytest

from experiments.output.export import write_vtu
from experiments.phantom.forehead import forehead_model, probe_loads
from solvers.forward.equilibrium import EquilibriumSolver

meshio = pytest.importorskip("meshio", reason="the vtu extra (meshio) is not installed")


def test_vtu_holds_the_deformed_volume(tmp_path):
    model = forehead_model()
    result = EquilibriumSolver(model).solve(model.generalized_force(probe_loads(model)[1]))
    path = write_vtu(tmp_path / "deformed.vtu", model.volume, result.positions, (5, 5, 2))
    assert [p.name for p in tmp_path.iterdir()] == ["deformed.vtu"]  # no temporary left
    mesh = meshio.read(path)
    assert len(mesh.points) == 50 and mesh.cells[0].type == "hexahedron"
    assert len(mesh.cells[0].data) == 16 and mesh.cells[0].data.max() == 49
    rest = mesh.point_data["rest_position"]
    assert np.allclose(mesh.points - rest, mesh.point_data["displacement"])
    # the largest displacement sits at the skin's centre, under the probe
    centre = np.argmax(mesh.point_data["displacement_magnitude"])
    assert np.allclose(rest[centre, :2], 0.0, atol=1e-9)
    # every hexahedron has positive volume in VTK's corner order (a tetrahedron's worth)
    corners = mesh.points[mesh.cells[0].data]
    edges = corners[:, [1, 3, 4]] - corners[:, [0]]
    assert np.all(np.linalg.det(edges) > 0)


def test_without_meshio_the_error_names_the_extra(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_meshio(name, *args, **kwargs):
        if name == "meshio":
            raise ImportError("No module named 'meshio'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_meshio)
    model = forehead_model()
    with pytest.raises(ImportError, match=r"dvs\[vtu\]"):
        write_vtu(tmp_path / "x.vtu", model.volume, model.rest)
    assert not list(tmp_path.iterdir())
