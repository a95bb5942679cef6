"""SE-Sync's isotropic pose-graph problem: κ, τ per edge, its objective and data matrix M.

Rosen, Carlone, Bandeira & Leonard, "SE-Sync: a certifiably correct algorithm for
synchronization over the special Euclidean group", IJRR 2019 (eqs. 1-2, 13-16). Each edge
``e = (i, j)`` measures ``R̃_e ≈ R_iᵀ R_j`` and ``t̃_e ≈ R_iᵀ (t_j − t_i)`` with isotropic
precisions ``κ_e`` (rotation) and ``τ_e`` (translation), and the maximum-likelihood problem is

    ``F(t, R) = Σ_e κ_e ‖R_j − R_i R̃_e‖_F² + τ_e ‖t_j − t_i − R_i t̃_e‖²``

over ``t_i ∈ ℝ^d``, ``R_i ∈ SO(d)`` (no ½, as SE-Sync prints it). κ and τ come from each edge's
information matrix exactly as SE-Sync's ``read_g2o_file`` computes them (the information divergence
minimisers): 3D ``κ = 3 / (2 tr(Ω_RR⁻¹))``, ``τ = 3 / tr(Ω_tt⁻¹)``; 2D ``κ = Ω_θθ`` (the entry
itself), ``τ = 2 / tr(Ω_tt⁻¹)``; ``Ω_RR``/``Ω_tt`` are the rotation/translation blocks of Ω in the
graph's tangent order (the g2o reader's permutation does not change them).

Layout. A point of rank ``r`` (``r = d``: a pose estimate; ``r > d``: a point of the relaxation) is
``u`` ``(n, r, d+1)``: vertex ``i``'s block ``u_i = [t_i | Y_i]`` (``Y_i`` = ``R_i`` at rank d). SE-Sync
writes ``X = [t | R]`` (translations first, then the rotations); here each vertex's ``d+1`` columns
are kept together, a permutation of SE-Sync's columns, so that M, and the certificate S built from
it, have one ``(d+1)×(d+1)`` block per vertex pair and reuse the solver's block sparsity. Each edge's
term is ``‖u_i B_iᵀ + u_j B_jᵀ‖_F²`` with the ``(d+1)×(d+1)`` maps (:func:`edge_maps`)

    ``B_j = [[0, √κ I_d], [√τ, 0]]``,   ``B_i = [[0, −√κ R̃ᵀ], [−√τ, −√τ t̃ᵀ]]``,

so ``F = tr(X M Xᵀ)`` with M's blocks ``M_ii += B_iᵀB_i``, ``M_jj += B_jᵀB_j``, ``M_ij += B_iᵀB_j``:
SE-Sync's data matrix ``M = [[L(W^τ), Ṽ], [Ṽᵀ, L(G̃^ρ) + Σ̃]]`` (eq. 16) with rows and columns
permuted.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from posegraph.model.graph import PoseGraph, edge_components
from posegraph.model.priors import prior_poses
from posegraph.errors import GraphError

__all__ = ["SyncProblem", "sync_problem", "component_problems", "isotropic_precisions", "edge_maps", "edge_residuals", "objective",
           "euclidean_gradient", "data_matrix_blocks", "scatter_to_vertices"]


@dataclass(frozen=True, eq=False)
class SyncProblem:
    """SE-Sync's problem for a pose graph, or one of its connected components (see the module docstring)."""

    d: int
    """Dimension of the space: 3 (SE(3)) or 2 (SE(2))."""
    num_poses: int
    """Number of vertices ``n`` (the graph's vertex indices, not its ids)."""
    edge_from: np.ndarray
    """``(m,)`` int64 index ``i`` of each edge's first vertex."""
    edge_to: np.ndarray
    """``(m,)`` int64 index ``j``."""
    rotations: np.ndarray
    """``(m, d, d)`` measured rotations ``R̃``."""
    translations: np.ndarray
    """``(m, d)`` measured translations ``t̃``."""
    kappa: np.ndarray
    """``(m,)`` rotational precisions κ."""
    tau: np.ndarray
    """``(m,)`` translational precisions τ."""

    @property
    def num_edges(self) -> int:
        return int(self.edge_from.shape[0])


def isotropic_precisions(information: np.ndarray, group) -> tuple[np.ndarray, np.ndarray]:
    """``(κ, τ)`` ``(m,)`` each from ``information`` ``(m, D, D)``, as SE-Sync's reader (module docstring)."""
    information = np.asarray(information, dtype=np.float64)
    rot, tra = group.rotation_block, group.translation_block
    d = group.space_dim
    tau = d / np.trace(np.linalg.inv(information[:, tra, tra]), axis1=1, axis2=2)
    if d == 2:
        kappa = information[:, rot, rot][:, 0, 0].copy()
    else:
        kappa = 3.0 / (2.0 * np.trace(np.linalg.inv(information[:, rot, rot]), axis1=1, axis2=2))
    return kappa, tau


