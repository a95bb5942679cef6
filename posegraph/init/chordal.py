"""Chordal initialisation: rotations by a linear relaxation, then translations given them.

Martinec & Pajdla, "Robust rotation and translation estimation in multiview reconstruction",
CVPR 2007; Carlone, Tron, Daniilidis & Dellaert, "Initialization techniques for 3D SLAM: a survey
on rotation estimation and its use in pose graph optimization", ICRA 2015.

Both stages are written once for the graph's group (:class:`posegraph.lie.group.LieGroup`):
rotations ``R`` are r×r (r = 3 for SE(3), r = 2 for SE(2)), translations have r entries.

Stage 1 — rotations. Each edge ``i → j`` measures ``R_z ≈ R_iᵀ R_j``, i.e. ``R_j ≈ R_i R_z``.
Dropping the constraint ``R ∈ SO(r)`` leaves a linear least-squares problem in the matrix
entries,

    ``min Σ_e w_e ‖R_j − R_i R_z‖_F²  =  min Σ_e w_e ‖Y_j − R_zᵀ Y_i‖_F²``,  ``Y_k = R_kᵀ``,

with the held rotations (fixed vertices and anchors) eliminated as known values, not added as
priors. The r columns of ``Y`` (the rows of ``R``) do not interact: it is one sparse SPD
system of size rp×rp (p free vertices; its r×r blocks are ``w I`` summed on the diagonal and
``−w R_z`` off it, a "connection Laplacian") with r right-hand sides, factorised once. Each
solved r×r block is then projected onto SO(r) — the nearest rotation in the Frobenius norm (SO(3):
by SVD with the determinant fixed to +1, :func:`posegraph.lie.so3.project`; SO(2): the rotation by
``atan2(m₁₀ − m₀₁, m₀₀ + m₁₁)``, :func:`posegraph.lie.so2.project`). ``w_e = tr(Ω_ωω)/3`` (2D:
``Ω_θθ``), see :mod:`posegraph.init.weights`. In 2D this is the relaxation of Carlone et al.'s
"R_j ≈ R_i R_ij" over the entries of 2×2 matrices (a complex-number least squares), where gtsam's
LAGO instead solves for unwrapped angles along a spanning tree's cycles.

Stage 2 — translations given the rotations. With all ``R_k`` known, an edge's rotation error
``δ = Log(R_zᵀ R_iᵀ R_j)`` is known, and the translation part of ``Log(Z⁻¹ Xi⁻¹ Xj)`` is

    ``v = V(δ)⁻¹ R_zᵀ (R_iᵀ (t_j − t_i) − t_z)``,

where ``V(δ)⁻¹`` maps a pose's translation to the translation part of its ``Log`` (SE(3):
``J_l(δ)⁻¹`` of SO(3); SE(2): ``E I − (ω/2) J``); it is the translation block of the group's
``Jl([δ; 0])⁻¹``, which is how it is computed here for any group. The cost is then

affine in the translations, and the edge cost ``½ [δ; v]ᵀ Ω [δ; v]`` is *exactly*
quadratic in them, and its minimiser over ``v`` is ``v* = −Ω_vv⁻¹ Ω_vω δ``. Minimising the
graph's true cost over all translations at fixed rotations is one sparse SPD solve (rp×rp, one
right-hand side) with, per edge, ``B = V(δ)⁻¹ R_zᵀ R_iᵀ``, weight ``Bᵀ Ω_vv B`` and weighted
offset ``Bᵀ (Ω_vv V(δ)⁻¹ R_zᵀ t_z − Ω_vω δ)``. The returned start is thus the best start
with the chordal rotations: its cost is the cost's minimum over translations.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import GraphError
from posegraph.model.graph import PoseGraph
from posegraph.init.checks import require_usable
from posegraph.model.graph import held_vertices
from posegraph.init.priors import align_to_priors, without_priors
from posegraph.init.linear_system import NotPositiveDefiniteError, RelativeLeastSquares
from posegraph.init.odometry import odometry_initialization
from posegraph.init.scales import edge_scale_terms, log_scales, rotation_blocks
from posegraph.init.weights import rotation_weights, translation_information

__all__ = ["chordal_initialization", "chordal_problem", "chordal_rotations", "translations_given_rotations"]


def chordal_rotations(graph: PoseGraph, *, linear_solver: str = "auto") -> np.ndarray:
    """``(n, r, r)`` rotations by the chordal relaxation; held vertices keep their file rotation.

    See the module docstring (stage 1). ``linear_solver``: ``"auto"``, ``"cholmod"`` or
    ``"scipy"`` (:class:`posegraph.init.linear_system.RelativeLeastSquares`).
    """
    require_usable(graph)
    return _rotations(graph, chordal_problem(graph, linear_solver))


def translations_given_rotations(
    graph: PoseGraph, rotations: np.ndarray, *, linear_solver: str = "auto"
) -> np.ndarray:
    """``(n, r)`` translations minimising the graph's cost with the rotations held at ``rotations (n, r, r)``.

    Held vertices keep their file translation. Exact for positive-definite information (module
    docstring, stage 2); an ``Ω_vv`` with eigenvalues below the floor of
    :func:`posegraph.init.weights.translation_information` is raised to it first.
    """
    require_usable(graph)
    rotations = np.asarray(rotations, dtype=np.float64)
    r = graph.group.space_dim
    if rotations.shape != (graph.num_vertices, r, r):
        raise ValueError(f"rotations must have shape {(graph.num_vertices, r, r)}, got {rotations.shape}")
    problem = chordal_problem(graph, linear_solver)
    return _translations(graph, rotations, problem, log_scales(graph, problem.held, linear_solver))


def chordal_initialization(
    graph: PoseGraph, *, linear_solver: str = "auto", problem: RelativeLeastSquares | None = None
) -> np.ndarray:
    """``(n, k, k)`` poses: chordal rotations, then the cost-minimising translations given them.

    Fixed vertices and component anchors keep their file pose exactly; a component that priors
    reach is then moved rigidly to fit them (:mod:`posegraph.init.priors`). Works for any number of
    components, duplicate edges, degree-one vertices and information spanning many decades.
    Raises :class:`~posegraph.errors.GraphError` when the linear systems cannot be solved to
    working precision (no backend factorises them, or the solution overflows).

    ``problem``: the analysed system of :func:`chordal_problem` for a graph with the same edges
    and held vertices (e.g. ``graph`` with other information, as GNC reweights it): its pattern
    and symbolic factorisation are reused instead of analysed anew; ``linear_solver`` is then
    the problem's.
    """
    require_usable(graph)
    if graph.priors is not None:  # solved with today's anchors, then moved to fit the priors
        poses = chordal_initialization(without_priors(graph), linear_solver=linear_solver, problem=problem)
        return align_to_priors(graph, poses)
    if problem is None:
        problem = chordal_problem(graph, linear_solver)  # both stages share its sparsity analysis
    elif not (np.array_equal(problem.edge_from, graph.edge_from) and np.array_equal(problem.edge_to, graph.edge_to)):
        raise ValueError("the chordal problem was analysed for other edges than the graph's")
    try:
        rotations = _rotations(graph, problem)
        scales = log_scales(graph, problem.held, problem.linear_solver)  # Sim(3) only (posegraph.init.scales)
        translations = _translations(graph, rotations, problem, scales)
    except NotPositiveDefiniteError as err:
        raise GraphError(
            f"the chordal initialisation failed numerically ({err}); the information matrices may span too "
            "many decades: try the odometry initialisation", graph.source,
        ) from err  # fmt: skip
    r = graph.group.space_dim
    poses = np.zeros((graph.num_vertices, r + 1, r + 1))
    poses[:, :r, :r] = rotations * np.exp(scales)[:, None, None]
    poses[:, :r, r] = translations
    poses[:, r, r] = 1.0
    held = problem.held
    poses[held] = graph.poses[held]  # bit-exact, bottom row as read included
    return poses


def chordal_problem(graph: PoseGraph, linear_solver: str = "auto", ordering: str = "auto") -> RelativeLeastSquares:
    """The sparse system both chordal stages solve, analysed for ``graph``'s edges and held vertices
    (``ordering``: CHOLMOD's, of the vertex graph; ``"auto"`` as the solver's)."""
    return RelativeLeastSquares(
        held_vertices(without_priors(graph)), graph.edge_from, graph.edge_to, linear_solver=linear_solver,
        block=graph.group.space_dim, ordering=ordering,
    )  # fmt: skip


def _rotations(graph: PoseGraph, problem: RelativeLeastSquares) -> np.ndarray:
    """Stage 1: solve for ``Y_k = R_kᵀ`` (residual ``Y_j − R_zᵀ Y_i``, weight ``w I``), project."""
    r = graph.group.space_dim
    file_rotations, _ = rotation_blocks(graph.poses, graph.group)  # Sim(3): without the scales
    weights = rotation_weights(graph.information, graph.group)
    null = None
    if problem.iterative:  # the odometry's rotations: Y_j ≈ R_zᵀ Y_i along every edge
        null = rotation_blocks(odometry_initialization(graph), graph.group)[0].transpose(0, 2, 1)
    transposed = problem.solve(
        file_rotations.transpose(0, 2, 1),
        transfer=rotation_blocks(graph.measurements, graph.group)[0].transpose(0, 2, 1),
        weight=weights[:, None, None] * np.eye(r),
        near_null_space=null,
    )
    rotations = np.array(file_rotations, copy=True)
    free = ~problem.held
    rotations[free] = graph.group.rotations.project(transposed[free].transpose(0, 2, 1))
    return rotations


def _translation_log_matrix(group, rotation_error: np.ndarray, scale_error: np.ndarray) -> np.ndarray:
    """``(m, r, r)`` ``V(δ)⁻¹``: the translation block of ``Jl([δ; 0])⁻¹`` (module docstring, stage 2);
    Sim(3): of ``Jl([δ; 0; λ_e])⁻¹``, ``V(δ, λ_e)⁻¹``, with the edge's log-scale error ``λ_e``."""
    tangent = np.zeros(rotation_error.shape[:-1] + (group.dim,))
    tangent[..., list(group.rotation_axes)] = rotation_error
    tangent[..., list(group.scale_axes)] = scale_error[..., None]
    translation = list(group.translation_axes)
    return group.left_jacobian_inverse(tangent)[..., translation, :][..., translation]


