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
[-0.9, 0.499], with the exact Jacobian from direct sensitivities. The stiffening fit starts
from the neo-Hookean one with k2 = 1 / s_max^2 (s_max: the largest s of its last frame)
and k1 = E/10, and k2 s_max^2 is bounded by ``STIFFENING_CAP`` (``stiffening_start``).
Errors: sigma (S^T S)^-1/2 at the estimate (``standard_errors``); the two energies are
compared by the likelihood ratio of their whitened costs (``likelihood_ratio``).

Run: ``python -c "from experiments.realskin.planarstiffening import stiffening_study;
stiffening_study('/tmp/out')"``; it writes ``stiffening.json``, ``stiffening.md`` and
``stiffening_force.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats
from scipy.signal import savgol_filter

from experiments.output.atomic import atomic_write_json, atomic_write_text
from experiments.realskin import authors
from experiments.realskin.data import dic_noise_mm
from experiments.realskin.planar import Assumptions, Extensometer, Solution
from experiments.realskin.planarfit import Fit, least_squares_fit
from experiments.realskin.reproduce import measured, mesh_for
from experiments.realskin.stages import internal_standard_errors
from symbolic.planar_stiffening import EXPONENT_CAP, NAMES, Isochoric, PlanarStiffening

FULL_TRAVEL_MM = 10.0
"""Frames up to this travel: every synchronised DIC frame of both cases."""

START_NH = {"healthy": (0.03, 0.2), "keloid": (0.12, 0.38)}
"""Neo-Hookean start values (E [N/mm], nu)."""

MESH_SIZE_MM = 1.0
"""Element size around the pads and the gap [mm] (4x elsewhere), as ``reproduce``."""

STIFFENING_CAP = 50.0
"""Upper bound on k2 s_max^2 (s_max: the largest s of the neo-Hookean fit's last frame):
well inside ``EXPONENT_CAP``, so the term stays a stiffening and cannot become a hard
wall on s (the healthy fit of 2026-11-27 slid to k2 s^2 = 200 with k1 -> 0)."""
assert STIFFENING_CAP < EXPONENT_CAP / 2

X_SCALE = "jac"
"""scipy's ``x_scale`` on z = (ln E, nu, ln k1, ln k2) (see ``fit``)."""


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


def fit(
    problem: WhitenedExtensometer,
    start,
    max_evaluations: int = 100,
    k2_max: float = np.inf,
    x_scale=X_SCALE,
) -> Fit:
    """Trust-region least squares on z = (ln E, nu[, ln k1, ln k2]) with the exact Jacobian
    (``planarfit.least_squares_fit``; each solve from rest, a failed solve gives NaN
    residuals so the trust region shrinks), nu in ``NU_BOUNDS`` and k2 <= ``k2_max``."""
    n = len(start)
    return least_squares_fit(
        lambda p, previous: problem.solve(p),
        problem,
        start,
        np.arange(n) != 1,
        problem.measures,
        (RuntimeError, ArithmeticError, ValueError),
        ftol=1e-8,
        max_evaluations=max_evaluations,
        upper={3: k2_max} if n == 4 and np.isfinite(k2_max) else None,
        x_scale=x_scale,
    )


def largest_s(problem: WhitenedExtensometer, u) -> float:
    """The largest s = Ibar1 - 3 over the fitted triangles in the state u [-]."""
    s = Isochoric.of(problem.model.mesh.deformation_gradient(u)).s
    return float(s[problem.weights > 0].max())