def sync_problem(graph: PoseGraph) -> SyncProblem:
    """SE-Sync's problem for ``graph``: its edges and, when it has pose priors, a world vertex.

    FIX lines play no part (SE-Sync's problem has none). A pose prior ``Z ≈ X_k O`` (residual
    ``Log(Z⁻¹ X_k O) = Ad_{O⁻¹} Log(P⁻¹ X_k)`` with ``P = Z O⁻¹``) is the edge from a world vertex
    at the identity to ``k`` measuring ``P`` with information ``Ad_{O⁻¹}ᵀ Ω Ad_{O⁻¹}``: the problem
    keeps SE-Sync's form, the world vertex is index ``n`` (:attr:`SyncProblem.num_poses` is then
    ``n + 1``) and the gauge is gone from the components it reaches. Several connected components
    are one problem whose matrices are block-diagonal (:func:`component_problems` splits them).

    Raises :class:`~posegraph.errors.GraphError` for a graph SE-Sync's problem is not defined on: a
    group other than SE(2)/SE(3) (Sim(3)), position priors (a point says nothing of a rotation: no
    term of SE-Sync's form), landmarks (no variables of its form), no edges, or information whose κ or τ is not finite and positive.
    """
    if graph.group.name not in ("SE3", "SE2"):
        raise GraphError(f"SE-Sync's problem is defined on SE(2) and SE(3) graphs, not {graph.group.name}: "
                         "nothing to certify", graph.source)
    if graph.landmarks is not None and graph.landmarks.count:
        raise GraphError(f"the graph has {graph.landmarks.count} landmarks, which SE-Sync's problem has no variables "
                         "for (it is defined on poses alone): nothing to certify", graph.source)
    priors = graph.priors
    if priors is not None and priors.num_position:
        raise GraphError("the graph has position priors, which SE-Sync's problem has no terms for (they measure "
                         "no rotation): nothing to certify", graph.source, _first_line(priors.position_lines))
    pose_priors = 0 if priors is None else priors.num_pose
    if graph.num_edges + pose_priors == 0:
        raise GraphError("the graph has no edges: nothing to certify", graph.source)
    n, d, group = graph.num_vertices, graph.group.space_dim, graph.group
    edge_from, edge_to = np.asarray(graph.edge_from, dtype=np.int64), np.asarray(graph.edge_to, dtype=np.int64)
    measurements, information = graph.measurements, graph.information
    lines = graph.edge_lines
    if pose_priors:
        undo = group.adjoint(group.inverse(priors.pose_offsets))
        vertices, targets = prior_poses(graph)  # P = Z O⁻¹ (pose priors only: position priors are refused above)
        edge_from = np.r_[edge_from, np.full(pose_priors, n, dtype=np.int64)]
        edge_to = np.r_[edge_to, vertices]
        measurements = np.concatenate([measurements, targets])
        information = np.concatenate([information, np.swapaxes(undo, 1, 2) @ priors.pose_information @ undo])
        lines = None if lines is None or priors.pose_lines is None else np.r_[lines, priors.pose_lines]
    kappa, tau = _checked_precisions(information, group, graph.source, lines)
    return SyncProblem(
        d=d, num_poses=n + (1 if pose_priors else 0), edge_from=edge_from, edge_to=edge_to,
        rotations=measurements[:, :d, :d].copy(), translations=measurements[:, :d, d].copy(), kappa=kappa, tau=tau,
    )  # fmt: skip


def _first_line(lines) -> int | None:
    return None if lines is None or len(lines) == 0 else int(lines[0])


def _checked_precisions(information, group, source, lines) -> tuple[np.ndarray, np.ndarray]:
    """:func:`isotropic_precisions`, or a :class:`GraphError` naming the first edge without positive finite κ, τ."""
    try:
        kappa, tau = isotropic_precisions(information, group)
    except np.linalg.LinAlgError:
        kappa = tau = np.full(information.shape[0], np.nan)
    bad = ~(np.isfinite(kappa) & np.isfinite(tau) & (kappa > 0) & (tau > 0))
    if bad.any():
        line = None if lines is None else int(lines[np.flatnonzero(bad)[0]])
        raise GraphError("an information matrix gives no positive finite κ and τ (SE-Sync's isotropic "
                         "precisions): its rotation and translation blocks must be positive definite",
                         source, line)  # fmt: skip
    return kappa, tau


