"""The cost the solver minimises and its linearisation, with an optional robust loss.

Without a loss the cost is ``F(X) = ½ Σ eᵀ Ω e`` (:mod:`posegraph.solve.residuals`) and the
linearisation the Gauss-Newton system (:func:`posegraph.solve.linearize.linearize`), exactly.
A loss ``ρ`` of the squared norm ``s = eᵀΩe`` of each edge makes it ``F(X) = ½ Σ ρ(s)``
(``ρ(s) = s`` is least squares), linearised by iteratively reweighted least squares: per edge
the weight ``w = ρ'(s)``, which makes ``g = Σ w JᵀΩe`` the exact gradient of that cost and
``H = Σ w JᵀΩJ`` its IRLS approximation (Triggs et al., *Bundle adjustment — a modern
synthesis*, §4.3). The solver loop sees only :meth:`Objective.evaluate` and
:meth:`Objective.linearize`, so a loss plugs in through ``SolverParams.loss`` without any
change to it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Protocol

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.solve.linearize import EdgeBlocks, linearize
from posegraph.solve.residuals import edge_errors, weighted_residuals
from posegraph.solve.unary import PriorErrors, linearize_priors, prior_errors, prior_squared_norms

if TYPE_CHECKING:
    from posegraph.solve.landmark_terms import LandmarkErrors

__all__ = ["Loss", "Evaluation", "Objective"]


class Loss(Protocol):
    """A robust loss of the squared Mahalanobis norm ``s = eᵀΩe`` of each edge: cost ``½ Σ ρ(s)``."""

    def rho(self, s: np.ndarray) -> np.ndarray:
        """``(m,) -> (m,)``: ``ρ(s)``, with ``ρ(0) = 0``, ``ρ'(0) = 1`` (``ρ(s) = s`` is no loss)."""

    def weight(self, s: np.ndarray) -> np.ndarray:
        """``(m,) -> (m,)``: ``ρ'(s) ≥ 0``, the IRLS weight of each edge."""


@dataclass(frozen=True, eq=False)
class Evaluation:
    """The cost at one set of poses, with what its linearisation reuses."""

    relative: np.ndarray
    """``(m, k, k)`` relative poses ``X_i⁻¹ X_j``."""
    residuals: np.ndarray
    """``(m, d)`` residuals ``e = Log(Z⁻¹ X_i⁻¹ X_j)``."""
    cost: float
    """``½ Σ eᵀΩe``, or ``½ Σ ρ(eᵀΩe)`` with a loss."""
    weights: np.ndarray | None = None
    """``(m,)`` IRLS weights ``ρ'(s)``, None without a loss."""
    priors: PriorErrors | None = None
    """The priors' residuals (:mod:`posegraph.solve.unary`), None for a graph without priors."""
    prior_weights: np.ndarray | None = None
    """``(a + b,)`` IRLS weights of the priors, None without a loss or priors."""
    points: np.ndarray | None = None
    """``(L, s)`` the landmark positions evaluated, None for a pose graph."""
    landmarks: LandmarkErrors | None = None
    """The landmark measurements' residuals (:mod:`posegraph.solve.landmark_terms`), None without landmarks."""
    landmark_weights: np.ndarray | None = None
    """``(Σq,)`` IRLS weights of the landmark measurements, None without a loss or landmarks."""
    weighted_residuals: np.ndarray | None = None
    """``(m, d)`` ``Ω e`` per edge (the cost's and the gradient's common factor: the linearisation reuses it)."""


class Objective:
    """``F`` over the poses of ``graph``: evaluation and linearisation, with an optional :class:`Loss`."""

    def __init__(self, graph: PoseGraph, loss: Loss | None = None):
        self.graph = graph
        self.loss = loss
        # C-contiguous once: batched d×d products are several times slower on other layouts
        self.information = np.ascontiguousarray(graph.information)

    def evaluate(self, poses: np.ndarray, points: np.ndarray | None = None) -> Evaluation:
        """The cost at ``poses`` ``(n, k, k)`` and landmark ``points`` ``(L, s)`` (graphs with landmarks),
        the priors' and landmark measurements' terms included (a loss applies to them too)."""
        relative, residuals = edge_errors(poses, self.graph)
        priors = prior_errors(poses, self.graph) if self.graph.priors is not None else None
        prior_s = prior_squared_norms(priors, self.graph.priors) if priors is not None else np.zeros(0)
        landmarks = None
        if self.graph.landmarks is not None:  # (imported here: a pose graph's run does without the module)
            from posegraph.solve.landmark_terms import landmark_errors

            landmarks = landmark_errors(self.graph, poses, points)
        landmark_s = landmarks.squared if landmarks is not None else np.zeros(0)
        omega_e = weighted_residuals(residuals, self.information)
        if self.loss is None:
            cost = 0.5 * float(np.einsum("mi,mi->", residuals, omega_e)) + 0.5 * float(np.sum(prior_s)) + 0.5 * float(np.sum(landmark_s))
            return Evaluation(relative, residuals, cost, priors=priors, points=points, landmarks=landmarks, weighted_residuals=omega_e)
        s = np.einsum("mi,mi->m", residuals, omega_e)
        rho = self.loss.rho
        cost = 0.5 * (float(np.sum(rho(s))) + float(np.sum(rho(prior_s))) + float(np.sum(rho(landmark_s))))
        weights = np.asarray(self.loss.weight(s), dtype=np.float64)
        prior_weights = np.asarray(self.loss.weight(prior_s), dtype=np.float64) if priors is not None else None
        landmark_weights = np.asarray(self.loss.weight(landmark_s), dtype=np.float64) if landmarks is not None else None
        return Evaluation(relative, residuals, cost, weights, priors, prior_weights, points, landmarks, landmark_weights, omega_e)

    def linearize(self, poses: np.ndarray, evaluation: Evaluation) -> EdgeBlocks:
        """Per-edge gradient and Hessian blocks at ``poses``, which ``evaluation`` evaluated (and the priors')."""
        errors = (evaluation.relative, evaluation.residuals)
        blocks = linearize(poses, self.graph, self.information, errors, weights=evaluation.weights,
                           weighted=evaluation.weighted_residuals)
        if evaluation.priors is not None:
            blocks = replace(blocks, priors=linearize_priors(poses, self.graph, evaluation.priors, evaluation.prior_weights))
        if evaluation.landmarks is not None:
            from posegraph.solve.landmark_terms import linearize_landmarks

            landmarks = linearize_landmarks(self.graph, poses, evaluation.points, evaluation.landmark_weights, evaluation.landmarks)
            blocks = replace(blocks, landmarks=landmarks)
        return blocks
