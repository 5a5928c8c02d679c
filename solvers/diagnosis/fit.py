"""A nested least-squares fit of an extended problem (docs/inverse.md).

``fit`` minimises |W r(p)|^2 over any subset of p = [x; theta] with scipy's
trust-region reflective method, in the internal coordinates of
``ExtendedProblem`` (log for alpha, scaled linear for theta) and with the
exact reduced Jacobian (implicit function theorem through eq. 22).
``EffectFit`` keeps what the tests need: the whitened residual rho, its
Jacobian, the states and their dg/ds factorisations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from solvers.diagnosis.extended import ExtendedProblem
from solvers.diagnosis.stability import admissible, into_admissible
from solvers.forward.equilibrium import EquilibriumError


@dataclass
class EffectFit:
    """A nested least-squares fit of an extended problem.

    Attributes
    ----------
    problem : ExtendedProblem
        The problem fitted.
    p : numpy.ndarray
        Estimate [x; theta] in natural units.
    free : numpy.ndarray
        Which entries of p were estimated.
    states : list of numpy.ndarray
        Equilibrium states at p.
    residual : numpy.ndarray
        Raw residual r [mm].
    whitened : numpy.ndarray
        rho = W r [mm].
    jacobian : numpy.ndarray
        d rho / dp (natural units).
    state_jacobians : list of StateJacobian
        dg/ds of every case at the solution.
    prior : numpy.ndarray, optional
        The rows P of the effects' priors (``ExtendedProblem.prior_matrix``), whose
        |P p|^2 the fit added to |rho|^2; None without priors.
    raw_jacobian : numpy.ndarray, optional
        dr/dp before whitening (natural units): the left-out predictions
        (``solvers.diagnosis.guard``) whiten its rows with their own cases' noise.
    """

    problem: ExtendedProblem
    p: np.ndarray
    free: np.ndarray
    states: list
    residual: np.ndarray
    whitened: np.ndarray
    jacobian: np.ndarray
    success: bool = True
    status: str = ""
    evaluations: int = 0
    wall_time_s: float = 0.0
    state_jacobians: list = field(default_factory=list)
    prior: np.ndarray | None = None
    raw_jacobian: np.ndarray | None = None

    @property
    def cost(self) -> float:
        """|rho|^2 [mm^2] (the data's part; ``penalty`` is the prior's)."""
        return float(self.whitened @ self.whitened)

    @property
    def penalty(self) -> float:
        """|P p|^2 [mm^2], the prior's part of the cost (0 without priors)."""
        return 0.0 if self.prior is None else float(np.sum((self.prior @ self.p) ** 2))

    def information(self) -> tuple[np.ndarray, np.ndarray]:
        """J^T J and P^T P over the estimated entries (whitened, natural units) [mm^2]."""
        chosen = self.estimated()
        sub = self.jacobian[:, chosen]
        gram = sub.T @ sub
        if self.prior is None:
            return gram, np.zeros_like(gram)
        rows = self.prior[:, chosen]
        return gram, rows.T @ rows

    def effective_dof(self) -> float:
        """The parameters the data determine: tr((J^T J + P^T P)^-1 J^T J).

        Without a prior the count of estimated entries (each is one degree of
        freedom); with one, a field of N coefficients counts fewer than N.
        """
        if self.prior is None:
            return float(self.estimated().sum())
        gram, prior = self.information()
        if not gram.size:
            return 0.0
        return float(np.trace(np.linalg.lstsq(gram + prior, gram, rcond=1e-12)[0]))

    def at_bound(self, tolerance: float = 1e-6) -> np.ndarray:
        """Entries of p on a bound (by a fraction of the range)."""
        span = self.problem.upper - self.problem.lower
        return (np.abs(self.p - self.problem.lower) <= tolerance * span) | (
            np.abs(self.problem.upper - self.p) <= tolerance * span
        )

    def estimated(self) -> np.ndarray:
        """Free entries that are not on a bound: the ones the statistics count."""
        return self.free & ~self.at_bound()

    def standard_errors(self, sigma: float) -> np.ndarray:
        """sigma sqrt(diag((J^T J + P^T P)^-1)) over the estimated entries (NaN elsewhere)
        [natural]: with a prior, the posterior's (Laplace) standard deviations."""
        out = np.full(self.p.size, np.nan)
        chosen = self.estimated()
        if chosen.any():
            gram, prior = self.information()
            try:
                covariance = np.linalg.pinv(gram + prior, rcond=1e-12)
                out[chosen] = sigma * np.sqrt(np.maximum(np.diag(covariance), 0.0))
            except np.linalg.LinAlgError:
                pass
        return out

    def rms(self) -> tuple[float, float]:
        """RMS and maximum marker distance [mm]."""
        return self.problem.rms(self.residual)


