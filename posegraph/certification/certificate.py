"""``certify(graph)``: SE-Sync's certificate of global optimality, trying a cheap candidate first.

1. Candidate: Levenberg-Marquardt (:func:`posegraph.optimize`, chordal start) on the graph with each
   information replaced by its isotropic counterpart ``Ω = diag(4κ I, 2τ I)`` — the geodesic cost
   whose second-order expansion is SE-Sync's ``F`` (``‖R − I‖_F² ≈ 2θ²``), so its optimum is a few
   Newton steps from F's — then :func:`posegraph.certification.local.refine_poses` to F's critical point.
2. Verification at rank d: ``S = M − diag(0, Λ)``, PSD by one Cholesky of ``S + η I``
   (:mod:`posegraph.certification.verify`). When that succeeds the candidate is the global optimum.
3. Otherwise the Riemannian staircase (:mod:`posegraph.certification.staircase`) from rank d+1, escaping
   along the negative eigenvector, and SE-Sync's rounding of its last point.

``certified`` is True only when S is numerically PSD *and* the rounded estimate's suboptimality
bound ``F(x̂) − tr Λ`` is at most :data:`RELATIVE_GAP_TOLERANCE`·F + :data:`ABSOLUTE_GAP_TOLERANCE`: a relaxation that is not tight (a
rank > d solution whose rounding loses) is reported as not certified, with the bound.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import SyncProblem, euclidean_gradient, objective, sync_problem
from posegraph.certification.verify import DEFAULT_ETA, certificate_matrix, lambda_blocks, verify
from posegraph.graph import PoseGraph

__all__ = ["Certificate", "certify", "RELATIVE_GAP_TOLERANCE", "isotropic_graph", "candidate_poses", "poses_to_blocks",
           "blocks_to_poses"]

RELATIVE_GAP_TOLERANCE = 1e-6
"""Largest ``(F(x̂) − tr Λ) / F`` still called certified (SE-Sync prints F to 6 digits) …"""
ABSOLUTE_GAP_TOLERANCE = 1e-9
"""… plus this much, for the noise-free graphs whose F is 0 to round-off."""


@dataclass
class Certificate:
    """What :func:`certify` found (the report of ``posegraph certify``)."""

    certified: bool
    """S ⪰ −ηI and the suboptimality bound within :data:`RELATIVE_GAP_TOLERANCE`·F: ``poses`` is a global
    minimiser of SE-Sync's isotropic objective (not of the graph's anisotropic cost)."""
    sesync_objective: float
    """``F(x̂)``, SE-Sync's objective at the returned poses (no ½; as SE-Sync prints "F(x)")."""
    dual_bound: float
    """``tr Λ``: a lower bound on F's global minimum when S ⪰ 0."""
    suboptimality_bound: float
    """``F(x̂) − tr Λ``."""
    min_eigenvalue: float
    """Estimate of ``λ_min(S)`` (≈ 0 at a certified point: S has the rows of X in its null space)."""
    rank: int
    """Rank of the relaxation at which the certificate was computed (d: the fast path)."""
    eta: float
    """The PSD tolerance η (S counts as PSD when ``S + ηI`` factorises)."""
    status: str
    """``"certified"``, ``"not certified: …"`` with the reason."""
    seconds: dict = field(default_factory=dict)
    """Seconds per phase (``candidate``, ``refine``, ``verify``, ``staircase``, ``rounding``)."""
    poses: np.ndarray | None = field(default=None, repr=False)
    """``(n, k, k)`` the estimate x̂, in the gauge that puts the graph's first held vertex at its file pose."""

    def report(self) -> dict:
        """The fields as JSON-ready values (poses left out)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "poses"}
        return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in out.items()}


def isotropic_graph(graph: PoseGraph, problem: SyncProblem) -> PoseGraph:
    """``graph`` with Ω = ``diag(4κ I, 2τ I)`` (tangent order of its group) and no FIX vertex."""
    group = graph.group
    information = np.zeros_like(graph.information)
    rot, tra = np.array(group.rotation_axes), np.array(group.translation_axes)
    information[:, rot, rot] = 4.0 * problem.kappa[:, None]
    information[:, tra, tra] = 2.0 * problem.tau[:, None]
    fixed = np.zeros(graph.num_vertices, dtype=bool)
    return dataclasses.replace(graph, information=information, fixed=fixed, edge_source=None)


def poses_to_blocks(poses: np.ndarray) -> np.ndarray:
    """``(n, d+1, d+1)`` pose matrices → ``u`` ``(n, d, d+1)`` = ``[t_i | R_i]``."""
    d = poses.shape[-1] - 1
    return np.concatenate([poses[:, :d, d:], poses[:, :d, :d]], axis=2)


def blocks_to_poses(u: np.ndarray, reference: np.ndarray, anchor: int) -> np.ndarray:
    """``u`` ``(n, d, d+1)`` → pose matrices, moved rigidly so that vertex ``anchor`` is at ``reference``."""
    n, d = u.shape[0], u.shape[1]
    poses = np.zeros((n, d + 1, d + 1))
    poses[:, :d, :d], poses[:, :d, d], poses[:, d, d] = u[:, :, 1:], u[:, :, 0], 1.0
    motion = reference @ np.linalg.inv(poses[anchor])
    motion[:d, :d] = _nearest_rotation(motion[:d, :d])
    motion[d] = np.eye(d + 1)[d]
    return motion @ poses


def _nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(matrix)
    u[:, -1] *= np.sign(np.linalg.det(u @ vt))
    return u @ vt


def _anchor(graph: PoseGraph) -> int:
    """The vertex whose file pose the output keeps: the first FIX vertex, else the smallest id."""
    fixed = np.flatnonzero(graph.fixed)
    return int(fixed[0]) if fixed.size else int(np.argmin(graph.ids))


def candidate_poses(graph: PoseGraph, problem: SyncProblem) -> np.ndarray:
    """LM on :func:`isotropic_graph` from the chordal start: poses ``(n, k, k)``."""
    from posegraph.solve import optimize

    return optimize(isotropic_graph(graph, problem)).poses


def certify(graph: PoseGraph, poses: np.ndarray | None = None, *, refine: bool = False, eta: float = DEFAULT_ETA,
            staircase: bool = True, max_rank: int = 10) -> Certificate:  # fmt: skip
    """Certify a global minimiser of SE-Sync's isotropic objective for ``graph`` (module docstring).

    ``poses`` ``(n, k, k)``: certify these poses as they are (their rotations with the best
    translations define Λ; no solving, no staircase) — poses optimised for another cost, e.g. LM's on
    the g2o cost, are *not* a critical point of F and will not certify; with ``refine=True`` they are
    instead the start of the Newton refinement (in place of the LM candidate). ``staircase=False``
    stops after the rank-d test; ``max_rank`` caps the staircase (SE-Sync's ``rmax``).
    """
    problem = sync_problem(graph)
    anchor, seconds = _anchor(graph), {}
    start = time.perf_counter()
    solve = poses is None or refine
    if poses is None:
        poses = candidate_poses(graph, problem)
        seconds["candidate"] = _lap(start)
    u = poses_to_blocks(np.asarray(poses, dtype=np.float64))
    if solve:
        u = refine_poses(problem, u, anchor)[0]
        seconds["refine"] = _lap(start, seconds)
    value = objective(problem, u)
    u_best = u.copy()
    u_best[:, :, 0] = translations_given_rotations(problem, u[:, :, 1:], anchor)
    lambdas = lambda_blocks(problem, u_best)
    check = verify(certificate_matrix(problem, lambdas), u_best, eta)
    seconds["verify"] = _lap(start, seconds)
    rank = problem.d
    if not check.positive_semidefinite and solve and staircase:
        from posegraph.certification.staircase import riemannian_staircase

        found = riemannian_staircase(problem, u_best, check, eta, max_rank)
        seconds["staircase"] = _lap(start, seconds)
        u, value, lambdas, check, rank = found.rounded, found.objective, found.lambdas, found.verification, found.rank
        seconds["rounding"] = found.rounding_seconds
    out = blocks_to_poses(u, graph.poses[anchor], anchor)
    return _certificate(value, lambdas, check, rank, eta, seconds, out)


def _lap(start: float, seconds: dict | None = None) -> float:
    """Seconds since ``start`` less those already recorded in ``seconds``."""
    return time.perf_counter() - start - (sum(seconds.values()) if seconds else 0.0)


def _certificate(value, lambdas, check, rank, eta, seconds, poses) -> Certificate:
    dual = float(np.trace(lambdas, axis1=1, axis2=2).sum())
    bound = value - dual
    tight = bound <= RELATIVE_GAP_TOLERANCE * abs(value) + ABSOLUTE_GAP_TOLERANCE
    if not check.positive_semidefinite:
        status = f"not certified: S has a negative eigenvalue ≈ {check.min_eigenvalue:.3g} < −η"
    elif not tight:
        status = f"not certified: the relaxation is not tight at rank {rank} (F(x) − tr Λ = {bound:.6g})"
    else:
        status = "certified"
    return Certificate(
        certified=bool(check.positive_semidefinite and tight), sesync_objective=float(value), dual_bound=dual,
        suboptimality_bound=float(bound), min_eigenvalue=float(check.min_eigenvalue), rank=int(rank), eta=float(eta),
        status=status, seconds=seconds, poses=poses,
    )  # fmt: skip