def component_problems(problem: SyncProblem) -> list[tuple[np.ndarray, SyncProblem]]:
    """``[(vertices, sub-problem), …]``: one per connected component with at least one edge, ``vertices``
    ``(n_c,)`` the problem's vertex indices of the component (in order; a world vertex is last)."""
    n = problem.num_poses
    _, labels = edge_components(n, problem.edge_from, problem.edge_to)
    edge_label = labels[problem.edge_from]
    out = []
    for label in np.unique(edge_label).tolist():  # one pass per component: few
        vertices = np.flatnonzero(labels == label)
        index = np.full(n, -1, dtype=np.int64)
        index[vertices] = np.arange(vertices.size)
        edges = np.flatnonzero(edge_label == label)
        out.append((vertices, dataclasses.replace(
            problem, num_poses=int(vertices.size), edge_from=index[problem.edge_from[edges]],
            edge_to=index[problem.edge_to[edges]], rotations=problem.rotations[edges],
            translations=problem.translations[edges], kappa=problem.kappa[edges], tau=problem.tau[edges],
        )))  # fmt: skip
    return out


def edge_maps(problem: SyncProblem) -> tuple[np.ndarray, np.ndarray]:
    """``(B_i, B_j)``, each ``(m, d+1, d+1)``: an edge's term is ``‖u_i B_iᵀ + u_j B_jᵀ‖_F²`` (module docstring)."""
    d, m = problem.d, problem.num_edges
    root_kappa, root_tau = np.sqrt(problem.kappa), np.sqrt(problem.tau)
    b_i = np.zeros((m, d + 1, d + 1))
    b_j = np.zeros((m, d + 1, d + 1))
    b_i[:, :d, 1:] = -root_kappa[:, None, None] * np.swapaxes(problem.rotations, 1, 2)
    b_i[:, d, 0] = -root_tau
    b_i[:, d, 1:] = -root_tau[:, None] * problem.translations
    b_j[:, :d, 1:] = root_kappa[:, None, None] * np.eye(d)
    b_j[:, d, 0] = root_tau
    return b_i, b_j


def edge_residuals(problem: SyncProblem, u: np.ndarray, maps=None) -> np.ndarray:
    """``(m, r, d+1)`` residual matrices ``E_e = u_i B_iᵀ + u_j B_jᵀ`` at ``u`` ``(n, r, d+1)``.

    At rank d, ``E_e[:, :d] = √κ (R_j − R_i R̃)`` and ``E_e[:, d] = √τ (t_j − t_i − R_i t̃)``.
    """
    b_i, b_j = edge_maps(problem) if maps is None else maps
    return u[problem.edge_from] @ np.swapaxes(b_i, 1, 2) + u[problem.edge_to] @ np.swapaxes(b_j, 1, 2)


def objective(problem: SyncProblem, u: np.ndarray, maps=None) -> float:
    """SE-Sync's ``F = tr(X M Xᵀ) = Σ_e ‖E_e‖_F²`` at ``u`` ``(n, r, d+1)`` (at rank d, ``F(t, R)``)."""
    return float(np.sum(edge_residuals(problem, u, maps) ** 2))


def scatter_to_vertices(num_poses: int, vertices: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``out[v] = Σ_{k: vertices[k] = v} values[k]``: ``values`` ``(m, ...)`` → ``(num_poses, ...)`` (by bincount)."""
    values = np.asarray(values, dtype=np.float64)
    width = int(np.prod(values.shape[1:], dtype=np.int64))
    slots = (vertices[:, None] * width + np.arange(width)[None, :]).ravel()
    out = np.bincount(slots, weights=values.reshape(-1), minlength=num_poses * width)
    return out.reshape((num_poses,) + values.shape[1:])


def euclidean_gradient(problem: SyncProblem, u: np.ndarray, maps=None, residuals=None) -> np.ndarray:
    """``∇F = 2 X M`` at ``u``, as ``(n, r, d+1)`` blocks (vertex ``i``'s: ``Σ_e 2 E_e B_{i,e}``)."""
    maps = edge_maps(problem) if maps is None else maps
    residuals = edge_residuals(problem, u, maps) if residuals is None else residuals
    n = problem.num_poses
    return 2.0 * (scatter_to_vertices(n, problem.edge_from, residuals @ maps[0])
                  + scatter_to_vertices(n, problem.edge_to, residuals @ maps[1]))  # fmt: skip


def data_matrix_blocks(problem: SyncProblem, maps=None) -> np.ndarray:
    """``(m, 3, d+1, d+1)`` per-edge blocks ``[B_iᵀB_i, B_jᵀB_j, B_iᵀB_j]`` of M (vertex-interleaved layout)."""
    b_i, b_j = edge_maps(problem) if maps is None else maps
    b_i_t = np.swapaxes(b_i, 1, 2)
    return np.stack([b_i_t @ b_i, np.swapaxes(b_j, 1, 2) @ b_j, b_i_t @ b_j], axis=1)