def _translations(
    graph: PoseGraph, rotations: np.ndarray, problem: RelativeLeastSquares, scales: np.ndarray | None = None
) -> np.ndarray:
    """Stage 2: residual ``t_j − t_i − h`` with weight ``Bᵀ Ω_vv B`` (module docstring). Sim(3), with the
    log-scales ``scales (n,)``: ``B`` and ``h`` carry ``1/(s_z s_i)``, ``V`` the edge's scale error, and
    its ``Ω_vλ`` coupling joins ``Ω_vω``'s (:mod:`posegraph.init.scales`)."""
    group, r = graph.group, graph.group.space_dim
    i, j = graph.edge_from, graph.edge_to
    factor, offset_factor, scale_error = edge_scale_terms(graph, scales)
    measured_rotation_t = rotation_blocks(graph.measurements, group)[0].transpose(0, 2, 1)
    rotation_error = group.rotations.log(measured_rotation_t @ rotations[i].transpose(0, 2, 1) @ rotations[j])  # δ
    to_residual = _translation_log_matrix(group, rotation_error, scale_error) @ measured_rotation_t  # V(δ)⁻¹ R_zᵀ
    transfer_b = to_residual @ rotations[i].transpose(0, 2, 1) * factor[:, None, None]  # B
    offset = (to_residual @ graph.measurements[:, :r, r : r + 1])[..., 0] * offset_factor[:, None]  # V⁻¹ R_zᵀ t_z / s_z

    omega_vv = translation_information(graph.information, group)
    known_error = graph.information[:, group.translation_block, group.rotation_block] @ rotation_error[..., None]
    if group.scale_axes:
        known_error = known_error + graph.information[:, group.translation_block, group.scale_axes] * scale_error[:, None, None]
    weight = transfer_b.transpose(0, 2, 1) @ omega_vv @ transfer_b
    weight = 0.5 * (weight + weight.transpose(0, 2, 1))
    weighted_offset = transfer_b.transpose(0, 2, 1) @ (omega_vv @ offset[..., None] - known_error)
    translations = problem.solve(
        graph.poses[:, :r, r : r + 1],
        transfer=np.broadcast_to(np.eye(r), (graph.num_edges, r, r)),
        weight=weight,
        weighted_offset=weighted_offset,
    )
    return translations[:, :, 0]
