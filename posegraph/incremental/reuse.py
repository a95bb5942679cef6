"""The whole graph's last evaluation and linearisation, extended to new edges instead of recomputed.

Gauss-Newton on the whole graph stops after linearising at its final point (the stopping test needs
the gradient there). Until the next update that solves, the front end only adds vertices placed by
composition and their edges: the poses already in do not move, so every old edge's residual, Jacobian
factors and gradient blocks at the next start are those of that final point. :class:`LastPoint` keeps
them and, at the next solve, computes only the new edges' (the solver's own
:class:`~posegraph.solve.objective.Objective` on those edges) and joins the two: one whole-graph
evaluation and one linearisation fewer per update. It is used only when it is exact: the first ``n``
poses equal bit for bit the ones it was made at, the edges are the same ones with new ones appended
(a removal resets it), and the graph has no priors (their terms are not split by edge here).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.solve.linearize import EdgeBlocks
from posegraph.solve.objective import Evaluation, Objective

__all__ = ["LastPoint"]


class LastPoint:
    """The evaluation and linearisation of the whole graph at its last solved point (module docstring)."""

    def __init__(self):
        self.clear()

    def clear(self) -> None:
        self.poses = self.points = self.evaluation = self.blocks = None

    def keep(self, poses: np.ndarray, evaluation: Evaluation, blocks: EdgeBlocks | None) -> None:
        """Remember ``evaluation`` and ``blocks`` (None: a solve that stopped without linearising), both
        made at ``poses`` ``(n, k, k)`` (copied) and the landmarks' points of ``evaluation`` (copied)."""
        self.poses, self.evaluation, self.blocks = poses.copy(), evaluation, blocks
        self.points = None if evaluation.points is None else np.array(evaluation.points, copy=True)

    def extended(self, objective: Objective, poses: np.ndarray, points: np.ndarray | None = None):
        """``(evaluation, blocks)`` of ``objective`` at ``poses`` and landmark ``points`` ``(L, s)``, from the
        kept ones and the new edges and landmark measurements alone (``blocks`` None when none were kept);
        None when the kept ones do not apply (nothing kept, priors, a kept pose or point moved)."""
        graph, kept = objective.graph, self.poses
        if kept is None or graph.priors is not None or poses.shape[0] < kept.shape[0]:
            return None
        if not np.array_equal(poses[: kept.shape[0]], kept) or not self._points_kept(graph, points):
            return None
        old = self.evaluation.residuals.shape[0]
        part = slice(old, graph.num_edges)
        new_graph = replace(graph, edge_from=graph.edge_from[part], edge_to=graph.edge_to[part],
                            measurements=graph.measurements[part], information=graph.information[part],
                            landmarks=_new_measurements(graph.landmarks, self.evaluation.landmarks))
        new = Objective(new_graph, objective.loss)
        evaluation = new.evaluate(poses, points)
        if self.blocks is None:  # (with landmarks the joined evaluation cannot be linearised: not kept so)
            return _joined_evaluation(self.evaluation, evaluation), None
        return _joined_evaluation(self.evaluation, evaluation), _joined_blocks(self.blocks, new.linearize(poses, evaluation),
                                                                               objective.information)

    def _points_kept(self, graph, points: np.ndarray | None) -> bool:
        """Whether the kept landmark terms apply: none either way, or the kept points unmoved, the kept
        measurements a prefix of each family (new families none), and blocks kept."""
        if graph.landmarks is None or self.evaluation.landmarks is None:
            return graph.landmarks is None and self.evaluation.landmarks is None
        kept, residuals = self.points, self.evaluation.landmarks.residuals
        families = graph.landmarks.observations
        return (self.blocks is not None and points.shape[0] >= kept.shape[0] and np.array_equal(points[: kept.shape[0]], kept)
                and len(families) == len(residuals) and all(f.count >= e.shape[0] for f, e in zip(families, residuals)))


