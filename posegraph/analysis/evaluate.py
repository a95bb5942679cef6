"""Trajectory error metrics: absolute trajectory error (ATE) and relative pose error (RPE).

The figures follow the definitions of evo (Grupp, "evo: Python package for the evaluation of
odometry and SLAM", https://github.com/MichaelGrupp/evo) and of Sturm et al., "A benchmark for
the evaluation of RGB-D SLAM systems" (IROS 2012):

* **ATE** — the estimated positions ``p_k`` are first aligned to the reference positions ``g_k``
  by the rigid transform ``(R, t)`` minimising ``Σ_k ‖R p_k + t − g_k‖²`` (Umeyama 1991 /
  Horn 1987, rotation and translation, no scale; in 2D the planar closed form, see
  :func:`align_rigid`). For a Sim(3) trajectory (a monocular system's, whose poses carry a scale)
  the alignment is a similarity ``(c, R, t)`` (Umeyama with scale, evo's ``-as``), each pose's own
  scale applied first (:func:`posegraph.lie.group.embed_in_se3`). The error of pose ``k`` is
  ``‖R p_k + t − g_k‖`` (``ate_translation``, in the file's length unit) and the angle of
  ``G_kᵀ · R · P_k`` (``ate_rotation``, degrees), where ``P_k``, ``G_k`` are the rotations.
* **RPE** — for consecutive poses ``k, k+1`` (in id order) the relative motions
  ``A = X_k⁻¹ X_{k+1}`` (estimate) and ``B = Y_k⁻¹ Y_{k+1}`` (reference) are compared through
  ``E = B⁻¹ A``; the error is ``‖trans(E)‖`` (``rpe_translation``) and the rotation angle of
  ``E`` in degrees (``rpe_rotation``). RPE needs no alignment: it is invariant to a rigid
  motion of either trajectory. This is evo's ``evo_rpe --delta 1 --delta_unit f``.

Each error list is summarised as evo does (:class:`ErrorStats`: rmse, mean, median, std, min,
max, sse; ``std`` is the population standard deviation, as ``numpy.std``).

Poses are matched by vertex id: only ids present in both graphs are compared.

Dimensions: poses are SE(3) ``(n, 4, 4)`` or SE(2) ``(n, 3, 3)`` matrices and every function works
on either through the same code (``d = 3`` or ``2`` below).  A 2D trajectory gives the same figures
as its embedding at ``z = 0`` (:func:`posegraph.lie.se2.to_se3`); :func:`evaluate` embeds a 2D
trajectory when the other one is 3D.

Files: :func:`read_trajectory` reads a g2o file's vertices; a file with edges only, such as gtsam's
``sphere2500_groundtruth.txt`` (``EDGE3`` lines, no vertices), gives the poses obtained by chaining
its odometry edges ``i → i+1`` from the identity at the smallest id (read with gtsam).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from posegraph.errors import InputError
from posegraph.lie import so2
from posegraph.lie.group import embed_in_se3

__all__ = [
    "ErrorStats",
    "TrajectoryErrors",
    "error_stats",
    "rotation_angle",
    "align_rigid",
    "is_similarity_trajectory",
    "match_by_id",
    "absolute_trajectory_error",
    "relative_pose_error",
    "evaluate",
    "read_trajectory",
    "chain_odometry",
]


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a list of non-negative errors, with evo's field names."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    def as_dict(self) -> dict:
        return asdict(self)


def error_stats(errors: np.ndarray) -> ErrorStats:
    """Statistics of ``errors`` ``(k,)``: ``rmse = sqrt(mean(e²))``, ``sse = Σ e²``, ``std`` = numpy.std."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, nan, nan, 0.0, 0)
    sq = e * e
    return ErrorStats(
        rmse=float(np.sqrt(sq.mean())),
        mean=float(e.mean()),
        median=float(np.median(e)),
        std=float(e.std()),
        min=float(e.min()),
        max=float(e.max()),
        sse=float(sq.sum()),
        count=int(e.size),
    )