STATISTICAL_TOLERANCE = 1e-7
"""ftol, xtol and gtol of the diagnosis loop's fits and the guard's refits. scipy's trf
stops when a step lowers the cost F = chi^2 / 2 by less than 1e-7 F: at chi^2 of 10^3-10^4
that is 10^-4-10^-3 in chi^2, far below what a statistic, a p-value or the guard reads.
``fit``'s default, 1e-10, spent 1-7 more evaluations (factorisations of K(p)) per refit,
most of them where an effect's parameter drifts along a flat valley of chi^2
(docs/diagnosis.md, "How exactly the loop fits")."""


def statistical_tolerance(problem: ExtendedProblem, rows: int) -> float:
    """ftol of the loop's fits: ``STATISTICAL_TOLERANCE`` on a model linear in its state;
    on one that is not (Newton per case, each evaluation dear), 0.1 / m for m residuals,
    so that chi^2 is good to about 0.1 phi, a hundredth of what the selection rule
    (docs/diagnosis.md, eq. G3) compares with it."""
    if problem.linear_state:
        return STATISTICAL_TOLERANCE
    return max(STATISTICAL_TOLERANCE, 0.1 / max(int(rows), 1))


def fit(
    problem: ExtendedProblem,
    start=None,
    free=None,
    states=None,
    max_evaluations=100,
    tolerance=1e-10,
) -> EffectFit:
    """Nested least squares of |W r(p)|^2 over the ``free`` entries of p.

    Parameters
    ----------
    problem : ExtendedProblem
        The problem.
    start : numpy.ndarray, optional
        Start p in natural units (default ``problem.start()``); clipped to the bounds
        and brought into the admissible set (``solvers.diagnosis.stability``).
    free : numpy.ndarray of bool, optional
        Entries to estimate (default all).
    states : list, optional
        Warm-start states of the cases.
    """
    begin = time.perf_counter()
    p0 = problem.start() if start is None else np.array(start, dtype=float)
    p0 = into_admissible(problem, np.clip(p0, problem.lower, problem.upper))
    free = np.ones(p0.size, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    z_full = problem.to_internal(p0)
    lower, upper = (problem.to_internal(b)[free] for b in (problem.lower, problem.upper))
    cache: dict = {"states": states}
    prior = problem.prior_matrix()

    def evaluate(z_free: np.ndarray):
        if cache.get("z") is not None and np.array_equal(cache["z"], z_free):
            return cache["rho"], cache["jac"]
        z = z_full.copy()
        z[free] = z_free
        p = problem.to_natural(z)
        if not admissible(problem, p):  # no equilibrium: trf shrinks its step and retries
            return np.full_like(cache["rho"], np.nan), None
        try:
            r, jac, new_states, state_jacobians = problem.evaluate_full(p, cache["states"])
        except EquilibriumError:  # as for an inadmissible p: trf shrinks its step
            if cache.get("rho") is None:
                raise  # at the start: the fit cannot begin
            return np.full_like(cache["rho"], np.nan), None
        cache.update(
            z=np.array(z_free), states=new_states, full=(r, jac, new_states, state_jacobians)
        )
        cache["rho"] = problem.whiten(r)
        cache["jac"] = problem.whiten(jac)[:, free] * problem.natural_derivative(z)[free]
        if prior is not None:  # the prior's rows: the cost is the negative log posterior
            cache["rho"] = np.concatenate([cache["rho"], prior @ p])
            derivative = prior[:, free] * problem.natural_derivative(z)[free]
            cache["jac"] = np.vstack([cache["jac"], derivative])
        return cache["rho"], cache["jac"]

    evaluations, success, status = 0, True, "no free parameters"
    z_free = z_full[free]
    if free.any():
        try:
            result = least_squares(
                lambda z: evaluate(z)[0],
                np.clip(z_free, lower, upper),
                jac=lambda z: evaluate(z)[1],
                bounds=(lower, upper),
                method="trf",
                ftol=tolerance,
                xtol=tolerance,
                gtol=tolerance,
                max_nfev=max_evaluations,
                x_scale=1.0,
            )
            z_free, success, status = result.x, result.status > 0, result.message
            evaluations = result.nfev
        except EquilibriumError as error:
            success, status = False, f"failed: {error}"
    z = z_full.copy()
    z[free] = z_free
    p = problem.to_natural(z)
    if free.any() and cache.get("z") is not None and np.array_equal(cache["z"], z_free):
        r, jac, final_states, state_jacobians = cache["full"]  # trf's last evaluation
    else:
        r, jac, final_states, state_jacobians = problem.evaluate_full(p, cache["states"])
    return EffectFit(
        problem=problem,
        p=p,
        free=free,
        states=final_states,
        residual=r,
        whitened=problem.whiten(r),
        jacobian=problem.whiten(jac),
        success=bool(success),
        status=str(status),
        evaluations=int(evaluations),
        wall_time_s=time.perf_counter() - begin,
        state_jacobians=state_jacobians,
        prior=prior,
        raw_jacobian=jac,
    )
