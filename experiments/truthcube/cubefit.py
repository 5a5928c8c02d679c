"""Poisson's ratio and the plate from the beads (Gauss-Newton, exact sensitivities).

The unknowns are p = [nu; t_1; ...; t_S], t_k the plate's translation in state k (3,)
[mm, model frame], and with ``slip`` also the plate face's lateral stretch b_k [1] in
each state (``cubemodel.plate_displacement``: d_i = t_k + b_k (x_i, y_i, 0)). E is
fixed (``cubemodel.YOUNG_KPA``): with the plate's displacement prescribed and no force
measured, the beads do not depend on it. The residual is the model's bead positions
minus the measured ones, every located bead in x, y and z,

    r_k(p) = S B_k(nu, t_k, b_k) - Y_k,      g(s_k; nu, d(t_k, b_k)) = 0,

with B_k from the model's equilibrium (``EquilibriumSolver``: the linear model in one
solve, the neo-Hookean one by Newton). Sensitivities by the implicit function theorem,
ds/dp = -(dg/ds)^-1 dg/dp: dg/dt is the constant constraint block -(I3 (x) Q 1) (the
plate moves all prescribed points alike), dg/db the same block on the points' (x_i,
y_i, 0), dg/dnu a central difference of g at the solution (g is smooth in nu).
``scipy.optimize.least_squares`` (trf) minimises |r|^2 within nu in [``NU_BOUNDS``].

**Choice**: the plate's translation is a nuisance estimated from the beads (three
numbers per state), not its nominal travel 0.05-0.1825 x 80 mm: the beads one layer
below the plate already move more than the nominal travel (measured: 4.3 mm at 5 %,
nominal 4.0 mm), and the layers drift along y by up to 1.9 mm with the base's layer
still (a lateral plate motion, not a registration offset).

**Slip.** The model prescribes all three components of d on the plate's points; a
frictionless plate (z alone prescribed) it cannot state. The stretch b is the honest
stand-in: a plate face that expands laterally and uniformly, b = 0 the bonded plate.
A frictionless plate's face would expand non-uniformly; b measures how far the data
are from the bonded plate, not a friction law.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from experiments.truthcube.cubemodel import (
    CubeData,
    bead_rows,
    plate_displacement,
    plate_points,
)
from solvers.forward.equilibrium import EquilibriumError, EquilibriumSolver, NewtonSettings

NU_BOUNDS = (0.3, 0.4999)
"""The range of Poisson's ratio searched [1]."""
NU_STEP = 1e-6
"""Half-width of the central difference of g in nu [1]."""


@dataclass
class CubeFit:
    """A fit of nu and the plate's translations.

    Attributes
    ----------
    nu : float
        Poisson's ratio [1].
    nu_se : float
        Its standard error [1]: sqrt(s^2 (J^T J)^-1) with s^2 = |r|^2 / (n - k) (the
        residual is taken as independent noise; it is partly model error).
    translations : numpy.ndarray
        (S, 3) plate translations of the fitted states [mm, model frame]; (S, 4) with
        the lateral stretch b [1] of a slipping plate.
    translation_se : numpy.ndarray
        Their standard errors, same shape.
    rms_mm : list of float
        RMS bead distance |S B - Y| of each fitted state [mm].
    states : list of int
        The fitted states.
    evaluations : int
        Residual evaluations of the fit.
    errors : list of numpy.ndarray
        Per state, model minus measured bead positions (N_k, 3) [mm].
    """

    nu: float
    nu_se: float
    translations: np.ndarray
    translation_se: np.ndarray
    rms_mm: list
    states: list
    evaluations: int
    errors: list = field(default_factory=list, repr=False)