def rotation_angle(rotations: np.ndarray) -> np.ndarray:
    """Rotation angle θ ∈ [0, π] of rotation matrices ``(..., 3, 3)`` or ``(..., 2, 2)``, in radians.

    3D: ``θ = atan2(‖vee(R − Rᵀ)‖ / 2, (tr R − 1) / 2)``; 2D: ``θ = |atan2(R₁₀ − R₀₁, R₀₀ + R₁₁)|``.
    sin θ and cos θ are both read off R, so the angle is accurate near 0 (where ``arccos`` of the
    trace loses half the digits) and near π (where ``arcsin`` would).
    """
    R = np.asarray(rotations, dtype=np.float64)
    if R.shape[-1] == 2:
        return np.abs(so2.to_angle(R))
    skew = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    sin_theta = 0.5 * np.linalg.norm(skew, axis=-1)
    cos_theta = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(sin_theta, cos_theta)


def align_rigid(source: np.ndarray, target: np.ndarray, *, with_scale: bool = False):
    """Rigid transform ``(R, t)`` minimising ``Σ_k ‖R·source_k + t − target_k‖²`` (no scale).

    ``source``, ``target``: ``(k, d)`` points, ``d = 3`` or ``2``. With centred points ``s̃, g̃``
    and ``Σ = Σ_k g̃_k s̃_kᵀ``, ``t = ḡ − R s̄`` and

    * 3D (``k ≥ 3`` for a unique answer): Umeyama (1991), "Least-squares estimation of
      transformation parameters between two point patterns", with the scale fixed to 1:
      ``Σ = U S Vᵀ``, ``R = U diag(1, 1, det(U)·det(V)) Vᵀ`` (the sign keeps R a rotation, never
      a reflection).
    * 2D (``k ≥ 2``): the planar rotation ``R(φ)`` maximising ``tr(R Σᵀ)``, in closed form
      ``φ = atan2(Σ₁₀ − Σ₀₁, Σ₀₀ + Σ₁₁)`` (Horn's 2D case; gtsam's ``Pose2.Align``): no SVD, and
      no reliance on the determinant fix to pin the free third axis of the rank-2 ``Σ`` that
      planar points embedded in 3D give Umeyama (tests check both agree on such points).

    Returns ``R`` ``(d, d)`` and ``t`` ``(d,)``; with ``with_scale``, ``(c, R, t)`` minimising
    ``Σ_k ‖c R·source_k + t − target_k‖²``: the same ``R`` and Umeyama's ``c = tr(Rᵀ Σ) / Σ_k ‖s̃_k‖²``,
    ``t = ḡ − c R s̄`` (evo's ``-as``).
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    source_mean = source.mean(axis=0)
    target_mean = target.mean(axis=0)
    cross = (target - target_mean).T @ (source - source_mean)
    if cross.shape == (2, 2):
        R = so2.project(cross)
    else:
        U, _, Vt = np.linalg.svd(cross)
        d = np.ones(3)
        d[2] = np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0
        R = (U * d) @ Vt
    if not with_scale:
        return R, target_mean - R @ source_mean
    spread = float(np.sum((source - source_mean) ** 2))
    c = float(np.sum(R * cross)) / spread if spread > 0.0 else 1.0
    return c, R, target_mean - c * R @ source_mean


def is_similarity_trajectory(poses: np.ndarray) -> bool:
    """Whether ``(n, 4, 4)`` poses carry scales (a Sim(3) graph's): some ``|det(s R)^{1/3} − 1| > 1e-9``."""
    poses = np.asarray(poses)
    if poses.shape[-1] != 4 or not poses.size:
        return False
    return bool(np.any(np.abs(np.cbrt(np.linalg.det(poses[..., :3, :3])) - 1.0) > 1e-9))


def match_by_id(
    estimate_ids: np.ndarray, reference_ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids present in both lists, sorted, with their positions in each.

    Returns ``(ids, estimate_index, reference_index)``, each ``(k,)``.
    """
    estimate_ids = np.asarray(estimate_ids, dtype=np.int64)
    reference_ids = np.asarray(reference_ids, dtype=np.int64)
    ids, estimate_index, reference_index = np.intersect1d(
        estimate_ids, reference_ids, assume_unique=True, return_indices=True
    )
    return ids, estimate_index, reference_index


def absolute_trajectory_error(
    estimate: np.ndarray, reference: np.ndarray, *, align: bool = True, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pose ATE after a rigid (``with_scale``: similarity) alignment of ``estimate`` onto ``reference``.

    ``estimate``, ``reference``: matched poses ``(k, d+1, d+1)``. Returns ``(translation_errors
    (k,), rotation_errors_deg (k,), alignment (d+1, d+1))`` where ``alignment`` is the SE(d)
    matrix ``[R t; 0 1]`` (``[c R t; 0 1]`` with scale) applied to the estimate (identity when
    ``align`` is False).
    """
    estimate = np.asarray(estimate, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    d = estimate.shape[-1] - 1
    alignment = np.eye(d + 1)
    if align:
        c, R, t = align_rigid(estimate[:, :d, d], reference[:, :d, d], with_scale=True) if with_scale else (
            1.0, *align_rigid(estimate[:, :d, d], reference[:, :d, d]))  # fmt: skip
        alignment[:d, :d] = c * R
        alignment[:d, d] = t
    aligned = _aligned(alignment, estimate)
    translation = np.linalg.norm(aligned[:, :d, d] - reference[:, :d, d], axis=-1)
    rotation = np.degrees(
        rotation_angle(np.swapaxes(reference[:, :d, :d], -1, -2) @ aligned[:, :d, :d])
    )
    return translation, rotation, alignment


def _aligned(alignment: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """``alignment @ estimate`` with the alignment's scale ``c`` taken out of the rotation blocks."""
    d = estimate.shape[-1] - 1
    aligned = alignment @ estimate
    c = abs(np.linalg.det(alignment[:d, :d])) ** (1.0 / d)
    if c != 1.0:
        aligned[:, :d, :d] /= c
    return aligned


def _inverse(poses: np.ndarray) -> np.ndarray:
    """``[[Rᵀ, −Rᵀ t], [0, 1]]`` for poses ``(k, d+1, d+1)``."""
    d = poses.shape[-1] - 1
    Rt = np.swapaxes(poses[:, :d, :d], -1, -2)
    out = np.zeros_like(poses)
    out[:, :d, :d] = Rt
    out[:, :d, d] = -np.einsum("kij,kj->ki", Rt, poses[:, :d, d])
    out[:, d, d] = 1.0
    return out


def _relative(poses: np.ndarray) -> np.ndarray:
    """``X_k⁻¹ X_{k+1}`` for consecutive poses ``(k, d+1, d+1)`` → ``(k−1, d+1, d+1)``."""
    return _inverse(poses[:-1]) @ poses[1:]


def relative_pose_error(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step RPE between consecutive matched poses (delta = 1 pose).

    ``estimate``, ``reference``: ``(k, d+1, d+1)`` in the order to walk (id order). Returns
    ``(translation_errors (k−1,), rotation_errors_deg (k−1,))`` of ``E = B⁻¹ A`` with
    ``A = X_k⁻¹ X_{k+1}``, ``B = Y_k⁻¹ Y_{k+1}``.
    """
    A = _relative(np.asarray(estimate, dtype=np.float64))
    B = _relative(np.asarray(reference, dtype=np.float64))
    E = _inverse(B) @ A
    d = E.shape[-1] - 1
    return np.linalg.norm(E[:, :d, d], axis=-1), np.degrees(rotation_angle(E[:, :d, :d]))


@dataclass(frozen=True)
class TrajectoryErrors:
    """Result of :func:`evaluate`. Lengths are in the files' unit, angles in degrees."""

    num_matched: int
    """Poses compared (ids present in both graphs)."""
    num_estimate: int
    num_reference: int
    ate_translation: ErrorStats
    ate_rotation: ErrorStats
    rpe_translation: ErrorStats
    rpe_rotation: ErrorStats
    alignment: np.ndarray
    """``(4, 4)`` SE(3) or, for two 2D trajectories, ``(3, 3)`` SE(2) transform applied to the
    estimate before computing ATE; a similarity ``[c R, t; 0, 1]`` for a Sim(3) trajectory."""

    def as_dict(self) -> dict:
        return {
            "num_matched": self.num_matched,
            "num_estimate": self.num_estimate,
            "num_reference": self.num_reference,
            "ate_translation": self.ate_translation.as_dict(),
            "ate_rotation_deg": self.ate_rotation.as_dict(),
            "rpe_translation": self.rpe_translation.as_dict(),
            "rpe_rotation_deg": self.rpe_rotation.as_dict(),
            "alignment": self.alignment.tolist(),
        }


def evaluate(
    estimate_ids: np.ndarray,
    estimate_poses: np.ndarray,
    reference_ids: np.ndarray,
    reference_poses: np.ndarray,
    *,
    align: bool = True,
    source: str | None = None,
    with_scale: bool | None = None,
) -> TrajectoryErrors:
    """ATE and RPE of an estimated trajectory against a reference, matched by vertex id.

    ``*_ids`` ``(n,)`` and ``*_poses`` ``(n, 4, 4)`` or ``(n, 3, 3)``; poses are compared in
    increasing id order. When one trajectory is 2D and the other 3D, the 2D one is embedded at
    ``z = 0`` (:func:`posegraph.lie.se2.to_se3`). ``with_scale`` (default: when either trajectory carries
    scales, :func:`is_similarity_trajectory`) aligns by a similarity, each pose's scale applied first, and
    RPE compares the aligned estimate (so its steps are at the reference's scale, as evo's ``-as``). Raises :class:`~posegraph.errors.InputError` (naming ``source``) when fewer than 3 ids are
    shared, since the alignment is then not unique.
    """
    ids, ei, ri = match_by_id(estimate_ids, reference_ids)
    if ids.size < 3:
        raise InputError(
            f"only {ids.size} vertex id(s) in common between the estimate and the reference "
            "(need at least 3 to align the trajectories)",
            path=source,
        )
    estimate = np.asarray(estimate_poses, dtype=np.float64)[ei]
    reference = np.asarray(reference_poses, dtype=np.float64)[ri]
    if with_scale is None:
        with_scale = is_similarity_trajectory(estimate) or is_similarity_trajectory(reference)
    if estimate.shape[-1] != reference.shape[-1] or estimate.shape[-1] == 4:
        estimate, reference = embed_in_se3(estimate), embed_in_se3(reference)  # Sim(3): each pose's scale applied
    ate_t, ate_r, alignment = absolute_trajectory_error(estimate, reference, align=align, with_scale=with_scale)
    rpe_t, rpe_r = relative_pose_error(_aligned(alignment, estimate) if with_scale else estimate, reference)
    return TrajectoryErrors(
        num_matched=int(ids.size),
        num_estimate=int(len(estimate_ids)),
        num_reference=int(len(reference_ids)),
        ate_translation=error_stats(ate_t),
        ate_rotation=error_stats(ate_r),
        rpe_translation=error_stats(rpe_t),
        rpe_rotation=error_stats(rpe_r),
        alignment=alignment,
    )


def chain_odometry(
    ids_from: np.ndarray, ids_to: np.ndarray, measurements: np.ndarray, source: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Poses from the odometry edges (``|i − j| = 1``) of an edge list, starting at the identity.

    ``ids_from``, ``ids_to`` ``(m,)`` vertex ids and ``measurements`` ``(m, d+1, d+1)`` with
    ``Z ≈ X_i⁻¹ X_j``. Returns ``(ids, poses)`` for the ids ``min .. max``: ``X_min = I`` and
    ``X_{k+1} = X_k Z_{k,k+1}`` (an edge ``k+1 → k`` is used inverted). Raises
    :class:`~posegraph.errors.InputError` when an id of that range has no odometry edge to its
    successor.
    """
    ids_from = np.asarray(ids_from, dtype=np.int64)
    ids_to = np.asarray(ids_to, dtype=np.int64)
    Z = np.asarray(measurements, dtype=np.float64)
    first = int(min(ids_from.min(), ids_to.min()))
    last = int(max(ids_from.max(), ids_to.max()))
    n = last - first + 1
    size = Z.shape[-1]
    steps = np.full((n - 1, size, size), np.nan)
    forward = ids_to == ids_from + 1
    steps[ids_from[forward] - first] = Z[forward]
    backward = (ids_from == ids_to + 1) & ~np.isin(ids_to - first, ids_from[forward] - first)
    if np.any(backward):
        steps[ids_to[backward] - first] = _inverse(Z[backward])
    missing = np.flatnonzero(np.isnan(steps[:, 0, 0]))
    if missing.size:
        k = first + int(missing[0])
        raise InputError(f"no odometry edge from vertex {k} to {k + 1}: cannot chain the trajectory", path=source)
    poses = np.empty((n, size, size))
    poses[0] = np.eye(size)
    for k in range(n - 1):  # a sequential product: each pose depends on the previous one
        poses[k + 1] = poses[k] @ steps[k]
    return np.arange(first, last + 1, dtype=np.int64), poses


def _is_gtsam_edge_file(path: str) -> bool:
    """True for a file with ``EDGE3`` lines and no ``VERTEX`` line (gtsam's edge-only format)."""
    from posegraph.io.text_input import read_blocks

    has_edge3 = False
    for block in read_blocks(path):  # as the g2o reader reads it: memory bounded, binary refused
        for line in block.lines:
            tag = line.lstrip()[:6]
            if tag.startswith("VERTEX"):
                return False
            has_edge3 = has_edge3 or tag.startswith("EDGE3")
    return has_edge3


def read_trajectory(path, *, repair_information: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Vertex ids ``(n,)`` and poses ``(n, 4, 4)`` — ``(n, 3, 3)`` for a 2D graph — of a trajectory file.

    A g2o file is read with :func:`posegraph.io.g2o.read_g2o` (vertices alone are enough). A file
    without any ``VERTEX`` line that the g2o reader refuses — gtsam's own format with ``EDGE3 i j x y z roll pitch yaw`` lines,
    as in ``sphere2500_groundtruth.txt`` — is read with ``gtsam.readG2o`` (gtsam's reader, so its
    angle convention is gtsam's) and its poses are :func:`chain_odometry` of its edges.
    ``repair_information`` is passed to ``read_g2o`` (the information matrices do not enter the
    poses, but a file with indefinite ones is refused without it).
    """
    import os

    from posegraph.errors import GraphError
    from posegraph.io.g2o import read_g2o

    name = os.fspath(path)
    try:
        graph = read_g2o(name, require_edges=False, repair_information=repair_information)
    except GraphError as err:
        if not _is_gtsam_edge_file(name):
            raise
        refused = err
    else:
        return graph.ids, graph.poses

    from posegraph.crosscheck.gtsam_bridge import require_gtsam

    try:
        gtsam = require_gtsam()
    except ImportError as exc:
        raise ImportError(f"{name} has edges but no vertices; reading it as a trajectory {exc}") from exc
    try:
        factors, _ = gtsam.readG2o(name, True)
    except RuntimeError as exc:
        raise InputError(
            f"gtsam cannot read the file either ({exc}); the g2o reader said: {refused.reason}", name
        ) from exc
    ids_from, ids_to, measurements = [], [], []
    for k in range(factors.size()):
        factor = factors.at(k)
        if isinstance(factor, gtsam.BetweenFactorPose3):
            i, j = factor.keys()
            ids_from.append(i)
            ids_to.append(j)
            measurements.append(factor.measured().matrix())
    if not ids_from:
        raise GraphError("the file has neither vertices nor 3D edges: no trajectory to read", name)
    return chain_odometry(np.array(ids_from), np.array(ids_to), np.array(measurements), source=name)