def stiffening_start(neo_hookean, s_max: float) -> tuple[tuple, float]:
    """The stiffening fit's start from the neo-Hookean fit's (E, nu), and the k2 bound.

    k2 = 1 / s_max^2: the exponential active at the most strained triangle of the last
    frame (k2 s_max^2 = 1), so every column of the Jacobian is alive at the start.
    k1 = E / 10: a small perturbation of the neo-Hookean fit (its added stress k1 s e at
    s_max is 0.2 e (1 + nu) s_max ~ 1-5 % of mu/2 there), so the fit leaves the
    neo-Hookean solution only as far as the data ask. (The alternative, k1 matching the
    neo-Hookean stress mu/2 at s_max, started the keloid fit next to the neo-Hookean
    compromise E with a strong term; it ended unconverged at a force RMS of 0.29 N.)
    Bound: k2 <= ``STIFFENING_CAP`` / s_max^2.
    """
    young, poisson = map(float, neo_hookean[:2])
    return (young, poisson, young / 10.0, 1.0 / s_max**2), STIFFENING_CAP / s_max**2


def standard_errors(problem: WhitenedExtensometer, result: Fit) -> dict:
    """sigma (S^T S)^-1/2 diagonals, S = dr/dz at the estimate, sigma = sqrt(RSS / (m - n))
    (``stages.internal_standard_errors``): the whitened residuals carry the model error, so
    sigma >> 1 and these errors hold only if that misfit were noise. ``std`` in natural
    units (delta method: p std(ln p) for the log parameters), ``std_log`` of z."""
    x = np.asarray(result.x, dtype=float)
    log = np.arange(len(x)) != 1
    r = problem.residuals(result.solution)
    scaled = problem.jacobian(result.solution) * np.where(log, x, 1.0)
    std_z, sigma, singular = internal_standard_errors(r, scaled, rank_tolerance=1e-12)
    names = NAMES[: len(x)]
    return {
        "sigma": sigma,
        "condition": float("nan") if singular is None else float(singular.max() / singular.min()),
        "std": dict(zip(names, map(float, std_z * np.where(log, x, 1.0)))),
        "std_log": dict(zip(names, map(float, std_z))),
    }


def likelihood_ratio(neo_hookean: dict, stiffening: dict, size: int) -> dict:
    """2 (cost_NH - cost_stiff) against chi^2 with 2 degrees of freedom, and the same
    divided by the stiffening fit's residual variance 2 cost / (m - 4) (the misfit is
    mostly model error, not the whitened noise: a quasi-likelihood, F-test-like ratio)."""
    ratio = 2.0 * (neo_hookean["cost"] - stiffening["cost"])
    variance = 2.0 * stiffening["cost"] / (size - 4)
    return {
        "lr": ratio,
        "p": float(stats.chi2.sf(ratio, 2)),
        "residual_variance": variance,
        "lr_scaled": ratio / variance,
        "p_scaled": float(stats.chi2.sf(ratio / variance, 2)),
    }


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


def row(case: str, energy: str, result: Fit, problem: WhitenedExtensometer, bound=None) -> dict:
    """One fit as a JSON row (``bound``: the stiffening fit's s_max, start and k2 bound)."""
    names = NAMES[: len(result.x)]
    extra = {}
    if bound is not None:
        s_max, start, k2_max = bound
        extra = {
            "s_max": s_max,
            "start": dict(zip(names, map(float, start))),
            "k2_max": k2_max,
            "k2_s_max2": float(result.x[3]) * s_max**2,
            "at_bound": bool(np.log(k2_max) - np.log(result.x[3]) < 1e-4),
        }
    return {
        "case": case,
        "energy": energy,
        "parameters": dict(zip(names, map(float, result.x))),
        **result.measures,
        **standard_errors(problem, result),
        **extra,
        "evaluations": result.evaluations,
        "seconds": result.seconds,
        "message": result.message,
        "success": result.success,
        "residuals": int(len(problem.residuals(result.solution))),
        "sigma_u_mm": problem.sigma_u,
        "sigma_f_n": problem.sigma_f,
        "frames": len(problem.frames.indices),
        "travel_mm": (-problem.frames.pad_ux_mm).tolist(),
        "force_measured_n": problem.frames.force_n.tolist(),
        "force_model_n": result.solution.force.tolist(),
    }