def rms(errors: np.ndarray) -> float:
    """RMS bead distance [mm] of (N, 3) position errors."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(errors) ** 2, axis=1))))


class CubeSolver:
    """Bead positions and their sensitivities for one model and the data's beads.

    Parameters
    ----------
    model : ContinuumModel or NeoHookeanModel
        The cube's model (``cubemodel.cube_model``).
    data : CubeData
        The beads.
    slip : bool
        The plate face may stretch laterally (b, a fourth plate parameter per state).
    """

    def __init__(self, model, data: CubeData, slip: bool = False):
        self.model = model
        self.data = data
        self.solver = EquilibriumSolver(model, ("nu",), NewtonSettings(tolerance=1e-10))
        self.rows = bead_rows(model, data.params)
        self.rest_points = model.volume.collocation(data.params) @ model.rest
        n_free, r = model.n_free, model.n_constraints
        self.n_free = n_free
        plate = model._constraint_rows @ np.ones(model.prescribed.uv.shape[0])
        self.width = 4 if slip else 3
        """Plate parameters per state: t (3), and b with ``slip``."""
        self.plate = np.zeros((3 * (n_free + r), self.width))
        for c in range(3):
            self.plate[3 * n_free + c * r : 3 * n_free + (c + 1) * r, c] = -plate
        if slip:
            points = plate_points(model)
            for c in range(2):
                rows = model._constraint_rows @ points[:, c]
                self.plate[3 * n_free + c * r : 3 * n_free + (c + 1) * r, 3] = -rows
        self._starts: dict = {}

    def equilibrium(self, nu: float, translation: np.ndarray, key=None):
        """The equilibrium at nu with the plate moved by ``translation`` (3,) [mm]."""
        force = np.zeros((self.model.n_free, 3))
        prescribed = plate_displacement(self.model, translation)
        start = self._starts.get(key)
        try:
            solution = self.solver.solve(force, [nu], prescribed, start=start)
        except EquilibriumError:  # a poor start: from rest by load continuation
            solution = self.solver.solve_by_continuation(force, [nu], prescribed)
        if key is not None:
            self._starts[key] = solution.state
        return solution

    def positions(self, solution) -> np.ndarray:
        """Bead positions S B (N, 3) [mm] of an equilibrium."""
        delta = solution.state[: 3 * self.n_free].reshape(3, -1).T
        return self.rest_points + self.rows @ delta

    def sensitivities(self, solution, nu: float, translation: np.ndarray) -> np.ndarray:
        """d vec(S B) / d[nu, plate] (3 N, 1 + width): rows the x, y, z blocks of the beads."""
        args = (np.zeros((self.model.n_free, 3)), plate_displacement(self.model, translation))
        g = self.solver.residual  # the continua never take the componentwise path
        up = g(solution.state, [nu + NU_STEP], *args).full().ravel()
        down = g(solution.state, [nu - NU_STEP], *args).full().ravel()
        dg_dp = np.column_stack([(up - down) / (2 * NU_STEP), self.plate])
        ds_dp = -solution.solve(dg_dp)
        observe = sp.kron(sp.identity(3), self.rows).tocsr()
        return observe @ ds_dp[: 3 * self.n_free]


def fit_cube(
    solver: CubeSolver,
    states=None,
    nu0: float = 0.45,
    translations0: np.ndarray | None = None,
    fixed_nu: float | None = None,
    beads: np.ndarray | None = None,
) -> CubeFit:
    """Fit nu and the plate translations of ``states`` to the beads (module docstring).

    Parameters
    ----------
    solver : CubeSolver
        The model and beads.
    states : list of int, optional
        The states fitted (default all).
    nu0 : float
        Start of nu [1].
    translations0 : numpy.ndarray, optional
        (S_all, 3) or (S_all, width) start plate parameters [mm]; default the nominal
        travel along -z.
    fixed_nu : float, optional
        Hold nu at this value and fit the translations alone (a held-out state).
    beads : numpy.ndarray, optional
        (N,) bool: fit these beads alone (default every located bead); ``errors`` and
        ``rms_mm`` are then theirs.
    """
    data = solver.data
    states = list(range(data.loaded.shape[0]) if states is None else states)
    if translations0 is None:
        translations0 = np.outer(data.nominal_travel, [0.0, 0.0, -1.0])
    width = solver.width
    translations0 = np.asarray(translations0, dtype=float)
    if translations0.shape[1] < width:
        translations0 = np.column_stack([translations0, np.zeros(len(translations0))])
    translations0 = translations0[:, :width]
    chosen = np.ones(data.rest.shape[0], bool) if beads is None else np.asarray(beads, bool)
    seen = [np.all(np.isfinite(data.loaded[k]), axis=1) & chosen for k in states]
    free_nu = fixed_nu is None
    cache: dict = {}

    def unpack(p):
        nu = float(p[0]) if free_nu else float(fixed_nu)
        t = np.asarray(p[1:] if free_nu else p).reshape(-1, width)
        return nu, t

    def evaluate(p):
        key = tuple(np.round(p, 14))
        if key not in cache:
            cache.clear()
            nu, t = unpack(p)
            residuals, blocks, errors = [], [], []
            for j, k in enumerate(states):
                solution = solver.equilibrium(nu, t[j], key=k)
                error = (solver.positions(solution) - data.loaded[k])[seen[j]]
                errors.append(error)
                residuals.append(error.T.reshape(-1))
                jac = solver.sensitivities(solution, nu, t[j])
                mask = np.tile(seen[j], 3)
                blocks.append(jac[mask])
            cache[key] = (np.concatenate(residuals), blocks, errors)
        return cache[key]

    def residual(p):
        return evaluate(p)[0]

    def jacobian(p):
        blocks = evaluate(p)[1]
        rows = sum(b.shape[0] for b in blocks)
        columns = (1 if free_nu else 0) + width * len(states)
        out = np.zeros((rows, columns))
        at = 0
        for j, block in enumerate(blocks):
            size = block.shape[0]
            if free_nu:
                out[at : at + size, 0] = block[:, 0]
            start = (1 if free_nu else 0) + width * j
            out[at : at + size, start : start + width] = block[:, 1:]
            at += size
        return out

    t0 = translations0[states].reshape(-1)
    p0 = np.concatenate([[nu0], t0]) if free_nu else t0
    lower = np.full(p0.size, -np.inf)
    upper = np.full(p0.size, np.inf)
    if free_nu:
        lower[0], upper[0] = NU_BOUNDS
        p0[0] = float(np.clip(nu0, *NU_BOUNDS))
    result = least_squares(
        residual, p0, jac=jacobian, bounds=(lower, upper), method="trf", x_scale="jac"
    )
    r, jac = residual(result.x), jacobian(result.x)
    errors = evaluate(result.x)[2]
    s2 = float(r @ r) / max(r.size - p0.size, 1)
    covariance = s2 * np.linalg.pinv(jac.T @ jac)
    se = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    nu, t = unpack(result.x)
    return CubeFit(
        nu=nu,
        nu_se=float(se[0]) if free_nu else 0.0,
        translations=t,
        translation_se=(se[1:] if free_nu else se).reshape(-1, width),
        rms_mm=[rms(e) for e in errors],
        states=states,
        evaluations=int(result.nfev),
        errors=errors,
    )


def predict_state(solver: CubeSolver, nu: float, translation: np.ndarray, state: int):
    """Model minus measured bead positions (N_seen, 3) [mm] of one state at nu and a
    given plate translation, and their RMS distance [mm]."""
    solution = solver.equilibrium(nu, translation, key=state)
    seen = np.all(np.isfinite(solver.data.loaded[state]), axis=1)
    error = (solver.positions(solution) - solver.data.loaded[state])[seen]
    return error, rms(error)


def extrapolated_translation(fit: CubeFit, nominal: np.ndarray, state: int) -> np.ndarray:
    """The plate parameters of a state not fitted, from the fitted ones: each one
    proportional to the nominal travel, the ratio their least-squares one through 0."""
    travel = np.asarray(nominal, dtype=float)[fit.states]
    ratio = (travel @ fit.translations) / float(travel @ travel)
    return ratio * float(nominal[state])


def layer_bulge(rest: np.ndarray, moved: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """The lateral expansion of each bead layer: the least-squares slope b of
    u_h - mean(u_h) = b (x_h - mean(x_h)) over the layer's beads, x_h and u_h their
    horizontal rest positions and displacements [mm] (a layer's mean lateral shift, the
    plate's drift, removed), per layer in increasing order of ``layer`` [1].

    A plate bonded to the silicone holds the layer next to it from expanding; a sliding
    plate lets it expand as much as the middle of the cube.
    """
    out = []
    for value in np.unique(layer):
        chosen = (layer == value) & np.all(np.isfinite(moved), axis=1)
        x = rest[chosen, :2] - rest[chosen, :2].mean(axis=0)
        u = moved[chosen, :2] - rest[chosen, :2]
        u = u - u.mean(axis=0)
        out.append(float(np.sum(u * x) / np.sum(x * x)))
    return np.array(out)
