"""Small pose graphs with a known truth for the initialisation tests.

Every builder returns ``(graph, truth)``: ``truth`` ``(n, k, k)`` are the poses the measurements
were generated from. File poses are deliberately wrong (the truth seen through a per-component
rigid motion — the gauge — and then perturbed), except that held vertices (fixed ones, or each
unfixed component's smallest id) carry the truth through the gauge exactly, so a perfect
initialiser returns ``expected_poses(graph, truth)``. Builders take ``group`` (SE(3) by default,
or SE(2)), so each test runs on both through one code path.
"""

from __future__ import annotations

import numpy as np

from posegraph.model.graph import PoseGraph, component_anchors, connected_components
from posegraph.lie import se3, so3
from posegraph.lie.group import SE2, SE3


def random_rotations(rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, 3, 3)`` rotations uniform on SO(3) (unit quaternions from a 4D Gaussian)."""
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return so3.from_quaternion(q)


def trajectory(rng: np.random.Generator, n: int, step: float = 1.0, turn: float = 0.3, group=SE3) -> np.ndarray:
    """``(n, k, k)`` a random walk: each pose is the previous one moved by a random body-frame step."""
    if group is SE2:
        tangent = np.concatenate([rng.normal(scale=step, size=(n, 2)), rng.normal(scale=turn, size=(n, 1))], axis=1)
        first = SE2.exp(np.concatenate([rng.normal(scale=5.0, size=2), rng.uniform(-np.pi, np.pi, 1)]))
    else:
        tangent = np.concatenate([rng.normal(scale=turn, size=(n, 3)), rng.normal(scale=step, size=(n, 3))], axis=1)
        first = se3.from_rotation_translation(random_rotations(rng, 1)[0], rng.normal(scale=5.0, size=3))
    steps = group.exp(tangent)
    k = group.matrix_size
    poses = np.empty((n, k, k))
    poses[0] = first
    for k in range(1, n):  # a test fixture: n is tens of poses
        poses[k] = poses[k - 1] @ steps[k]
    return poses


def information_matrices(
    rng: np.random.Generator, count: int, low: float = 1.0, high: float = 1.0, rotate: bool = True, size: int = 6
) -> np.ndarray:
    """``(count, d, d)`` SPD information (``d = size``) with eigenvalues log-uniform in [low, high].

    With ``rotate`` each matrix has random eigenvectors (coupling rotation and translation);
    otherwise it is diagonal.
    """
    eigenvalues = np.exp(rng.uniform(np.log(low), np.log(high), size=(count, size)))
    if not rotate:
        return eigenvalues[:, :, None] * np.eye(size)
    basis, _ = np.linalg.qr(rng.normal(size=(count, size, size)))
    return (basis * eigenvalues[:, None, :]) @ basis.transpose(0, 2, 1)


def noisy_measurements(
    rng: np.random.Generator, exact: np.ndarray, information: np.ndarray, max_sigma=(0.05, 0.1), group=SE3
) -> np.ndarray:
    """``Z · Exp(ε)`` with ε ~ N(0, Ω⁻¹), its standard deviation per eigen-direction capped.

    ``max_sigma`` = (radians, metres): a weak direction (information 1e-2) would otherwise get a
    10 rad error; the cap keeps the measurement plausible while its weight stays tiny.
    """
    eigenvalues, basis = np.linalg.eigh(information)
    sigma = 1.0 / np.sqrt(eigenvalues)
    rotation, translation = list(group.rotation_axes), list(group.translation_axes)
    cap = np.where(np.abs(basis[:, rotation, :]).sum(axis=1) >= np.abs(basis[:, translation, :]).sum(axis=1), *max_sigma)
    sigma = np.minimum(sigma, cap)
    noise = (basis @ (sigma * rng.normal(size=sigma.shape))[..., None])[..., 0]
    return exact @ group.exp(noise)


def build_graph(
    truth: np.ndarray,
    edge_from: np.ndarray,
    edge_to: np.ndarray,
    information: np.ndarray,
    *,
    rng: np.random.Generator,
    noise: bool = False,
    ids: np.ndarray | None = None,
    fixed: np.ndarray | None = None,
    file_perturbation: float = 0.5,
    group=SE3,
) -> PoseGraph:
    """A graph whose measurements come from ``truth`` (noisy or exact) and whose file poses are off.

    Each component is seen through a random rigid motion (the gauge); non-held vertices are further
    perturbed by ``Exp(N(0, file_perturbation²))``.
    """
    n = truth.shape[0]
    edge_from = np.asarray(edge_from, dtype=np.int64)
    edge_to = np.asarray(edge_to, dtype=np.int64)
    exact = group.inverse(truth[edge_from]) @ truth[edge_to]
    measurements = noisy_measurements(rng, exact, information, group=group) if noise else exact
    ids = np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
    fixed = np.zeros(n, dtype=bool) if fixed is None else np.asarray(fixed, dtype=bool)
    graph = PoseGraph(
        ids=ids,
        poses=truth.copy(),
        edge_from=edge_from,
        edge_to=edge_to,
        measurements=measurements,
        information=information,
        fixed=fixed,
        group=group,
    )
    count, labels = connected_components(graph)
    gauge = group.exp(rng.normal(scale=1.0, size=(count, group.dim)))
    poses = gauge[labels] @ truth
    held = fixed.copy()
    held[component_anchors(graph)] = True
    poses[~held] = poses[~held] @ group.exp(rng.normal(scale=file_perturbation, size=(int((~held).sum()), group.dim)))
    return graph.with_poses(poses)


def expected_poses(graph: PoseGraph, truth: np.ndarray) -> np.ndarray:
    """The truth moved into each component's gauge: ``X_h^file (X_h^true)⁻¹ X_k^true`` for a held ``h``."""
    count, labels = connected_components(graph)
    held = np.array(graph.fixed, copy=True)
    held[component_anchors(graph)] = True
    first_held = np.full(count, -1)
    first_held[labels[held][::-1]] = np.flatnonzero(held)[::-1]
    h = first_held[labels]
    return graph.poses[h] @ graph.group.inverse(truth[h]) @ truth


