"""The base model plus active effects: one extended model, p = [x; theta].

``ExtendedModel`` composes, per load case k, the named CasADi Functions of the
extended equilibrium g_k(s, p) (eq. 22) and observation residual r_k(s, p)
(eq. 24), with p = [x; theta_1; ...; theta_E] in natural units and
s = [vec(B_free - B0_free); vec(extra state); vec(lam)] (columns stacked; lam the
multipliers of prescribed displacements, ``symbolic.effects.prescribed``). They split as

    g_k(s, p) = h(s, p) - F_B,k(theta)      (and -Q d_k on the constraint rows),

h the model part (the base model's force, the effects' internal forces and extra rows),
the same for every case: it and its derivatives dh/ds, dh/dp are built once per effect
set, and a case adds its load, a function of theta alone, and its observation. (Built
whole per case, every press of a design paid for its own symbolic Jacobians: 0.2 s per
press and effect at 15x15x3.)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from symbolic.effects.base import (
    CaseData,
    CaseSymbols,
    Effect,
    adds_rows,
    apply_stacked,
    changes_case,
    enters_model_part,
)
from symbolic.effects.functions import (
    CaseFunctions,
    CaseParts,
    SplitPart,
    StiffnessTerms,
    case_load,
    case_observation,
)
from symbolic.effects.prescribed import constraint_term, n_multipliers, with_constraint_rows
from symbolic.model import TissueModel
from symbolic.sparse import SparseCallback, padded


class ExtendedModel:
    """The base model plus active effects: parameters p = [x; theta].

    Parameters
    ----------
    model : TissueModel
        The base model (prescribed displacements: ``symbolic.effects.prescribed``).
    names : tuple of str
        Estimated model parameters x (e.g. the three alpha).
    effects : list of Effect
        Active effects, in order (load and observation maps compose in it).
    cases : list of CaseData
        The load cases.
    cache : dict, optional
        Shared store of built Functions (models with the same effects and case
        share them).
    """

    def __init__(
        self,
        model: TissueModel,
        names,
        effects: list[Effect],
        cases: list[CaseData],
        cache: dict | None = None,
    ):
        if len({e.name for e in effects}) != len(effects):
            raise ValueError("each effect can be active only once")
        self.model = model
        self.names = tuple(names)
        self.effects = list(effects)
        self.cases = list(cases)
        indices = [c.index for c in self.cases]
        self.slices: dict[str, slice] = {}
        labels = list(self.names)
        for effect in self.effects:
            block = effect.labels(indices)
            self.slices[effect.name] = slice(len(labels), len(labels) + len(block))
            labels += block
        self.labels = labels
        self._functions = {} if cache is None else cache

    @property
    def n_parameters(self) -> int:
        """Length of p."""
        return len(self.labels)

    def effect_bounds(self, effect: Effect) -> tuple[np.ndarray, ...]:
        """Lower, upper and scale of an effect's block in p."""
        repeat = len(self.cases) if effect.per_case else 1
        return tuple(
            np.tile(np.asarray(v, dtype=float), repeat)
            for v in (effect.lower, effect.upper, effect.scales)
        )

    @property
    def effect_set(self) -> tuple[int, ...]:
        """The identity of the active effects: the group of their entries in ``cache``."""
        return tuple(id(e) for e in self.effects)

    def functions(self, position: int) -> CaseFunctions:
        """The Functions of the case at ``position`` (built once, shared through ``cache``)."""
        return self._case_entry("functions", position, self._build)

    def _case_entry(self, kind: str, position: int, build):
        """The ``kind`` entry of the case at ``position`` in ``cache``: ``build(position)``
        once per effect set, case and labels (and position, for a per-case effect)."""
        per_case = any(e.per_case for e in self.effects)
        labels = tuple(self.labels)
        key = (kind, self.effect_set, id(self.cases[position]), position if per_case else 0, labels)
        if key not in self._functions:
            self._functions[key] = build(position)
        return self._functions[key]

    @property
    def linear_state(self) -> bool:
        """True when dg/ds = K(p), the same for every case, with K(p) = sum_t c_t(p) K_t
        (``stiffness_terms``): the cases then share one factorisation per parameter
        value (``solvers.forward.linearpath``). Otherwise Newton, case by case."""
        return self.stiffness_terms() is not None

    def stiffness_terms(self) -> StiffnessTerms | None:
        """K(p) as unit terms, or None unless the base model is linear and every effect
        that enters h has ``unit_terms`` (the same for all cases, at most one with extra
        state): then the linear path needs no CasADi graph of the stiffness at all
        (``solvers.forward.linearpath``). Built once per effect set.
        """
        inside = [e for e in self.effects if enters_model_part(e)]
        if not self.model.is_linear(self.names) or any(not e.unit_terms for e in inside):
            return None
        return self._unit_terms(inside, "stiffness_terms")

    def _unit_terms(self, inside: list[Effect], kind: str) -> StiffnessTerms | None:
        """The unit terms of the base model and of the ``unit_terms`` effects ``inside``
        (None for a per-case one, or more than one with extra state), kept as ``kind``."""
        model = self.model
        if any(e.per_case for e in inside):
            return None
        if sum(1 for e in inside if e.extra_points(model)) > 1:
            return None  # each effect's terms place its extra state right after the free points
        key = ("functions", self.effect_set, kind, tuple(self.labels))
        if key not in self._functions:
            x, base, names = model.linear_terms(self.names)
            p = ca.MX.sym("p", self.n_parameters)
            values = self._values(p)
            base_coefficients = ca.Function("c", [x], [base])(p[: len(self.names)])
            coefficients = [base_coefficients]
            n = self.n_state

            base_key = ("base_terms", id(model), tuple(names), n)  # kept across sets
            if base_key not in self._functions:
                self._functions[base_key] = [padded(model.free_term(t, "kron"), n) for t in names]
            matrices = list(self._functions[base_key])
            for effect in inside:
                coefficients.append(
                    effect.stiffness_coefficients(model, values, p[self.slices[effect.name]])
                )
                matrices += [padded(m, n) for m in effect.stiffness_terms(model)]
            if model.n_constraints:  # the multipliers' block, constant (coefficient 1)
                coefficients.append(ca.DM.ones(1))
                matrices.append(constraint_term(model, n))
            c = ca.vertcat(*coefficients)
            self._functions[key] = StiffnessTerms(
                matrices, ca.Function("coefficients", [p], [c, ca.jacobian(c, p)])
            )
        return self._functions[key]

    def split_part(self) -> SplitPart | None:
        """h(s, p) = K(p) s + n(s, p), K(p) the unit terms of the base model and of the
        ``unit_terms`` effects and n the internal forces of the others in numbers
        (``Effect.numeric_force``), or None: unless the base model is linear, some effect
        enters h without unit terms, and every such effect adds an internal force alone
        (no extra state or rows) that it gives in numbers, for every case alike. The split
        path (``solvers.diagnosis.splitpath``) then needs CasADi only for K's coefficients
        and n's arguments, functions of p. Built once per effect set.
        """
        model = self.model
        inside = [e for e in self.effects if enters_model_part(e)]
        forces = [e for e in inside if not e.unit_terms]
        if not forces or not model.is_linear(self.names):
            return None
        if any(e.per_case or e.extra_points(model) or adds_rows(e) for e in forces):
            return None
        key = ("functions", self.effect_set, "split_part", tuple(self.labels))
        if key not in self._functions:
            self._functions[key] = self._split_part(inside, forces)
        return self._functions[key]

    def _split_part(self, inside: list[Effect], forces: list[Effect]) -> SplitPart | None:
        """Built: ``split_part`` of the effects ``inside`` h, ``forces`` not unit terms."""
        p = ca.MX.sym("p", self.n_parameters)
        values = self._values(p)
        arguments, evaluators, start = [], [], 0
        for effect in forces:
            numeric = effect.numeric_force(self.model, values, p[self.slices[effect.name]])
            if numeric is None:
                return None
            arguments.append(numeric[0])
            evaluators.append((slice(start, start + numeric[0].numel()), numeric[1]))
            start += numeric[0].numel()
        terms = self._unit_terms([e for e in inside if e.unit_terms], "split_terms")
        if terms is None:
            return None
        q = ca.vertcat(*arguments)
        function = ca.Function("split_arguments", [p], [q, ca.jacobian(q, p)])
        return SplitPart(terms, function, tuple(evaluators))

    def case_parts(self, position: int) -> CaseParts:
        """The load and observation Functions of one case (no model part; built once).

        Kept for the cache's life, not dropped with their effect set's heavy Functions
        (``solvers.diagnosis.cache.SharedCache``): they hold no stiffness, and the sets
        that widen them (``_case_parts``) come and go in turn.
        """
        return self._case_entry("case_parts", position, self._case_parts)

    def _case_parts(self, position: int) -> CaseParts:
        """Built: the parts of the effects that change the case, widened to this set's
        p and s (``CaseParts.widened``) when they are fewer and add no state."""
        changing = [e for e in self.effects if changes_case(e)]
        if len(changing) < len(self.effects) and not any(
            e.extra_points(self.model) for e in changing
        ):
            fewer = ExtendedModel(self.model, self.names, changing, self.cases, self._functions)
            slices = [slice(0, len(self.names))] + [self.slices[e.name] for e in changing]
            columns = np.concatenate([np.arange(b.start, b.stop) for b in slices])
            parts, tail = fewer.case_parts(position), n_multipliers(self.model)
            return parts.widened(columns, self.n_parameters, self.n_state, tail)
        s, p, symbols, thetas = self._symbols(position)
        load = case_load(self.model, self.effects, self.cases[position], thetas, s.numel())
        r = case_observation(self.model, self.effects, self.cases[position], symbols, thetas)
        return CaseParts(
            load=ca.Function("load", [p], [load, ca.jacobian(load, p)]),
            observation=ca.Function(
                "observation", [s, p], [r, ca.jacobian(r, s), ca.jacobian(r, p)]
            ),
        )

    @property
    def n_state(self) -> int:
        """Length of s: free points' displacements, effects' extra state, multipliers."""
        extra = sum(e.extra_points(self.model) for e in self.effects)
        return 3 * (self.model.n_free + extra) + n_multipliers(self.model)

    def _values(self, p: ca.MX) -> dict:
        """All parameter values by name (``TissueModel.values``), x the first entries of p."""
        values = self.model.values()
        values.update({name: p[i] for i, name in enumerate(self.names)})
        return values

    def _symbols(self, position: int) -> tuple[ca.MX, ca.MX, CaseSymbols, list]:
        """Fresh s and p, the case symbols on s and every effect's theta (a slice of p)."""
        model = self.model
        n_free = model.n_free
        extra_sizes = [e.extra_points(model) for e in self.effects]
        s = ca.MX.sym("s", self.n_state)
        p = ca.MX.sym("p", self.n_parameters)
        values = self._values(p)
        symbols = CaseSymbols(ca.reshape(s[: 3 * n_free], n_free, 3), values)
        start = 3 * n_free
        for effect, size in zip(self.effects, extra_sizes):
            if size:
                symbols.extra[effect.name] = ca.reshape(s[start : start + 3 * size], size, 3)
                start += 3 * size
        if model.n_constraints:
            symbols.lam = ca.reshape(s[start:], model.n_constraints, 3)
        thetas = [effect.block(p[self.slices[effect.name]], position) for effect in self.effects]
        return s, p, symbols, thetas

    def _build(self, position: int) -> CaseFunctions:
        """The case's Functions: the shared model part (``_model_part``) plus its load.

        g(s, p) = h(s, p) - F_B(theta; case): what the case adds, its declared load and
        the load effects' change of it, depends on p alone, so dg/ds is h's and the
        case's only derivatives are the load's d/dp and the observation's.
        """
        s, p, symbols, thetas = self._symbols(position)
        h, h_ds, h_dp = self._model_part(position)
        load = case_load(self.model, self.effects, self.cases[position], thetas, s.numel())
        g = h(s, p) + load
        r = case_observation(self.model, self.effects, self.cases[position], symbols, thetas)
        return CaseFunctions(s, p, g, r, h_ds(s, p), h_dp(s, p) + ca.jacobian(load, p))

    def _model_part(self, position: int) -> tuple:
        """h(s, p) = K(B; x) Delta + the effects' internal forces and extra rows, with
        dh/ds and dh/dp: the part of g no load case changes, built once per effect set.

        dh/ds is the base model's block in closed form (a linear model's K(x), one
        sparse product, or the numeric neo-Hookean tangent) plus the linear effects'
        K_theta, AD doing the other effects; all of it by AD, once, when the base model
        has no tangent (the D-NURBS K(B)).
        """
        # a per-case effect outside h (a measurement) leaves it the same for every case
        per_case = any(e.per_case and enters_model_part(e) for e in self.effects)
        key = (
            "functions",
            self.effect_set,
            "model_part",
            id(self.model),
            position if per_case else 0,
            tuple(self.labels),
        )
        if key in self._functions:
            return self._functions[key]
        model = self.model
        n_free = model.n_free
        s, p, symbols, thetas = self._symbols(position)
        x = ca.vertcat(*[symbols.values[n] for n in self.names])
        base = ca.vec(self._base_force()(symbols.delta, x))
        force, extra_rows = ca.MX(n_free, 3), []
        closed, tangents = ca.MX(n_free, 3), []  # forces with a closed-form tangent
        for effect, theta in zip(self.effects, thetas):
            term = effect.internal_force(model, symbols, theta)
            tangent = None if term is None else effect.internal_tangent(model, symbols, theta)
            if tangent is not None:
                closed, tangents = closed + term, tangents + [tangent]
            elif term is not None:
                force = force + term
            rows = effect.extra_residual(model, symbols, theta)
            if rows is not None:
                extra_rows.append(ca.vec(rows))
        n_state = s.numel()
        padding = n_state - 3 * n_free
        rest = ca.vertcat(ca.vec(force), *extra_rows, ca.MX(n_multipliers(model), 1))
        rest = with_constraint_rows(model, rest, s)
        linear = self._linear_effects()
        if linear is not None:
            base = base + ca.vec(linear[0](symbols.delta, p))
        base = base + ca.vec(closed)
        h = ca.vertcat(base, ca.MX(padding, 1)) + rest
        if model.is_linear(self.names):
            stiffness = self._base_stiffness()(x)
        else:
            tangent = self._base_tangent()
            stiffness = None if tangent is None else tangent(s[: 3 * n_free], x)
        if stiffness is None:
            dh_ds = ca.jacobian(h, s)
        else:
            if linear is not None:
                stiffness = stiffness + linear[1](p)
            for tangent in tangents:
                stiffness = stiffness + tangent
            dh_ds = ca.diagcat(stiffness, ca.MX(padding, padding)) + ca.jacobian(rest, s)
        made = (
            ca.Function("model_part", [s, p], [h]),
            ca.Function("model_part_ds", [s, p], [dh_ds]),
            ca.Function("model_part_dp", [s, p], [ca.jacobian(h, p)]),
        )
        self._functions[key] = made
        return made

    def _linear_effects(self) -> tuple[ca.Function, ca.Function] | None:
        """The ``linear`` effects' (Delta, p) -> sum K_theta vec(Delta) and p -> sum K_theta.

        Built once per effect set (not per case), so the stiffness constants are
        stored once; None when no effect is linear.
        """
        chosen = [e for e in self.effects if e.linear]
        if not chosen:
            return None
        key = ("functions", self.effect_set, "linear", tuple(self.labels))
        if key not in self._functions:
            p = ca.MX.sym("p", self.n_parameters)
            delta = ca.MX.sym("delta", self.model.n_free, 3)
            values = self._values(p)
            total = sum(e.stiffness(self.model, values, p[self.slices[e.name]]) for e in chosen)
            self._functions[key] = (
                ca.Function("linear_force", [delta, p], [apply_stacked(total, delta)]),
                ca.Function("linear_stiffness", [p], [total]),
            )
        return self._functions[key]

    def _base_force(self) -> ca.Function:
        """K(B; x)(B - B0) of the base model as a Function of (Delta, x) (built once)."""
        key = ("base_force", id(self.model), self.names)
        if key not in self._functions:
            x, values = self.model.symbolic_values(self.names)
            delta = ca.MX.sym("delta", self.model.n_free, 3)
            force = self.model.elastic_force(delta, values, self.names)
            self._functions[key] = ca.Function("elastic", [delta, x], [force])
        return self._functions[key]

    def _base_tangent(self) -> ca.Function | None:
        """(vec(Delta_free), x) -> the base model's numeric tangent as a CasADi callback,
        or None when the model has none (``TissueModel.tangent``; built once)."""
        key = ("base_tangent", id(self.model), self.names)
        if key not in self._functions:
            tangent = self.model.tangent(self.names)
            if tangent is not None:
                n = 3 * self.model.n_free
                pattern = tangent(np.zeros(n), [self.model.parameters[k] for k in self.names])
                sizes = (n, len(self.names))
                tangent = SparseCallback("base_tangent", tangent, sizes, pattern)
            self._functions[key] = tangent
        return self._functions[key]

    def _base_stiffness(self) -> ca.Function:
        """x -> K(x) on the free points, stacked, of a linear base model (built once)."""
        key = ("base_stiffness", id(self.model), self.names)
        if key not in self._functions:
            x, coefficients, terms = self.model.linear_terms(self.names)
            stiffness = self.model.stiffness_expression(coefficients, terms)
            self._functions[key] = ca.Function("stiffness", [x], [stiffness])
        return self._functions[key]
