"""The CasADi Functions of an extended model's load cases (``symbolic.effects.library``).

``CaseFunctions`` are what Newton and the implicit-function Jacobian need per case;
``CaseParts`` and ``StiffnessTerms`` are the linear path's (``solvers.forward.linearpath``):
each case's load and observation alone, and the stiffness as numeric unit terms with
symbolic coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.effects.base import CaseData, LoadState
from symbolic.effects.load import load_change
from symbolic.effects.prescribed import constraint_load
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


class CaseFunctions:
    """The CasADi Functions of one load case of an extended model, built on first use.

    Attributes
    ----------
    equilibrium : casadi.Function
        (s, p) -> g, the extended equilibrium (eq. 22) [N, and mm^3 for extra rows].
    newton : casadi.Function
        (s, p) -> (g, dg/ds): the equilibrium and its sparse Jacobian, given (the
        model part's, ``ExtendedModel._model_part``; the load does not depend on s).
    residual : casadi.Function
        (s, p) -> r, the observation residual W (y(s, p) - Y), columns stacked [mm].
    sensitivity : casadi.Function
        (s, p) -> (dg/dp, r, dr/ds, dr/dp) for the implicit-function Jacobian.
    n_state : int
        Length of s.
    """

    def __init__(self, s: ca.MX, p: ca.MX, g: ca.MX, r: ca.MX, dg_ds: ca.MX, dg_dp: ca.MX):
        self.s, self.p, self.g, self.r = s, p, g, r
        self.dg_ds, self.dg_dp = dg_ds, dg_dp
        self.n_state = int(s.numel())
        self._built: dict[str, ca.Function] = {}

    def _get(self, name: str, outputs, names) -> ca.Function:
        if name not in self._built:
            self._built[name] = ca.Function(name, [self.s, self.p], outputs(), ["s", "p"], names)
        return self._built[name]

    @property
    def equilibrium(self) -> ca.Function:
        return self._get("g", lambda: [self.g], ["g"])

    @property
    def newton(self) -> ca.Function:
        return self._get("newton", lambda: [self.g, self.dg_ds], ["g", "dg_ds"])

    @property
    def residual(self) -> ca.Function:
        return self._get("r", lambda: [self.r], ["r"])

    @property
    def sensitivity(self) -> ca.Function:
        s, p, r = self.s, self.p, self.r
        return self._get(
            "sensitivity",
            lambda: [
                self.dg_dp,
                r,
                ca.jacobian(r, s),
                ca.jacobian(r, p),
            ],
            ["dg_dp", "r", "dr_ds", "dr_dp"],
        )


@dataclass(frozen=True)
class CaseParts:
    """The Functions of one load case on the linear path: its load and its observation,
    without the model part (``ExtendedModel.case_parts``).

    Attributes
    ----------
    load : casadi.Function
        p -> (-F_B(p), -dF_B/dp): the case's part of g and of dg/dp [N].
    observation : casadi.Function
        (s, p) -> (r, dr/ds, dr/dp): the observation residual and its derivatives [mm].
    """

    load: ca.Function
    observation: ca.Function

    def widened(self, columns, n_p: int, n_state: int, tail: int = 0) -> CaseParts:
        """These parts, of a p' = p[columns] and an s' that begins s (and ends it in the
        ``tail`` multipliers, when the model has prescribed points), as parts of p and s.

        The parts of an effect set equal those of its effects that change the load or
        the observation (``ExtendedModel.case_parts``): the others enter neither, so
        their parameters get zero columns and their extra state zero rows. Widening
        reuses the smaller set's Functions, built once, instead of differentiating
        each case's graph again for every set (925 builds, 9 s of a default
        ``dvs next``). The values are the same arithmetic on the same numbers.
        """
        columns = np.asarray(columns, dtype=int)
        select = ca.DM(
            sp.csc_matrix(
                (np.ones(columns.size), (np.arange(columns.size), columns)),
                shape=(columns.size, n_p),
            )
        )
        p, s = ca.MX.sym("p", n_p), ca.MX.sym("s", n_state)
        q = p[columns.tolist()]
        load, load_q = self.load(q)
        extra, head = n_state - load.numel(), load.numel() - tail
        load_p = ca.mtimes(load_q, select)
        observed = self.observation(ca.vertcat(s[:head], s[n_state - tail :]), q)
        rows = observed[1].size1()
        return CaseParts(
            load=ca.Function(
                "load",
                [p],
                [
                    ca.vertcat(load[:head], ca.MX(extra, 1), load[head:]),
                    ca.vertcat(load_p[:head, :], ca.MX(extra, n_p), load_p[head:, :]),
                ],
            ),
            observation=ca.Function(
                "observation",
                [s, p],
                [
                    observed[0],
                    ca.horzcat(observed[1][:, :head], ca.MX(rows, extra), observed[1][:, head:]),
                    ca.mtimes(observed[2], select),
                ],
            ),
        )


@dataclass(frozen=True)
class StiffnessTerms:
    """K(p) = sum_t c_t(p) K_t of a model linear in the state whose every contribution to
    h is a unit term: the base model's (eq. 11-18 or C3) and the ``linear`` effects'.

    Attributes
    ----------
    matrices : list of scipy.sparse matrices or ``symbolic.sparse.ProductTerm``
        K_t on the free points, stacked, (3 n_state)-square [N/mm per unit c_t]; a
        ``ProductTerm`` is applied without its matrix until its coefficient is not zero.
    coefficients : casadi.Function
        p -> (c(p), dc/dp), (T, 1) and (T, n_p): the only symbolic part.
    shares_pattern : dict
        (s, t) -> whether K_s and K_t store their entries at the same positions, filled
        as the terms are summed (``solvers.forward.linearpath.stiffness_matrix``).
    """

    matrices: list
    coefficients: ca.Function
    shares_pattern: dict = field(default_factory=dict, compare=False, repr=False)


@dataclass(frozen=True)
class SplitPart:
    """h(s, p) = K(p) s + n(s, p) of a base model linear in the state whose effects add
    unit terms or internal forces given in numbers (``ExtendedModel.split_part``): the
    split path of ``solvers.diagnosis.splitpath``.

    Attributes
    ----------
    terms : StiffnessTerms
        K(p) = sum_t c_t(p) K_t: the base model's, the ``unit_terms`` effects' and the
        multipliers' block, (n_state)-square.
    arguments : casadi.Function
        p -> (q, dq/dp): the arguments of the forces, stacked.
    forces : tuple
        (slice of q, evaluator) per force (``Effect.numeric_force``); n is the sum of
        their vec(F) on the free rows of s.
    """

    terms: StiffnessTerms
    arguments: ca.Function
    forces: tuple


def case_load(model: TissueModel, effects, case: CaseData, thetas, n_state: int) -> ca.MX:
    """-F_B(theta) of the case on the free points, stacked, then zero on the extra rows
    and -vec(Q d_k) on the constraint rows of a model with prescribed points
    (``symbolic.effects.prescribed``): the declared load as the load effects change it,
    in turn (eq. 20)."""
    load = LoadState(np.asarray(case.force_vector, dtype=float))
    for effect, theta in zip(effects, thetas):
        load = effect.load(model, case, load, theta)
    force = -ca.DM(case.force)
    change = load_change(model, case, load)
    if change is not None:
        force = force - change
    if not model.n_constraints:
        return ca.vertcat(ca.vec(force), ca.MX(n_state - force.numel(), 1))
    tail = ca.DM(constraint_load(model, case))
    return ca.vertcat(ca.vec(force), ca.MX(n_state - force.numel() - tail.numel(), 1), tail)


def case_observation(model: TissueModel, effects, case: CaseData, symbols, thetas) -> ca.MX:
    """r = W (y - Y) with y = maps of S B over the observed components, columns stacked,
    then the force rows w_f (R vec(lam) - F) (as ``InverseProblem.case_residual``): the
    predicted markers as the observation effects change them, in turn (eq. 24)."""
    rest = ca.DM(case.rest_points)
    predicted = rest + ca.mtimes(to_casadi_sparse(case.rows), symbols.delta)
    for effect, theta in zip(effects, thetas):
        predicted = effect.observe(model, case, predicted, theta)
    difference = predicted - rest + ca.DM(case.offset)
    if tuple(case.observed) != (0, 1, 2):
        difference = difference[:, list(case.observed)]
    weights = ca.repmat(ca.DM(case.weights), 1, len(case.observed))
    r = ca.vec(weights * difference)
    if case.force_rows is None:
        return r
    if symbols.lam is None:
        raise ValueError("a force observation needs prescribed points (their multipliers)")
    force = ca.mtimes(to_casadi_sparse(case.force_rows), ca.vec(symbols.lam))
    return ca.vertcat(r, case.force_weight * (force - ca.DM(case.force_target)))
