"""Data from physics the effect library does not contain: a linear-elastic FE slab.

The generator shares nothing with the spline model but the phantom's shape
and the measurement:

- geometry: the forehead phantom's layer (a 40 x 40 mm patch of a sphere of
  radius 80 mm, 5 mm thick), meshed by 16 x 16 x 4 trilinear hexahedra;
- physics: a stiff skin (E = 0.3 MPa, 1.25 mm) on soft fat (E = 0.003 MPa),
  isotropic linear elasticity with Poisson's ratio 0.45, trilinear hexahedra
  assembled by scikit-fem (the ``fe`` extra; it replaced a hand-written assembly
  and reproduces its displacements to rounding), with the inner surface fixed and
  the lateral faces free; the
  probe is a Gaussian traction of standard deviation 0.5 mm around the
  contact (a 1 mm tip: the point force the dataset declares), lumped to the
  skin nodes;
- markers: the 9 x 9 skin nodes every second node, measured as
  ``experiments.phantom.simulate`` does (noise on rest and loaded markers, occlusion,
  random losses).

The spline model's energy (eq. 18) is anisotropic in parameter space, has no
layers, no Poisson coupling and no shear between components; the continuum
has all of these (the stiff skin on soft fat acts as a plate on a foundation
and spreads the load far). The moduli give a marker displacement RMS of
0.15 mm under 0.25 N, like the phantom's 0.14 mm.

Run as ``python -m experiments.diagnosis.outoflibrary --out FILE.npz``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.command.options import Command
from experiments.data.dataset import Dataset, save_dataset
from experiments.phantom.fe import require_skfem
from experiments.phantom.simulate import SimulationSettings
from solvers.linalg.cholmod import factorised, symmetric_lu
from symbolic.continuum import KPA, lame


@dataclass(frozen=True)
class SlabSettings:
    """The FE slab (lengths in mm, forces in N, moduli in N/mm^2 = MPa).

    Attributes
    ----------
    width, curvature_radius, thickness : float
        Geometry of the phantom's layer.
    elements : tuple of int
        Hexahedra along x, y and through the thickness; x and y counts must be
        multiples of ``markers - 1``.
    markers : int
        Markers per direction (every ``elements / (markers - 1)``-th skin node).
    young, poisson : float
        Young's modulus of the fat [N/mm^2] and Poisson's ratio of both layers.
    skin_young : float
        Young's modulus of the skin, the outermost ``skin_layers`` element
        layers [N/mm^2]. The stiff skin on soft fat spreads the probe's load as
        the phantom's large alpha_u does.
    skin_layers : int
        Element layers of skin (1 of 4: 1.25 mm).
    forces : tuple of float
        Probe forces along the inward normal at the centre [N].
    spread : float
        Standard deviation of the Gaussian traction of the probe [mm].
    contacts : tuple of (u, v), optional
        Contact points as fractions of the patch (x = (u - 1/2) width, y likewise);
        every one is loaded with each force (contact-major order). Default: the
        centre only (the paper's experiment).
    tilt_deg : float
        Forces after the first at a contact lean this far from the normal, away
        from the patch centre (along x at the centre), as
        ``experiments.phantom.designs.design_loads`` does for the phantom.
    """

    width: float = 40.0
    curvature_radius: float = 80.0
    thickness: float = 5.0
    elements: tuple[int, int, int] = (16, 16, 4)
    markers: int = 9
    young: float = 0.003
    poisson: float = 0.45
    skin_young: float = 0.3
    skin_layers: int = 1
    forces: tuple[float, ...] = (0.17, 0.25)
    spread: float = 0.5
    contacts: tuple[tuple[float, float], ...] | None = None
    tilt_deg: float = 0.0

    def __post_init__(self) -> None:
        nx, ny, nz = self.elements
        if min(self.elements) < 1 or nx % (self.markers - 1) or ny % (self.markers - 1):
            raise ValueError("elements along x and y must be multiples of markers - 1")
        if not (0 < self.poisson < 0.5) or self.young <= 0:
            raise ValueError("need E > 0 and 0 < nu < 0.5")


def slab_nodes(settings: SlabSettings) -> np.ndarray:
    """Node positions, shape (nx+1, ny+1, nz+1, 3) [mm]; layer 0 is the inner surface."""
    nx, ny, nz = settings.elements
    half, radius = 0.5 * settings.width, settings.curvature_radius
    x, y = np.meshgrid(
        np.linspace(-half, half, nx + 1), np.linspace(-half, half, ny + 1), indexing="ij"
    )
    outer = np.stack([x, y, np.sqrt(radius**2 - x**2 - y**2) - radius], axis=-1)
    center = np.array([0.0, 0.0, -radius])
    inner = center + (outer - center) * (radius - settings.thickness) / radius
    t = np.linspace(0.0, 1.0, nz + 1)
    return inner[:, :, None, :] + t[None, None, :, None] * (outer - inner)[:, :, None, :]


def _mesh(settings: SlabSettings):
    """scikit-fem hexahedra of the layer and, per structured node (i, j, k), its mesh node.

    A tensor mesh of the reference box [0, nx] x [0, ny] x [0, nz] is mapped node by node
    onto ``slab_nodes``; the element connectivity is scikit-fem's.
    """
    skfem = require_skfem()
    nx, ny, nz = settings.elements
    box = skfem.MeshHex.init_tensor(np.arange(nx + 1.0), np.arange(ny + 1.0), np.arange(nz + 1.0))
    index = np.rint(box.p).astype(int)  # (3, n_nodes): the structured index of each node
    nodes = slab_nodes(settings)
    mesh = skfem.MeshHex(nodes[index[0], index[1], index[2]].T.copy(), box.t)
    order = np.empty(nodes.shape[:3], dtype=int)
    order[index[0], index[1], index[2]] = np.arange(index.shape[1])
    return mesh, order


def slab_loads(settings: SlabSettings) -> list[tuple[np.ndarray, np.ndarray]]:
    """(contact point [mm], force vector [N]) of every load case."""
    radius, center = settings.curvature_radius, np.array([0.0, 0.0, -settings.curvature_radius])
    loads = []
    for u, v in settings.contacts or ((0.5, 0.5),):
        x, y = (u - 0.5) * settings.width, (v - 0.5) * settings.width
        contact = np.array([x, y, np.sqrt(radius**2 - x**2 - y**2) - radius])
        normal = (contact - center) / radius
        away = np.array([x, y, 0.0]) if abs(x) + abs(y) > 1e-9 else np.array([1.0, 0.0, 0.0])
        away -= (away @ normal) * normal
        away /= np.linalg.norm(away)
        angle = np.radians(settings.tilt_deg)
        for k, size in enumerate(settings.forces):
            direction = -normal if k == 0 else -np.cos(angle) * normal + np.sin(angle) * away
            loads.append((contact, size * direction))
    return loads


def solve_slab(settings: SlabSettings) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Rest nodes (nx+1, ny+1, nz+1, 3), displacements per load case, and the contacts [mm].

    Trilinear hexahedra assembled by scikit-fem (isotropic linear elasticity with the
    skin's modulus in its outer element layers); the contacts are (K, 3), one row
    per load case (``slab_loads``).
    """
    skfem = require_skfem()
    from skfem.helpers import ddot, div, sym_grad

    mesh, order = _mesh(settings)
    nodes = slab_nodes(settings)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementHex1()))
    centre = np.array([0.0, 0.0, -settings.curvature_radius])[:, None, None]
    skin_depth = settings.thickness * settings.skin_layers / settings.elements[2]

    @skfem.BilinearForm
    def elasticity(u, v, w):
        depth = settings.curvature_radius - np.linalg.norm(w.x - centre, axis=0)
        young = np.where(depth < skin_depth, settings.skin_young, settings.young)  # N/mm^2
        mu_l, lam = lame(young / KPA, settings.poisson)
        return 2.0 * mu_l * ddot(sym_grad(u), sym_grad(v)) + lam * div(u) * div(v)

    matrix = elasticity.assemble(basis)
    fixed = basis.nodal_dofs[:, order[:, :, 0].ravel()].ravel()
    free = basis.complement_dofs(fixed)
    factor = factorised(matrix[free][:, free].tocsc(), symmetric_lu)  # SPD
    skin_nodes = order[:, :, -1].ravel()
    skin = nodes[:, :, -1].reshape(-1, 3)
    results, contacts = [], []
    for contact, force in slab_loads(settings):
        weights = np.exp(-np.sum((skin - contact) ** 2, axis=1) / (2 * settings.spread**2))
        weights /= weights.sum()
        load = np.zeros(basis.N)
        for k in range(3):
            load[basis.nodal_dofs[k, skin_nodes]] = force[k] * weights
        solution = np.zeros(basis.N)
        solution[free] = factor.solve(load[free])
        displacement = solution[basis.nodal_dofs].T[order]  # (nx+1, ny+1, nz+1, 3)
        results.append(displacement)
        contacts.append(contact)
    return nodes, results, np.array(contacts)