def loop_graph_edges(rng: np.random.Generator, n: int, loops: int) -> tuple[np.ndarray, np.ndarray]:
    """An odometry chain ``k → k+1`` plus ``loops`` random loop closures ``i → j`` (i < j − 1)."""
    chain_from = np.arange(n - 1)
    i = rng.integers(0, n - 2, size=loops)
    j = np.minimum(i + rng.integers(2, n, size=loops), n - 1)
    keep = j > i + 1
    return np.concatenate([chain_from, i[keep]]), np.concatenate([chain_from + 1, j[keep]])


def noise_free_graph(seed: int, n: int = 40, loops: int = 20, ids: np.ndarray | None = None,
                     info_range=(1.0, 1e3), group=SE3) -> tuple[PoseGraph, np.ndarray]:
    """One component, exact measurements, information eigenvalues in ``info_range``."""
    rng = np.random.default_rng(seed)
    truth = trajectory(rng, n, group=group)
    edge_from, edge_to = loop_graph_edges(rng, n, loops)
    information = information_matrices(rng, edge_from.size, *info_range, size=group.dim)
    graph = build_graph(truth, edge_from, edge_to, information, rng=rng, ids=ids, group=group)
    return graph, truth


def hard_graph(seed: int, noise: bool = True, info_range=(1e-2, 1e7), group=SE3) -> tuple[PoseGraph, np.ndarray]:
    """Everything that upsets other initialisers, at once, on ~70 vertices:

    * three components with unordered, sparse ids; one holds two ``FIX`` vertices;
    * information eigenvalues log-uniform over ``info_range`` (default 1e-2..1e7) with random
      eigenvectors, so rotation and translation are coupled and some edges are almost blind;
    * duplicate edges, in both directions, with independent noise;
    * degree-one vertices hanging off each component.
    """
    rng = np.random.default_rng(seed)
    sizes = (30, 20, 12)
    parts_from, parts_to, truths = [], [], []
    offset = 0
    for size in sizes:
        truth = trajectory(rng, size, group=group)
        edge_from, edge_to = loop_graph_edges(rng, size, size // 2)
        # duplicates: repeat some edges, half of them reversed
        pick = rng.choice(edge_from.size, size=max(2, size // 5), replace=False)
        reverse = rng.random(pick.size) < 0.5
        dup_from = np.where(reverse, edge_to[pick], edge_from[pick])
        dup_to = np.where(reverse, edge_from[pick], edge_to[pick])
        edge_from, edge_to = np.concatenate([edge_from, dup_from]), np.concatenate([edge_to, dup_to])
        parts_from.append(edge_from + offset)
        parts_to.append(edge_to + offset)
        truths.append(truth)
        offset += size
    truth = np.concatenate(truths)
    edge_from, edge_to = np.concatenate(parts_from), np.concatenate(parts_to)
    # degree-one leaves: new vertices joined to one existing vertex each, in either direction
    leaves = 6
    attach = rng.integers(0, offset, size=leaves)
    leaf_scale = np.ones(group.dim)
    leaf_scale[list(group.rotation_axes)] = 0.3
    leaf_poses = truth[attach] @ group.exp(rng.normal(scale=leaf_scale, size=(leaves, group.dim)))
    truth = np.concatenate([truth, leaf_poses])
    leaf = np.arange(offset, offset + leaves)
    outward = rng.random(leaves) < 0.5
    edge_from = np.concatenate([edge_from, np.where(outward, attach, leaf)])
    edge_to = np.concatenate([edge_to, np.where(outward, leaf, attach)])
    n = truth.shape[0]
    # unordered, sparse ids
    ids = rng.permutation(np.arange(n) * 7 + 1000)
    fixed = np.zeros(n, dtype=bool)
    fixed[[sizes[0] + 3, sizes[0] + 11]] = True  # two FIX vertices in the second component
    information = information_matrices(rng, edge_from.size, *info_range, size=group.dim)
    graph = build_graph(
        truth, edge_from, edge_to, information, rng=rng, noise=noise, ids=ids, fixed=fixed, group=group
    )
    return graph, truth


def roll_blind_odometry_graph(seed: int, n: int = 60) -> tuple[PoseGraph, np.ndarray]:
    """Odometry precise in pitch, yaw and translation but blind in roll; mediocre loop closures.

    Odometry edges: Ω = diag(1e-2, 1e6, 1e6, 1e4, 1e4, 1e4) in ``[ω; v]`` order, noise σ = 0.02 rad
    in roll, 1e-3 rad in pitch and yaw, none in translation. Loop closures: Ω = diag(10, 10, 10, 1, 1,
    1) with σ = 0.3 on every component (noisier than their information says). Legitimate — an
    IMU-less wheel odometry that cannot see roll — and a trap for weighting an edge's chordal term by
    its roll information alone, as gtsam's ``InitializePose3`` does (√Ω[0,0]).
    """
    rng = np.random.default_rng(seed)
    truth = trajectory(rng, n, step=1.0, turn=0.2)
    edge_from, edge_to = loop_graph_edges(rng, n, 40)
    odometry = edge_to == edge_from + 1
    information = np.zeros((edge_from.size, 6, 6))
    information[odometry] = np.diag([1e-2, 1e6, 1e6, 1e4, 1e4, 1e4])
    information[~odometry] = np.diag([10.0, 10.0, 10.0, 1.0, 1.0, 1.0])
    graph = build_graph(truth, edge_from, edge_to, information, rng=rng)
    noise = np.zeros((edge_from.size, 6))
    noise[odometry, 0] = rng.normal(scale=0.02, size=odometry.sum())
    noise[odometry, 1:3] = rng.normal(scale=1e-3, size=(odometry.sum(), 2))
    noise[~odometry] = rng.normal(scale=0.3, size=((~odometry).sum(), 6))
    measurements = graph.measurements @ se3.exp(noise)
    return PoseGraph(graph.ids, graph.poses, edge_from, edge_to, measurements, information), truth


def noise_free_cases():
    """``(name, graph, truth)`` of the noise-free graphs every initialiser must solve exactly, traits in the name."""
    sparse_ids = np.random.default_rng(7).permutation(np.arange(40) * 13 + 5)
    yield "chain+loops", *noise_free_graph(0)
    yield "sparse-unordered-ids", *noise_free_graph(1, ids=sparse_ids)
    yield "ill-conditioned-1e-2..1e7", *noise_free_graph(2, info_range=(1e-2, 1e7))
    yield "components+fix+duplicates+leaves", *hard_graph(3, noise=False)
    yield "SE2 chain+loops", *noise_free_graph(0, group=SE2)
    yield "SE2 sparse-unordered-ids", *noise_free_graph(1, ids=sparse_ids, group=SE2)
    yield "SE2 ill-conditioned-1e-2..1e7", *noise_free_graph(2, info_range=(1e-2, 1e7), group=SE2)
    yield "SE2 components+fix+duplicates+leaves", *hard_graph(3, noise=False, group=SE2)