def stiffening_study(
    out_dir, log=print, mesh_size: float = MESH_SIZE_MM, cases=("healthy", "keloid")
) -> dict:
    """Fit both energies on both cases; write JSON, the markdown table and the figure.

    Healthy first (its fits are the skin held around the keloid), then the keloid. The
    stiffening fit starts from the neo-Hookean one (``stiffening_start``, s_max from its
    last frame) with k2 bounded by ``STIFFENING_CAP``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows, held, tests = [], {}, {}
    for case in cases:
        problem = problem_for(case, 2, held.get("neo-Hookean"), mesh_size)
        neo = fit(problem, START_NH[case])
        rows.append(row(case, "neo-Hookean", neo, problem))
        _log_row(log, rows[-1])
        s_max = largest_s(problem, neo.solution.u[-1])
        start, k2_max = stiffening_start(neo.x, s_max)
        log(f"{case}: s_max {s_max:.4g}, start {np.array(start)}, k2 <= {k2_max:.4g}")
        problem = problem_for(case, 4, held.get("stiffening"), mesh_size)
        result = fit(problem, start, k2_max=k2_max)
        rows.append(row(case, "stiffening", result, problem, (s_max, start, k2_max)))
        _log_row(log, rows[-1])
        if case == "healthy":
            held = {"neo-Hookean": (*neo.x, 0.0, 1.0), "stiffening": tuple(result.x)}
        tests[case] = likelihood_ratio(rows[-2], rows[-1], rows[-1]["residuals"])
        log(f"{case}: likelihood ratio {tests[case]}")
    report = {"rows": rows, "tests": tests, "mesh_size_mm": mesh_size, "keloid": "two materials"}
    atomic_write_json(out / "stiffening.json", report)
    atomic_write_text(out / "stiffening.md", table(rows, tests))
    figure(rows, out / "stiffening_force.png")
    return report


def _log_row(log, r: dict) -> None:
    log(
        f"{r['case']} {r['energy']}: "
        + ", ".join(f"{k} {v:.4g} +- {r['std'][k]:.2g}" for k, v in r["parameters"].items())
        + f"; RMS force {r['rms_force_n']:.4f} N, displacement {r['rms_displacement_mm']:.4f}"
        f" mm; cost {r['cost']:.6g}; {r['evaluations']} evaluations, {r['seconds']:.1f} s; "
        f"{r['message']}"
    )


def _value(r: dict, name: str) -> str:
    """'value +- std' of a fitted parameter ('at bound' for a k2 on its bound)."""
    value = r["parameters"][name]
    if name == "k2" and r.get("at_bound"):
        return f"{value:.4g} (at bound)"
    return f"{value:.4g} +- {r['std'][name]:.2g}"


def table(rows: list[dict], tests: dict | None = None) -> str:
    """The before/after table (markdown) and the likelihood ratios."""
    lines = [
        "| case | energy | E [N/mm] | nu | k1 [N/mm] | k2 | k2 s_max^2 | RMS force [N] "
        "| RMS displacement [mm] | cost | evaluations | converged | time [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        stiff = "k1" in r["parameters"]
        k1 = _value(r, "k1") if stiff else "0"
        k2 = _value(r, "k2") if stiff else "-"
        reach = f"{r['k2_s_max2']:.3g} (s_max {r['s_max']:.3g})" if "s_max" in r else "-"
        lines.append(
            f"| {r['case']} | {r['energy']} | {_value(r, 'E')} | {_value(r, 'nu')} | {k1} | "
            f"{k2} | {reach} | {r['rms_force_n']:.4f} | {r['rms_displacement_mm']:.4f} | "
            f"{r['cost']:.5g} | {r['evaluations']} | {'yes' if r['success'] else 'no'} | "
            f"{r['seconds']:.0f} |"
        )
    for case, test in (tests or {}).items():
        lines.append(
            f"\n{case}: 2 (cost_NH - cost_stiff) = {test['lr']:.4g} (chi^2_2 p = "
            f"{test['p']:.2g}); divided by the residual variance {test['residual_variance']:.4g}:"
            f" {test['lr_scaled']:.4g} (p = {test['p_scaled']:.2g})."
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