def simulate_slab(
    settings: SlabSettings | None = None,
    noise_mm: float = 0.02,
    seed: int = 0,
    missing_fraction: float = 0.03,
) -> Dataset:
    """A dataset v1 of the FE slab, measured like ``experiments.phantom.simulate``."""
    from experiments.phantom.simulate import measured_dataset

    settings = settings or SlabSettings()
    nodes, displacements, contacts = solve_slab(settings)
    step = settings.elements[0] // (settings.markers - 1)
    pick = (
        slice(None, None, step),
        slice(None, None, settings.elements[1] // (settings.markers - 1)),
    )
    rest = nodes[pick][:, :, -1].reshape(-1, 3)
    inner = nodes[pick][:, :, 0].reshape(-1, 3)
    positions = [rest + d[pick][:, :, -1].reshape(-1, 3) for d in displacements]
    forces = np.array([force for _, force in slab_loads(settings)])
    measurement = SimulationSettings(
        noise_mm=noise_mm, seed=seed, missing_fraction=missing_fraction
    )
    return measured_dataset(
        rest,
        inner,
        positions,
        forces,
        contacts,
        measurement,
        (settings.markers, settings.markers),
    )


def build_parser(prog: str = "python -m experiments.diagnosis.outoflibrary"):
    """The options of ``dvs study outoflibrary``."""
    from experiments.command.options import make_parser
    from experiments.phantom.simulate import add_simulation_arguments

    parser = make_parser(prog, __doc__.splitlines()[0])
    add_simulation_arguments(parser)
    return parser


def work(args) -> int:
    """``dvs study outoflibrary --out FILE.npz [--noise MM] [--seed N]``: a dataset v1."""
    from experiments.command.options import plural
    from experiments.phantom.simulate import check_simulation_arguments

    check_simulation_arguments(args)
    print("solving the linear-elastic FE slab under every load", flush=True)
    dataset = simulate_slab(noise_mm=args.noise, seed=args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_dataset(args.out, dataset)
    print(f"wrote {args.out}: FE slab, {plural(dataset.n_loads, 'load case')}")
    return 0


main = Command("experiments.diagnosis.outoflibrary", build_parser, work).main


if __name__ == "__main__":
    raise SystemExit(main())
