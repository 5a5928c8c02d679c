"""The next press for a stiffness map: where an inclusion would be seen best
(docs/imaging.md, "Adaptive imaging", eqs. I11-I14).

Linearised at a homogeneous fit (c = 0, ``solvers.imaging.fieldproblem``), press k contributes
rows to the residual: its field sensitivities J_k (n_k, N), the held nu's column and its
data y_k, all over sigma and before whitening, with the map P_k of the rest-marker
noise into its rows. A set S of presses is whitened together,

    W_S = (I + P_S P_S^T)^-1/2,                                                   (I11)

because the rest capture is shared by every press (``solvers.inverse.noise``), and nu is
profiled out by projection, as the map's own nu is. Then, with t_p the field of an
inclusion of the target's size and contrast centred at place p:

- **where it is**: the posterior over the places and "no inclusion",

      pi_p ~ pi_0 / m exp(-|y_S + J_S t_p|^2 / 2),   pi_none ~ (1 - pi_0) exp(-|y_S|^2 / 2)  (I12)

  (m places, uniform; y the whitened data, which an inclusion at p would explain);
- **the next press** k maximises the expected growth of the inclusion's signal
  lambda_p(S) = |J_S t_p|^2 over the posterior of its place,

      score(k) = sum_p pi_p log(lambda_p(S + k) / lambda_p(S))                    (I13)

  (the log: progress where the inclusion is seen least counts most, as eq. D7 of
  docs/design.md; with a flat posterior the press that covers the area best, once an
  inclusion shows, the press that sees it best);
- **stop** when the inclusion is known: the posterior mass within ``radius`` of its
  mode reaches the goal and its amplitude's standard error there, lambda^-1/2 in units
  of the target's log-contrast, is at most ``precision``; or when "no inclusion" has
  the goal's mass                                                                  (I14).

The problem is linear (the weight study's, ``experiments.imaging.weightstudy``): the
map's own nonlinearity and the fit's point are not in it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.special import logsumexp

from solvers.inverse.noise import Whitening


@dataclass
class PressRows:
    """Per press, the rows it adds to the residual, before whitening, over sigma.

    Attributes
    ----------
    J : list of numpy.ndarray
        (n_k, N) field sensitivities of each press [1].
    nu : list of numpy.ndarray
        (n_k,) the held Poisson ratio's column.
    y : list of numpy.ndarray
        (n_k,) the residual at c = 0 (the data the map explains).
    P : list of scipy.sparse.csr_matrix
        (n_k, n_rest) the rest-marker noise map of each press's rows.
    """

    J: list
    nu: list
    y: list
    P: list

    @classmethod
    def split(cls, problem, J_w, nu_w, y_w) -> PressRows:
        """The rows of every load case of a ``FieldProblem`` from its whitened J, nu column
        and residual at c = 0 (unwhitened with ``Whitening.root``)."""
        p_map = problem.problem.rest_noise_map()
        n = J_w.shape[0]
        root = Whitening.root(p_map, n)
        J, nu, y = (_in_spans(problem, root @ v) for v in (J_w, nu_w, y_w))
        p_map = sp.csr_matrix((n, 0)) if p_map is None else p_map.tocsr()
        return cls(J, nu, y, _in_spans(problem, p_map))

    def __len__(self) -> int:
        return len(self.J)

    def select(self, presses, y=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened J_S and y_S of ``presses`` (eq. I11), nu profiled out, and nu's unit
        direction q (J_S and y_S are orthogonal to it); ``y`` other data per press (e.g.
        another noise draw) instead of the stored."""
        presses = list(presses)
        data = self.y if y is None else y
        p_map = sp.vstack([self.P[k] for k in presses]).tocsr()
        n = p_map.shape[0]
        whiten = Whitening.of(p_map if p_map.shape[1] else None, n).matrix
        J = whiten @ np.vstack([self.J[k] for k in presses])
        nu = whiten @ np.concatenate([self.nu[k] for k in presses])
        y_s = whiten @ np.concatenate([data[k] for k in presses])
        q = nu / np.linalg.norm(nu)
        return J - np.outer(q, q @ J), y_s - q * (q @ y_s), q


