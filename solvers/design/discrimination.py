"""Which press tells the competing explanations apart: the sequential rule's questions.

After a diagnosis, the data leave questions open. Each is a question a press can
answer, judged on the pool's Gram matrix M(D) of eq. (D5):

- **detect e**: were effect e there at its realistic magnitude, would the loop's score
  test see it, on top of the effects the model already has? Its value is the
  non-centrality lambda of eq. (D2), the model's own effects refitted with x; it is
  answered when the power (D3) reaches the goal.
- **separate a from b**: the loop named a (fitted theta_a); could the rival b explain
  the same residual? Its value is the expected lack of fit of the rival, refitted,
  when a is the truth (T-optimality, Atkinson & Fedorov 1975):

      T_ab = |(I - P_[x, theta_b]) s_a|^2 / sigma^2                                  (D6)

  with s_a = rho(x, theta_a) - rho(x, 0) the named effect's solved signal and P the
  projection onto the columns of x, of the model's other effects and of theta_b. The
  loop keeps a over b when a's chi^2 drop beats b's by more than its rival margin m
  (``DiagnosisSettings.rival_margin``, 3.84). To first order the difference of the
  drops is T_ab plus noise of variance at most 4 (T_ab + 1) (a linear term 2 (s - P_b
  s)^T e, and e^T (P_a - P_b) e for one-parameter effects), so the separation reaches
  probability ``goal`` when

      T_ab >= t^2 - 1,   t = z + sqrt(z^2 + 1 + m),   z = Phi^-1(goal)             (D6')

  (13.6 for goal 0.9 and m = 3.84).

A question is **answered** when its value reaches the need. It is **open** when it is
not answered and the remaining budget could answer it: its value plus the remaining
presses times the best single press's gain reaches the need (an estimate; presses add
less than that when they share the rest markers' noise). Open questions keep the loop
going; a question no budget can answer does not, and is reported as such
(docs/design.md).

The next press maximises the progress over every unanswered question,

    score(D) = sum_q log min(value_q(D) / need_q, 1)                               (D7)

one press at a time on top of the presses made. **Choice:** a product of progress, not
the least ratio (maximin). A question far from its need, e.g. an effect whose
realistic magnitude no budget detects, then still steers the press towards where its
value grows most in proportion, so the loop lowers its detection limit on the way;
under maximin it would rule every press, or, once dropped as unreachable, be ignored.
A question whose value no press changes (confounded) adds a constant and steers
nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from solvers.design.information import projected_signal, scaled_inverse
from solvers.design.pool import InformationPool, Layout, Totals
from solvers.diagnosis.stats import needed_noncentrality

DETECT, SEPARATE = "detect", "separate"


def lack_of_fit(gram: np.ndarray, nuisance, signal: int) -> float:
    """|(I - P_N) s|^2 [mm^2]: what the columns ``nuisance`` leave of the signal column.

    The Schur complement G_ss - G_sN G_NN^+ G_Ns of the Gram matrix (``scaled_inverse``).
    """
    nuisance = np.asarray(nuisance, dtype=int)
    total = float(gram[signal, signal])
    if not nuisance.size:
        return total
    unit, inverse = scaled_inverse(gram, nuisance)
    g_ns = gram[nuisance, signal] * unit
    return float(max(total - g_ns @ inverse @ g_ns, 0.0))


def needed_separation(margin: float, goal: float) -> float:
    """T_ab at which a beats b by more than ``margin`` with probability ``goal`` (D6')."""
    z = float(stats.norm.ppf(goal))
    t = z + np.sqrt(z * z + 1.0 + margin)
    return float(t * t - 1.0)


@dataclass(frozen=True)
class Question:
    """One question a press can answer (the module's docstring).

    Attributes
    ----------
    kind : str
        ``detect`` or ``separate``.
    effect : int
        The layout's index of the effect asked about (e, or the named a).
    rival : int or None
        The layout's index of b (``separate``).
    given : tuple of int
        The layout's indices of the effects the model already has, refitted with x.
    needed : float
        The value that answers it [1].
    """

    kind: str
    effect: int
    rival: int | None
    given: tuple[int, ...]
    needed: float

    def label(self, layout: Layout) -> str:
        """``detect E`` or ``separate A from B``."""
        name = layout.effects[self.effect][0].name
        if self.kind == DETECT:
            return f"detect {name}"
        return f"separate {name} from {layout.effects[self.rival][0].name}"

    def value(self, matrix: np.ndarray, layout: Layout, sigma: float) -> float:
        """lambda (D2) or T_ab (D6) on the design of Gram matrix ``matrix`` [1]."""
        others = [k for k in self.given if k != self.effect]
        if self.rival is not None:
            others.append(self.rival)
        nuisance = np.concatenate([layout.nuisance] + [layout.blocks[k][0] for k in others])
        theta, signal = layout.blocks[self.effect]
        if self.kind == DETECT:
            scale = np.asarray(layout.effects[self.effect][0].scales, dtype=float)
            projected, _ = projected_signal(matrix, nuisance, theta, signal, scale)
            return projected / sigma**2
        return lack_of_fit(matrix, nuisance, signal) / sigma**2


def questions(
    layout: Layout, named: list[int], level: float, goal: float, margin: float
) -> list[Question]:
    """Separate every named effect from every other effect of the layout; detect every
    effect not named (on top of the named ones).

    ``level`` is the score tests' level (the loop's Bonferroni level); ``margin`` the
    loop's rival margin.
    """
    given = tuple(named)
    out = []
    for a in named:
        needed = needed_separation(margin, goal)
        out += [
            Question(SEPARATE, a, b, given, needed)
            for b in range(len(layout.effects))
            if b not in named
        ]
    for e, (effect, _) in enumerate(layout.effects):
        if e in named:
            continue
        one_sided = effect.dim == 1 and float(np.asarray(effect.lower)[0]) == 0.0
        needed = needed_noncentrality(effect.dim, level, one_sided, goal)
        out.append(Question(DETECT, e, None, given, needed))
    return out


@dataclass(frozen=True)
class Standing:
    """Where a question stands on the presses made.

    Attributes
    ----------
    question : Question
    value : float
        Its value now [1].
    best_gain : float
        The largest rise one more candidate press gives [1].
    answered, reachable : bool
        value >= needed; value + remaining * best_gain >= needed.
    """

    question: Question
    value: float
    best_gain: float
    answered: bool
    reachable: bool

    @property
    def ratio(self) -> float:
        """value / needed."""
        return self.value / self.question.needed


def standings(
    pool: InformationPool,
    asked: list[Question],
    made: Totals,
    candidates: list[int],
    sigma: float,
    remaining: int,
) -> list[Standing]:
    """Every question's ``Standing`` after the presses ``made``, with ``remaining`` to go."""
    now = made.matrix()
    after = [(made + pool.blocks[k]).matrix() for k in candidates]
    out = []
    for question in asked:
        value = question.value(now, pool.layout, sigma)
        gains = [question.value(m, pool.layout, sigma) - value for m in after]
        best = max(gains, default=0.0)
        answered = value >= question.needed
        reachable = answered or value + remaining * max(best, 0.0) >= question.needed
        out.append(Standing(question, value, best, answered, reachable))
    return out


@dataclass(frozen=True)
class Discrimination:
    """The sequential rule's criterion, eq. (D7), over ``asked`` (a ``Criterion`` for
    ``solvers.design.search``)."""

    asked: tuple[Question, ...]
    layout: Layout
    sigma: float

    def score(self, matrix: np.ndarray) -> float:
        """sum over the questions of log min(value / needed, 1) (larger is better; 0 when
        every question is answered)."""
        ratios = [q.value(matrix, self.layout, self.sigma) / q.needed for q in self.asked]
        return float(np.sum(np.log(np.clip(ratios, 1e-12, 1.0))))
