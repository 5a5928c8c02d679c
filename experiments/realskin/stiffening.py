"""Strain stiffening on the authors' planar model, fitted on every frame to the full travel.

The authors' set-up (``experiments.realskin.planar``: plane strain, free outer edges, the
.geo pads as holes, the force as the traction integral over the moving pad's edges), but

* **frames**: every synchronised DIC frame up to the full travel (healthy 49 frames to
  3.82 mm, keloid 85 frames to 4.12 mm), not their ten up to 3 (or 2) mm;
* **energy**: the neo-Hookean one, p = (E, nu), then the stiffening one of
  ``symbolic.planar_stiffening``, p = (E, nu, k1, k2);
* **cost**: whitened least squares, J = 1/2 |r|^2 with

      r = [ (I u_t - u_dic,t) / sigma_u ,  (F_x(u_t) - f_t) / sigma_f ],

  I the P1 interpolation at the non-spurious DIC points, sigma_u the DIC noise of
  ``experiments.realskin.data.dic_noise_mm`` (spatial, median over frames) and sigma_f
  the force record's scatter (``force_noise_n``: standard deviation of its residual about
  a quadratic Savitzky-Golay fit over 31 samples). The authors' cost (mm^4 against N^2)
  makes the force negligible; here both blocks are in units of their noise.
* **keloid**: two materials, as ``experiments.realskin.reproduce``: the keloid's
  triangles fitted, the skin around held at the healthy fit of the same energy.

Fit: scipy's trust-region least squares on z = (ln E, nu, ln k1, ln k2), nu in
[-0.9, 0.499], with the exact Jacobian from direct sensitivities.

Run: ``python -c "from experiments.realskin.stiffening import stiffening_study;
stiffening_study('/tmp/out')"``; it writes ``stiffening.json``, ``stiffening.md`` and
``stiffening_force.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from experiments.atomic import atomic_write_json, atomic_write_text
from experiments.realskin import authors
from experiments.realskin.data import dic_noise_mm
from experiments.realskin.planar import Assumptions, Extensometer, Solution
from experiments.realskin.reproduce import Fit, least_squares_fit, measured, mesh_for
from symbolic.planar_stiffening import NAMES, PlanarStiffening

FULL_TRAVEL_MM = 10.0
"""Frames up to this travel: every synchronised DIC frame of both cases."""

START_NH = {"healthy": (0.03, 0.2), "keloid": (0.12, 0.38)}
"""Neo-Hookean start values (E [N/mm], nu)."""

MESH_SIZE_MM = 1.0
"""Element size around the pads and the gap [mm] (4x elsewhere), as ``reproduce``."""


def force_noise_n(case) -> float:
    """sigma_f [N]: std of the force record about a 31-sample quadratic Savitzky-Golay fit."""
    force = np.asarray(case.force_fx_n, dtype=float)
    return float(np.std(force - savgol_filter(force, 31, 2)))


class WhitenedExtensometer(Extensometer):
    """The authors' forward problem with the stiffening energy and the whitened cost.

    Parameters
    ----------
    mesh, frames, fitted_region, held
        As ``planar.Extensometer`` (authors' assumptions); ``held`` is (E, nu, k1, k2).
    n_parameters : {2, 4}
        2: p = (E, nu) with k1 = 0 (neo-Hookean); 4: p = (E, nu, k1, k2).
    sigma_u, sigma_f : float
        DIC noise [mm] and force noise [N].
    keep : ndarray of bool (P,)
        The DIC points used (the non-spurious ones).
    """

    def __init__(self, mesh, frames, n_parameters, sigma_u, sigma_f, keep, region=None, held=None):
        super().__init__(mesh, frames, Assumptions(), fitted_region=region, held=held)
        self.model = PlanarStiffening(mesh.points, mesh.triangles)
        self.n_parameters, self.sigma_u, self.sigma_f = n_parameters, sigma_u, sigma_f
        self.points = self.interpolation[keep]
        self.observed = frames.dic_displacement_mm[:, keep]

    def full(self, p) -> np.ndarray:
        """(E, nu, k1, k2) of p (k1 = 0, k2 = 1 when p = (E, nu))."""
        p = np.asarray(p, dtype=float)
        return p if len(p) == 4 else np.array([p[0], p[1], 0.0, 1.0])

    def set_parameters(self, p) -> None:
        """The fitted material's parameters; the held ones elsewhere."""
        p = self.full(p)
        if self.held is None:
            self.model.set_parameters(*p)
            return
        fitted = self.weights > 0
        self.model.set_parameters(*[np.where(fitted, a, b) for a, b in zip(p, self.held)])

    def solve(self, p, sensitivities: bool = True, previous=None) -> Solution:
        """Every frame's equilibrium in order (continuation), with du/dp and dF/dp."""
        p = np.asarray(p, dtype=float)
        self.set_parameters(p)
        n, size = self.n_parameters, 2 * self.mesh.n_nodes
        u = np.zeros(size)
        states, forces, sens, force_d, iterations = [], [], [], [], []
        for target in self.targets():
            u, stiffness, factor, its = self._frame(u, target)
            states.append(u.copy())
            forces.append(self.force(u))
            iterations.append(its)
            if sensitivities:
                by_p = self.model.residual_derivatives(u, self.weights)[:, :n]
                s = np.zeros((size, n))
                s[self.free] = -factor.solve(by_p[self.free])
                sens.append(s)
                by_u, by_p_edge = self.model.edge_force_derivatives(
                    u, self.normals, self.mesh.moving_owner, self.weights
                )
                force_d.append(by_u[0] @ s + by_p_edge[0, :n])
        return Solution(
            p, np.array(states), np.array(forces),
            np.array(sens) if sensitivities else None,
            np.array(force_d) if sensitivities else None, iterations,
        )  # fmt: skip

    def at_points(self, solution: Solution) -> np.ndarray:
        """Model displacements at the kept DIC points (K, P, 2) [mm]."""
        return np.stack([self.points @ u.reshape(-1, 2) for u in solution.u])

    def residuals(self, solution: Solution) -> np.ndarray:
        """Whitened r: displacement misfit / sigma_u, then force misfit / sigma_f."""
        field = (self.at_points(solution) - self.observed) / self.sigma_u
        force = (solution.force - self.frames.force_n) / self.sigma_f
        return np.concatenate([field.ravel(), force])

    def jacobian(self, solution: Solution) -> np.ndarray:
        """dr/dp (len r, n) from the sensitivities."""
        n = self.n_parameters
        field = [
            (self.points @ s.reshape(-1, 2 * n)).reshape(-1, 2, n) for s in solution.sensitivity
        ]
        field = np.stack(field).reshape(-1, n) / self.sigma_u
        return np.vstack([field, solution.force_derivative / self.sigma_f])

    def measures(self, solution: Solution) -> dict:
        """RMS displacement [mm] (DIC points, both components) and RMS force [N]."""
        miss = solution.force - self.frames.force_n
        d = self.at_points(solution) - self.observed
        r = self.residuals(solution)
        return {
            "rms_displacement_mm": float(np.sqrt(np.mean(d**2))),
            "rms_force_n": float(np.sqrt(np.mean(miss**2))),
            "cost": 0.5 * float(r @ r),
        }


def fit(problem: WhitenedExtensometer, start, max_evaluations: int = 100) -> Fit:
    """Trust-region least squares on z = (ln E, nu[, ln k1, ln k2]) with the exact
    Jacobian (``reproduce.least_squares_fit``; each solve from rest)."""
    log = np.arange(len(start)) != 1
    return least_squares_fit(
        lambda p, previous: problem.solve(p), problem, start, log, problem.measures,
        (RuntimeError, ArithmeticError, ValueError), ftol=1e-8, max_evaluations=max_evaluations,
    )  # fmt: skip


def problem_for(case: str, n_parameters: int, held=None, mesh_size: float = MESH_SIZE_MM):
    """The whitened problem of a case on every frame (keloid: region 1, ``held`` around)."""
    data = measured(case)
    frames = authors.load_frames(data, FULL_TRAVEL_MM, count=10_000)
    keep = ~np.asarray(data.spurious, dtype=bool)
    region = 1 if case == "keloid" else None
    return WhitenedExtensometer(
        mesh_for(case, mesh_size, None), frames, n_parameters, dic_noise_mm(data),
        force_noise_n(data), keep, region=region, held=held,
    )  # fmt: skip


def row(case: str, energy: str, result: Fit, problem: WhitenedExtensometer) -> dict:
    """One fit as a JSON row."""
    names = NAMES[: len(result.x)]
    return {
        "case": case,
        "energy": energy,
        "parameters": dict(zip(names, map(float, result.x))),
        **result.measures,
        "evaluations": result.evaluations,
        "seconds": result.seconds,
        "message": result.message,
        "success": result.success,
        "sigma_u_mm": problem.sigma_u,
        "sigma_f_n": problem.sigma_f,
        "frames": len(problem.frames.indices),
        "travel_mm": (-problem.frames.pad_ux_mm).tolist(),
        "force_measured_n": problem.frames.force_n.tolist(),
        "force_model_n": result.solution.force.tolist(),
    }


def stiffening_study(out_dir, log=print, mesh_size: float = MESH_SIZE_MM) -> dict:
    """Fit both energies on both cases; write JSON, the markdown table and the figure.

    Healthy first (its fits are the skin held around the keloid), then the keloid.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows, held = [], {}
    for case in ("healthy", "keloid"):
        previous = None
        for energy, n in (("neo-Hookean", 2), ("stiffening", 4)):
            skin = held.get(energy) if case == "keloid" else None
            problem = problem_for(case, n, skin, mesh_size)
            if previous is None:
                start = START_NH[case]
            else:  # from the neo-Hookean fit, a small stiffening term
                start = (*previous.x, 0.1 * previous.x[0], 1.0)
            result = fit(problem, start)
            previous = result
            if case == "healthy":
                held[energy] = tuple(problem.full(result.x))
            rows.append(row(case, energy, result, problem))
            log(
                f"{case} {energy}: "
                + ", ".join(f"{k} {v:.4g}" for k, v in rows[-1]["parameters"].items())
                + f"; RMS force {result.measures['rms_force_n']:.4f} N, displacement "
                f"{result.measures['rms_displacement_mm']:.4f} mm; {result.evaluations} "
                f"evaluations, {result.seconds:.1f} s"
            )
    report = {"rows": rows, "mesh_size_mm": mesh_size, "keloid": "two materials"}
    atomic_write_json(out / "stiffening.json", report)
    atomic_write_text(out / "stiffening.md", table(rows))
    figure(rows, out / "stiffening_force.png")
    return report


def table(rows: list[dict]) -> str:
    """The before/after table (markdown)."""
    lines = [
        "| case | energy | E [N/mm] | nu | k1 [N/mm] | k2 | RMS force [N] | RMS displacement [mm] "
        "| sigma_u [mm] | sigma_f [N] | frames | time [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = r["parameters"]
        k1 = f"{p['k1']:.4g}" if "k1" in p else "0"
        k2 = f"{p['k2']:.4g}" if "k2" in p else "-"
        lines.append(
            f"| {r['case']} | {r['energy']} | {p['E']:.4g} | {p['nu']:.3f} | {k1} | {k2} | "
            f"{r['rms_force_n']:.4f} | {r['rms_displacement_mm']:.4f} | {r['sigma_u_mm']:.4f} | "
            f"{r['sigma_f_n']:.2g} | {r['frames']} | {r['seconds']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def figure(rows: list[dict], path) -> None:
    """Force against pad travel per case: measured and both fitted energies."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(dict.fromkeys(r["case"] for r in rows))
    fig, axes = plt.subplots(1, len(cases), figsize=(5 * len(cases), 4), squeeze=False)
    for ax, case in zip(axes[0], cases):
        chosen = [r for r in rows if r["case"] == case]
        travel = np.array(chosen[0]["travel_mm"])
        ax.plot(travel, -np.array(chosen[0]["force_measured_n"]), "k.", label="measured")
        for r, style in zip(chosen, ("C0-", "C3-")):
            ax.plot(travel, -np.array(r["force_model_n"]), style, label=r["energy"])
        ax.set(title=case, xlabel="pad travel [mm]", ylabel="pad force |F_x| [N]")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
