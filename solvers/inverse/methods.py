"""The two solution methods every inverse shares (docs/inverse.md, "Nested" and
"Simultaneous").

A problem (the static ``InverseProblem``, the dynamic ``DynamicProblem``) states what is
fitted; a method states how, once for both:

- ``ReducedSpaceSolver`` (nested): x is the only unknown. Every residual evaluation
  solves the forward problem, equilibrium or trajectory, and scipy's ``least_squares``
  iterates in the internal coordinates z of ``ParameterSpace``. A subclass states
  ``evaluate(z) -> (r, dr/dz)`` and its ``states``; where it helps, also ``residual``
  (r alone), ``active``, ``reset`` and ``extra``.
- ``FullSpaceSolver`` (simultaneous): the parameters and every state are the variables
  of one IPOPT NLP, the forward problem its equality constraints. A subclass builds
  ``self.solver`` (a CasADi nlpsol) and states ``initial(x0) -> (guess, lbx, ubx)`` and
  ``unpack(values) -> (x, states, extra)``.

Both return an ``InverseResult``, so every method of every problem can be compared.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import least_squares

from solvers.forward.equilibrium import EquilibriumError
from solvers.inverse.result import InverseResult


class ReducedSpaceSolver:
    """Least squares over the parameters alone, the forward problem solved inside.

    Parameters
    ----------
    problem : InverseProblem or DynamicProblem
        The problem; its ``space`` and ``cases`` are used here.
    method : {"trf", "lm"}
        scipy least-squares method; "lm" ignores the bounds.
    tolerance : float
        ftol = xtol = gtol of least_squares.
    max_evaluations : int
        Cap on residual evaluations.
    """

    name = "nested"
    finite_differences = False
    """True where the method has no Jacobian of its own (scipy's 2-point differences)."""

    def __init__(self, problem, method="trf", tolerance=1e-12, max_evaluations=200):
        if method not in ("trf", "lm"):
            raise ValueError(f"method must be 'trf' or 'lm', got {method!r}")
        self.problem = problem
        self.method, self.tolerance, self.max_evaluations = method, tolerance, max_evaluations
        self.forward_solves = 0
        self.build_time = 0.0

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual r(z) [mm] and its Jacobian dr/dz."""
        raise NotImplementedError

    def residual(self, z: np.ndarray) -> np.ndarray:
        """Residual r(z) alone (by default from ``evaluate``)."""
        return self.evaluate(z)[0]

    @property
    def active(self) -> np.ndarray | None:
        """Parameters that move the residual; the others keep their start (None: all)."""
        return None

    @property
    def states(self) -> list:
        """The forward state of every case at the last evaluation."""
        raise NotImplementedError

    def extra(self) -> dict:
        """Anything else the result carries (``InverseResult.extra``)."""
        return {}

    def reset(self) -> None:
        """Forget the previous solve (its counters, warm starts and caches)."""
        self.forward_solves = 0

    def solve(self, start: np.ndarray | None = None) -> InverseResult:
        """Run least_squares from ``start`` (natural units; default the space's start)."""
        self.reset()
        jacobian = None if self.finite_differences else (lambda z: self.evaluate(z)[1])
        z, success, status, nfev, elapsed = least_squares_fit(
            self.residual,
            self.problem.space,
            start,
            jacobian,
            self.active,
            self.method,
            self.tolerance,
            self.max_evaluations,
        )
        residual = self.residual(z)
        if not np.all(np.isfinite(residual)):  # a failed forward solve at the end point
            raise EquilibriumError(
                f"no equilibrium at the end of the fit ({status}); try another start"
            )
        space = self.problem.space
        return InverseResult(
            method=self.name,
            names=space.names,
            x=space.to_natural(z),
            cost=0.5 * float(residual @ residual),
            states=list(self.states),
            success=bool(success),
            status=str(status),
            iterations=int(nfev),
            forward_solves=self.forward_solves,
            build_time_s=self.build_time,
            solve_time_s=elapsed,
            extra=self.extra(),
        )


def least_squares_fit(
    residual,
    space,
    start,
    jacobian=None,
    active=None,
    method="trf",
    tolerance=1e-12,
    max_evaluations=200,
):
    """The outer loop of the reduced-space methods.

    ``residual(z) -> r`` and ``jacobian(z) -> dr/dz`` over every internal coordinate
    (None: scipy's 2-point differences); parameters not in ``active`` (mu and gamma at
    steady state) stay at their start values. A failed forward solve ends the start
    with ``success = False``.

    Returns
    -------
    z, success, status, evaluations, elapsed
        Internal coordinates at the end, the verdict, scipy's message, residual
        evaluations and wall time [s].
    """
    z_full = space.to_internal(space.start if start is None else start)
    active = np.ones(len(z_full), dtype=bool) if active is None else np.asarray(active)
    lower, upper = (b[active] for b in space.internal_bounds())

    def full(z_active: np.ndarray) -> np.ndarray:
        z = z_full.copy()
        z[active] = z_active
        return z

    begin = time.perf_counter()
    kwargs = {} if method == "lm" else {"bounds": (lower, upper)}
    try:
        fit = least_squares(
            lambda z: residual(full(z)),
            np.clip(z_full[active], lower, upper),
            jac="2-point" if jacobian is None else (lambda z: jacobian(full(z))[:, active]),
            method=method,
            ftol=tolerance,
            xtol=tolerance,
            gtol=tolerance,
            max_nfev=max_evaluations,
            x_scale=1.0,
            **kwargs,
        )
        outcome = full(fit.x), fit.status > 0, status_text(fit.message), fit.nfev
    except Exception as error:  # noqa: BLE001  a failed forward solve ends this start
        outcome = z_full, False, f"failed: {error}", 0
    return (*outcome, time.perf_counter() - begin)


def status_text(message: str) -> str:
    """scipy's least_squares message without its backticks and final full stop."""
    return message.replace("`", "").strip().rstrip(".")


class FullSpaceSolver:
    """Parameters and states in one IPOPT NLP, the forward problem as its constraints.

    A subclass sets ``problem``, ``solver`` (CasADi nlpsol with the parameters' internal
    coordinates first) and ``build_time`` when it is built.
    """

    name = "simultaneous"

    def initial(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The NLP's start (states warm-started at x0) and its variable bounds."""
        raise NotImplementedError

    def unpack(self, values: np.ndarray) -> tuple[np.ndarray, list, dict]:
        """x (natural units), the state of every case and extras from the NLP's solution."""
        raise NotImplementedError

    def bounds(self, guess: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """lbx, ubx: the space's internal bounds / ``scale`` on the leading parameters,
        free states."""
        lower, upper = self.problem.space.internal_bounds()
        lbx, ubx = np.full(guess.size, -np.inf), np.full(guess.size, np.inf)
        lbx[: lower.size], ubx[: upper.size] = lower / scale, upper / scale
        return lbx, ubx

    def solve(self, start: np.ndarray | None = None) -> InverseResult:
        """Solve from ``start`` (natural units; default the space's start values)."""
        problem, space = self.problem, self.problem.space
        x0 = space.start if start is None else np.asarray(start, dtype=float)
        begin = time.perf_counter()
        try:
            guess, lbx, ubx = self.initial(x0)
        except Exception as error:  # noqa: BLE001  no forward solution at this start
            return self._failed(x0, f"warm start failed: {error}", begin)
        solution = self.solver(x0=guess, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0)
        elapsed = time.perf_counter() - begin
        stats = self.solver.stats()
        x, states, extra = self.unpack(solution["x"].full().ravel())
        residual = np.concatenate(
            [problem.case_residual(c, s) for c, s in zip(problem.cases, states)]
        )
        return InverseResult(
            method=self.name,
            names=space.names,
            x=x,
            cost=0.5 * float(residual @ residual),
            states=list(states),
            success=bool(stats["success"]),
            status=str(stats["return_status"]),
            iterations=int(stats["iter_count"]),
            forward_solves=len(problem.cases),
            build_time_s=self.build_time,
            solve_time_s=elapsed,
            extra={"constraint_violation": float(np.abs(solution["g"].full()).max()), **extra},
        )

    def _failed(self, x0, status, begin) -> InverseResult:
        return InverseResult(
            self.name,
            self.problem.space.names,
            np.asarray(x0),
            np.inf,
            [],
            False,
            status,
            0,
            0,
            self.build_time,
            time.perf_counter() - begin,
        )