def _join(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    return None if a is None else np.concatenate([a, b])


def _new_measurements(landmarks, kept):
    """``landmarks`` with each family's measurements after the ``kept`` ones' (``LandmarkErrors``) only."""
    if landmarks is None:
        return None
    families = tuple(replace(f, pose=None if f.pose is None else f.pose[e.shape[0]:], landmark=f.landmark[e.shape[0]:],
                             measurements=f.measurements[e.shape[0]:], information=f.information[e.shape[0]:],
                             offsets=None if f.offsets is None else f.offsets[e.shape[0]:], lines=None, offset_ids=None, text=None)
                     for f, e in zip(landmarks.observations, kept.residuals))  # fmt: skip
    return replace(landmarks, observations=families)


def _per_family(old, new, counts_old, counts_new):
    """Per-measurement arrays over all families ``(Σq,)`` joined family by family, old rows first."""
    a, b = np.split(old, np.cumsum(counts_old)[:-1]), np.split(new, np.cumsum(counts_new)[:-1])
    return np.concatenate([x for pair in zip(a, b) for x in pair])


def _joined_landmarks(old, new):
    """The landmark errors of the kept measurements then the new ones, family by family (``sensed``
    left out: a joined evaluation is not linearised, :meth:`LastPoint.extended`)."""
    from posegraph.solve.landmark_terms import LandmarkErrors

    if old is None:
        return None
    counts_old, counts_new = [e.shape[0] for e in old.residuals], [e.shape[0] for e in new.residuals]
    residuals = tuple(np.concatenate([a, b]) for a, b in zip(old.residuals, new.residuals))
    return LandmarkErrors(residuals, _per_family(old.squared, new.squared, counts_old, counts_new)), (counts_old, counts_new)


def _joined_evaluation(old: Evaluation, new: Evaluation) -> Evaluation:
    """The evaluation of the old edges then the new ones (no priors), landmark measurements likewise family
    by family: per-edge arrays joined, costs summed."""
    joined = _joined_landmarks(old.landmarks, new.landmarks)
    landmarks, weights = (None, None) if joined is None else (joined[0], old.landmark_weights)
    if joined is not None and weights is not None:
        weights = _per_family(old.landmark_weights, new.landmark_weights, *joined[1])
    return Evaluation(relative=np.concatenate([old.relative, new.relative]),
                      residuals=np.concatenate([old.residuals, new.residuals]),
                      cost=old.cost + new.cost, weights=_join(old.weights, new.weights), points=new.points,
                      landmarks=landmarks, landmark_weights=weights,
                      weighted_residuals=_join(old.weighted_residuals, new.weighted_residuals))


def _joined_landmark_blocks(old, new, d: int):
    """The landmark families' blocks of the kept measurements then the new ones (``LandmarkBlocks``)."""
    from posegraph.solve.landmark_terms import LandmarkBlocks

    if old is None:
        return None
    hessian = []
    for a, b, ga, gb in zip(old.hessian, new.hessian, old.gradient, new.gradient):
        width = ga.shape[1]  # d + s of a pose–point family, s (< d) of point priors
        sizes = [d * d, (width - d) ** 2, d * (width - d)] if width > d else [width * width]
        split = lambda h, q: np.split(h, np.cumsum([q * z for z in sizes])[:-1])  # noqa: E731
        hessian.append(np.concatenate([x for pair in zip(split(a, ga.shape[0]), split(b, gb.shape[0])) for x in pair]))
    gradient = tuple(np.concatenate([a, b]) for a, b in zip(old.gradient, new.gradient))
    return LandmarkBlocks(tuple(hessian), gradient)


def _joined_blocks(old: EdgeBlocks, new: EdgeBlocks, information: np.ndarray) -> EdgeBlocks:
    """The linearisation of the old edges then the new ones; ``information`` ``(m, d, d)`` all edges'."""
    return EdgeBlocks(residuals=np.concatenate([old.residuals, new.residuals]), cost=old.cost + new.cost,
                      gradient=np.concatenate([old.gradient, new.gradient]),
                      jacobian_inverse=np.concatenate([old.jacobian_inverse, new.jacobian_inverse]),
                      adjoint=np.concatenate([old.adjoint, new.adjoint]), information=information,
                      weights=_join(old.weights, new.weights),
                      landmarks=_joined_landmark_blocks(old.landmarks, new.landmarks, information.shape[-1]))
