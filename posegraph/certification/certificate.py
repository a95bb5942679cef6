"""``certify(graph)``: SE-Sync's certificate of global optimality, trying a cheap candidate first.

Each connected component (a graph's pose priors join theirs to a world vertex at the identity,
:func:`posegraph.certification.problem.sync_problem`) is certified on its own:

1. Candidate: Levenberg-Marquardt (:func:`posegraph.optimize`, chordal start) on the component with
   each information replaced by its isotropic counterpart ``Ω = diag(4κ I, 2τ I)`` — the geodesic
   cost whose second-order expansion is SE-Sync's ``F`` (``‖R − I‖_F² ≈ 2θ²``), so its optimum is a
   few Newton steps from F's — then :func:`posegraph.certification.local.refine_poses` to F's critical point.
2. Verification at rank d (:mod:`posegraph.certification.verify`): a proven lower bound
   ``L = tr Λ − dn σ`` on the global minimum, σ the shift for which ``Q − Λ + σI ≻ 0`` was proven.
3. If the candidate is not certified: the Riemannian staircase
   (:mod:`posegraph.certification.staircase`), which keeps the best rounded estimate (never worse
   than the candidate) and the best lower bound any level proved.

**Certified** means ``F(x̂) − L ≤ η F(x̂) + ρ W`` summed over the components: ``η`` the caller's
relative tolerance (:data:`~posegraph.certification.verify.DEFAULT_TOLERANCE`), ``W`` the data's size
(:func:`~posegraph.certification.verify.data_scale`) and ``ρ`` =
:data:`~posegraph.certification.verify.ROUND_OFF`. Both sides scale alike when all information is
multiplied by a constant, neither changes with the units of the translations, and ``L`` is the same
whether translations are eliminated or not: the verdict does not depend on any of these.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from posegraph.certification.local import refine_poses, translations_given_rotations
from posegraph.certification.problem import SyncProblem, component_problems, objective, sync_problem
from posegraph.certification.verify import DEFAULT_TOLERANCE, Budget, Verification, data_scale, verify_point
from posegraph.model.graph import PoseGraph

__all__ = ["Certificate", "certify", "isotropic_graph", "candidate_poses", "poses_to_blocks", "blocks_to_poses"]


CANDIDATE_NEWTON_ITERATIONS = 20
"""Newton steps at most from the candidate (1–3 on every benchmark file): where F's landscape is so
indefinite that Newton crawls (the noisy grids: 100 steps, 0.4–1.3 s), the rank-d test fails anyway
and the staircase's trust region, made for such landscapes, takes over; its best rounding is then
refined with the full :data:`~posegraph.certification.local.MAX_NEWTON_ITERATIONS`."""


@dataclass
class Certificate:
    """What :func:`certify` found (the report of ``posegraph certify``); sums and extremes over the components."""

    certified: bool
    """``F(x̂) − lower_bound ≤ η F(x̂)`` (+ round-off): ``poses`` is within that of a global minimiser of SE-Sync's
    isotropic objective (not of the graph's anisotropic cost)."""
    sesync_objective: float
    """``F(x̂)``, SE-Sync's objective at the returned poses (no ½; as SE-Sync prints "F(x)")."""
    lower_bound: float
    """A proven lower bound on F's global minimum: ``tr Λ − dn σ`` at the best level, summed over components."""
    suboptimality_bound: float
    """``F(x̂) − lower_bound``: how far above the global minimum x̂ can be."""
    relative_suboptimality: float
    """``suboptimality_bound / F(x̂)`` (inf when F is 0)."""
    dual_bound: float
    """``tr Λ`` at the level that gave ``lower_bound`` (the bound without the eigenvalue slack)."""
    min_eigenvalue: float
    """The smallest eigenvalue of ``Q − Λ`` found (Ritz value; ≈ 0 at a certified point, Q − Λ's kernel)."""
    eigenvalue_residual: float
    """Its Ritz residual ``‖(Q − Λ)v − θv‖``: Q − Λ has an eigenvalue within this of ``min_eigenvalue``."""
    proven_min_eigenvalue: float
    """``−σ``: proven by Cholesky, ``λ_min(Q − Λ) > −σ`` (the slack in ``lower_bound`` is ``dn σ``)."""
    rank: int
    """Highest rank of the relaxation reached (d: the candidate was certified without the staircase)."""
    eta: float
    """The relative tolerance η."""
    status: str
    """``"certified"``, or ``"not certified: …"`` with the reason."""
    components: int = 1
    """Connected components certified one by one (a world vertex joins those with pose priors)."""
    seconds: dict = field(default_factory=dict)
    """Seconds per phase (``candidate``, ``refine``, ``verify``, ``staircase``), summed over components."""
    poses: np.ndarray | None = field(default=None, repr=False)
    """``(n, k, k)`` the estimate x̂: components with pose priors in the world frame, the others in the
    gauge that puts their first FIX vertex (else smallest id) at its file pose."""

    def report(self) -> dict:
        """The fields as JSON-ready values (poses left out)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "poses"}
        return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in out.items()}


def problem_graph(problem: SyncProblem, group, world: bool) -> PoseGraph:
    """The component as a :class:`PoseGraph` with Ω = ``diag(4κ I, 2τ I)`` (tangent order of ``group``); a
    world vertex (the last) held at the identity."""
    d, m, n = problem.d, problem.num_edges, problem.num_poses
    measurements = np.zeros((m, d + 1, d + 1))
    measurements[:, :d, :d], measurements[:, :d, d], measurements[:, d, d] = problem.rotations, problem.translations, 1
    information = np.zeros((m, group.dim, group.dim))
    rot, tra = np.array(group.rotation_axes), np.array(group.translation_axes)
    information[:, rot, rot] = 4.0 * problem.kappa[:, None]
    information[:, tra, tra] = 2.0 * problem.tau[:, None]
    fixed = np.zeros(n, dtype=bool)
    fixed[n - 1] = world
    return PoseGraph(ids=np.arange(n, dtype=np.int64), poses=np.broadcast_to(np.eye(d + 1), (n, d + 1, d + 1)).copy(),
                     edge_from=problem.edge_from, edge_to=problem.edge_to, measurements=measurements,
                     information=information, fixed=fixed, group=group)  # fmt: skip


def isotropic_graph(graph: PoseGraph, problem: SyncProblem | None = None) -> PoseGraph:
    """``graph`` with Ω = ``diag(4κ I, 2τ I)`` (tangent order of its group), no FIX vertex and no priors."""
    problem = sync_problem(dataclasses.replace(graph, priors=None)) if problem is None else problem
    out = problem_graph(problem, graph.group, world=False)
    return dataclasses.replace(graph, information=out.information, fixed=out.fixed, edge_source=None, priors=None)


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


def candidate_poses(graph: PoseGraph, problem: SyncProblem | None = None) -> np.ndarray:
    """LM on :func:`isotropic_graph` from the chordal start: poses ``(n, k, k)``."""
    from posegraph.solve import optimize

    return optimize(isotropic_graph(graph, problem)).poses


@dataclass
class _Part:
    """One component's outcome."""

    u: np.ndarray
    value: float
    check: Verification
    """The test that proved the component's best lower bound (``check.lower_bound``, ``check.dual_bound``)."""
    rank: int
    budget: Budget


def _certify_component(problem, group, world, poses, solve, staircase, max_rank, budget, seconds) -> _Part:
    """Candidate (or the given ``poses``), refinement, verification and, if needed, the staircase for one component."""
    anchor = problem.num_poses - 1 if world else 0
    start = time.perf_counter()
    if poses is None:
        from posegraph.solve import optimize

        poses = optimize(problem_graph(problem, group, world)).poses
        _add(seconds, "candidate", start)
    u = poses_to_blocks(np.asarray(poses, dtype=np.float64))
    if solve:
        start = time.perf_counter()
        u = refine_poses(problem, u, anchor, CANDIDATE_NEWTON_ITERATIONS)[0]
        _add(seconds, "refine", start)
    u[:, :, 0] = translations_given_rotations(problem, u[:, :, 1:], anchor)
    value = objective(problem, u)
    start = time.perf_counter()
    check = verify_point(problem, u, value, budget, anchor)
    _add(seconds, "verify", start)
    part = _Part(u, value, check, problem.d, budget)
    if solve and staircase and value - check.lower_bound > budget.allowed(value):
        from posegraph.certification.staircase import riemannian_staircase

        start = time.perf_counter()
        found = riemannian_staircase(problem, u, check, budget, max_rank, anchor)
        _add(seconds, "staircase", start)
        part = _Part(found.best, found.best_value, found.verification, found.rank, budget)
    return part


def _add(seconds: dict, phase: str, start: float) -> None:
    seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - start


def certify(graph: PoseGraph, poses: np.ndarray | None = None, *, refine: bool = True, eta: float = DEFAULT_TOLERANCE,
            staircase: bool = True, max_rank: int = 10) -> Certificate:  # fmt: skip
    """Certify a global minimiser of SE-Sync's isotropic objective for ``graph`` (module docstring).

    ``poses`` ``(n, k, k)``: the start of the Newton refinement on F, in place of the LM candidate,
    then verification and the staircase, as ``posegraph certify`` (``certify(graph, result.poses)``
    certifies an LM result of the g2o cost: that is not a critical point of F when the information is
    anisotropic, a few Newton steps from one). ``refine=False`` certifies the poses exactly as given
    (their rotations with the best translations define Λ; no solving, no staircase): only F's own
    critical points can pass, and a failure says so. ``eta``: the relative
    tolerance η; ``staircase=False`` stops after the rank-d test; ``max_rank`` caps the staircase
    (SE-Sync's ``rmax``). Pose priors are edges from a world vertex; the components are certified one
    by one (:func:`~posegraph.certification.problem.sync_problem`).
    """
    if not (np.isfinite(eta) and eta > 0):
        raise ValueError(f"eta must be a positive finite relative tolerance, got {eta!r}")
    problem = sync_problem(graph)
    n, world = graph.num_vertices, problem.num_poses > graph.num_vertices
    out, seconds, parts = np.array(graph.poses, dtype=np.float64, copy=True), {}, []
    for vertices, sub in component_problems(problem):
        has_world = world and vertices[-1] == n
        given = None if poses is None else np.asarray(poses)[vertices[vertices < n]]
        if given is not None and has_world:
            given = np.concatenate([given, np.eye(problem.d + 1)[None]])
        part = _certify_component(sub, graph.group, has_world, given, poses is None or refine, staircase, max_rank,
                                  Budget(eta, data_scale(sub)), seconds)  # fmt: skip
        anchor, reference = _output_gauge(graph, vertices, has_world)
        placed = blocks_to_poses(part.u, reference, anchor)
        out[vertices[vertices < n]] = placed[: np.count_nonzero(vertices < n)]
        parts.append(part)
    return _certificate(parts, eta, seconds, out, as_given=poses is not None and not refine)


def _output_gauge(graph: PoseGraph, vertices: np.ndarray, has_world: bool) -> tuple[int, np.ndarray]:
    """``(anchor within the component, its pose)``: the world vertex at the identity, else the first FIX
    vertex (else the smallest id) at its file pose."""
    if has_world:
        return vertices.size - 1, np.eye(graph.group.matrix_size)
    fixed = np.flatnonzero(graph.fixed[vertices])
    anchor = int(fixed[0]) if fixed.size else int(np.argmin(graph.ids[vertices]))
    return anchor, graph.poses[vertices[anchor]]


AS_GIVEN = ("; the poses were checked as given (refine=False): poses that minimise another cost, such as "
            "optimize's on the g2o cost, are not a critical point of SE-Sync's F; refine=True starts from them")
"""The end of a negative verdict on poses checked as given (:func:`certify` with ``refine=False``)."""


def _certificate(parts: list[_Part], eta: float, seconds: dict, poses: np.ndarray, as_given: bool = False) -> Certificate:
    """Sum the components' figures and state the verdict (module docstring); ``as_given``: no refinement ran."""
    value = sum(p.value for p in parts)
    lower = sum(p.check.lower_bound for p in parts)
    allowed = sum(p.budget.allowed(p.value) for p in parts)
    gap = value - lower
    worst = min(parts, key=lambda p: p.check.min_eigenvalue)
    certified = gap <= allowed
    if certified:
        status = "certified"
    elif all(p.check.positive_semidefinite for p in parts):  # the relaxation is solved, its rounding loses
        status = f"not certified: the relaxation is not tight (F(x) − lower bound = {gap:.6g})"
    else:
        status = (f"not certified: Q − Λ has a negative eigenvalue ≈ {worst.check.min_eigenvalue:.3g}; "
                  f"F(x) − lower bound = {gap:.6g}")  # fmt: skip
    if not certified and as_given:
        status += AS_GIVEN
    return Certificate(
        certified=bool(certified), sesync_objective=float(value), lower_bound=float(lower), suboptimality_bound=float(gap),
        relative_suboptimality=float(gap / value) if value > 0 else float("inf"),
        dual_bound=float(sum(p.check.dual_bound for p in parts)), min_eigenvalue=float(worst.check.min_eigenvalue),
        eigenvalue_residual=float(worst.check.residual), proven_min_eigenvalue=float(-worst.check.proven_shift),
        rank=max(p.rank for p in parts), eta=float(eta), status=status, components=len(parts), seconds=seconds,
        poses=poses,
    )  # fmt: skip