def _in_spans(problem, rows) -> list:
    """``rows`` (stacked over a ``FieldProblem``'s load cases) cut per load case."""
    edges = np.concatenate([[0], np.cumsum([len(b) for b in problem.b])])
    return [rows[a:b] for a, b in zip(edges[:-1], edges[1:])]


def per_press(problem, whitened: np.ndarray) -> list:
    """A ``FieldProblem``'s whitened rows (a vector, or a matrix by rows), unwhitened
    (``Whitening.root``, over sigma) and cut per load case."""
    root = Whitening.root(problem.problem.rest_noise_map(), whitened.shape[0])
    return _in_spans(problem, root @ whitened)


def inclusion_templates(xy, places, radius_mm: float, log_ratio: float) -> np.ndarray:
    """(N, m): the field of an inclusion centred at each place, log_ratio on the field
    nodes within ``radius_mm`` of it, 0 elsewhere (nodal coefficients).

    Parameters
    ----------
    xy : numpy.ndarray
        (N, 2) the field nodes' positions [mm].
    places : numpy.ndarray
        (m, 2) the candidate centres [mm].
    """
    distance = np.linalg.norm(xy[:, None, :] - np.asarray(places)[None, :, :], axis=2)
    templates = np.where(distance <= radius_mm, log_ratio, 0.0)
    nearest = np.argmin(distance, axis=0)  # a place between nodes keeps its nearest one
    templates[nearest, np.arange(len(places))] = log_ratio
    return templates


@dataclass(frozen=True)
class PlacePosterior:
    """Eq. (I12): the probability of each place and of no inclusion."""

    places: np.ndarray
    probability: np.ndarray
    none: float

    @classmethod
    def of(cls, J, y, templates, places, prior_none: float = 0.5) -> PlacePosterior:
        """From the whitened J_S and y_S of the presses so far."""
        signal = J @ templates
        log_like = -0.5 * np.sum((y[:, None] + signal) ** 2, axis=0)
        m = templates.shape[1]
        logs = np.concatenate(
            [np.log((1 - prior_none) / m) + log_like, [np.log(prior_none) - 0.5 * (y @ y)]]
        )
        weights = np.exp(logs - logsumexp(logs))
        return cls(np.asarray(places), weights[:-1], float(weights[-1]))

    def mode(self) -> np.ndarray:
        """The most probable place [mm]."""
        return self.places[int(np.argmax(self.probability))]

    def localised(self, radius_mm: float) -> float:
        """The posterior mass within ``radius_mm`` of the mode."""
        near = np.linalg.norm(self.places - self.mode(), axis=1) <= radius_mm
        return float(self.probability[near].sum())

    def known(self, J, templates, radius_mm: float, goal: float, precision: float) -> bool:
        """Eq. (I14) on the whitened J_S of the presses so far."""
        if self.none >= goal:
            return True
        mode = int(np.argmax(self.probability))
        information = float(np.sum((J @ templates[:, mode]) ** 2))
        return self.localised(radius_mm) >= goal and information >= precision**-2


def press_scores(rows: PressRows, chosen, candidates, templates, weights) -> np.ndarray:
    """Eq. (I13) of every candidate press: sum_p w_p log(lambda_p(S + k) / lambda_p(S)),
    lambda_p = |J t_p|^2 whitened with the press's rows in (shared rest noise)."""
    J_s = rows.select(chosen)[0]
    before = np.sum((J_s @ templates) ** 2, axis=0)
    scores = np.empty(len(candidates))
    for i, k in enumerate(candidates):
        J_k = rows.select(list(chosen) + [k])[0]
        after = np.sum((J_k @ templates) ** 2, axis=0)
        scores[i] = float(weights @ np.log(after / before))
    return scores
