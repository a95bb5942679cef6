"""Synthetic pose graphs with ground truth: sphere, torus, 3D grid, parking garage (3D); a Manhattan world (2D);
a monocular camera's Sim(3) graph whose odometry scale drifts (:func:`monocular`).

Every generator builds ground-truth poses ``X_k`` (world-from-body, ``(n, 4, 4)``; ``(n, 3, 3)``
SE(2) matrices for the planar ``manhattan``, whose noise is in ``[v_x, v_y, ω]`` order), the odometry
chain ``k → k+1`` and a set of candidate loop closures, then makes the measurements the way the
cost assumes they were made::

    Z_ij = (X_i⁻¹ X_j) · Exp(δ),   δ ~ N(0, Σ),   Σ = diag(σ_rot² I₃, σ_trans² I₃)   ([ω; v] order)

with information Ω = Σ⁻¹ on every edge. So at the ground truth each edge's residual
``Log(Z⁻¹ X_i⁻¹ X_j) = −δ`` and ``2 · cost(ground truth)`` is χ²-distributed with ``6 m``
degrees of freedom (mean ``3 m`` for the cost) when there are no outliers. The initial values of
the returned graph are the noisy odometry composed from the ground-truth first pose (vertex 0,
the gauge anchor), as in g2o's ``create_sphere``.

Loop closures: a fraction ``loop_closure_density`` of each shape's candidates is kept (chosen by
the generator's random stream). Outliers: ``outlier_fraction`` of all loop closures are wrong
data associations — edges between two random, non-consecutive vertices whose measurement is the
relative pose of some *other* true loop closure (plus loop-closure noise), so that an outlier
looks like an inlier until it is checked against the rest of the graph (the perceptual-aliasing
failure robust back ends are tested on; Sünderhauf & Protzel, "Switchable constraints", 2012).

Edges are ordered by their newer vertex, then the older one, as a front end emits them; odometry
edges point ``k → k+1``, loop closures from the older vertex to the newer.

Everything is drawn from ``np.random.default_rng(seed)`` in a fixed order, so the same arguments
give the same graph, bit for bit, and the same files.

Random outliers in any graph: :func:`inject_outliers` adds loop closures between random vertex
pairs with random relative poses (rotation uniform on SO(3), translation uniform in a cube the size
of the graph) to a graph read from a file, e.g. sphere2500 with 20 % of its loop-closure count.

Outlier files: whenever a written graph has outliers, ``NAME.outliers.txt`` beside ``NAME.g2o``
lists their 0-based indices in the g2o file's edge-line order, one per line after ``#`` comment
lines (``np.loadtxt`` reads it; :func:`read_outlier_indices`).

Command line (writes ``OUT``, ``OUT``'s ``_groundtruth.g2o`` sibling and, with outliers,
``OUT``'s ``.outliers.txt``)::

    python -m datasets.synthetic sphere --size 2500 -o sphere.g2o
    python -m datasets.synthetic grid --size 8000 --loop-density 0.5 --outliers 0.1 -o grid.g2o
    python -m datasets.synthetic inject sphere2500.g2o --fraction 0.2 --seed 1 -o sphere2500_outliers.g2o
    python -m datasets.synthetic monocular --size 2500 -o mono.g2o   # Sim(3): VERTEX_SIM3:EXPMAP lines
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from posegraph.model.graph import PoseGraph, vertex_ranks
from posegraph.lie import se2, se3, so2, so3
from posegraph.lie.group import SE2, SE3, SIM3_G2O, LieGroup

__all__ = [
    "NoiseParams",
    "SyntheticDataset",
    "sphere",
    "torus",
    "grid",
    "garage",
    "manhattan",
    "monocular",
    "generate",
    "shape_arguments",
    "SHAPES",
    "groundtruth_path",
    "outliers_path",
    "random_relative_poses",
    "inject_outliers",
    "write_outlier_indices",
    "read_outlier_indices",
    "write_dataset",
    "write_injected",
    "landmark_graph",
    "LANDMARK_TAGS",
    "main",
]


@dataclass(frozen=True)
class NoiseParams:
    """Measurement noise, loop-closure density and outliers of a synthetic graph.

    Sigmas are standard deviations of the right perturbation ``δ = [ω; v]`` in
    ``Z = Z_true · Exp(δ)``: radians for rotation, the shape's length unit (metres) for translation.
    """

    odometry_rotation_sigma: float = 0.01
    """σ of each rotation component of an odometry edge's noise (rad)."""
    odometry_translation_sigma: float = 0.05
    """σ of each translation component of an odometry edge's noise (m)."""
    loop_rotation_sigma: float = 0.01
    """σ of each rotation component of a loop closure's noise (rad)."""
    loop_translation_sigma: float = 0.05
    """σ of each translation component of a loop closure's noise (m)."""
    loop_closure_density: float = 1.0
    """Fraction in [0, 1] of the shape's candidate loop closures that are kept."""
    outlier_fraction: float = 0.0
    """Fraction in [0, 1) of all loop closures (inliers + outliers) that are outliers."""
    odometry_scale_sigma: float = 0.01
    """σ of the log-scale λ of a Sim(3) odometry edge (:func:`monocular`): the scale drift per step."""
    loop_scale_sigma: float = 0.001
    """σ of the log-scale of a Sim(3) loop closure, which carries the true relative scale."""
    noiseless: bool = False
    """If True the measurements are the exact relative poses (the information still states the
    sigmas above): the ground truth is then an exact minimum with cost 0 (outliers excepted)."""

    def __post_init__(self) -> None:
        for name in (
            "odometry_rotation_sigma",
            "odometry_translation_sigma",
            "loop_rotation_sigma",
            "loop_translation_sigma",
            "odometry_scale_sigma",
            "loop_scale_sigma",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r} (use noiseless=True for exact measurements)")
        if not 0.0 <= self.loop_closure_density <= 1.0:
            raise ValueError(f"loop_closure_density must be in [0, 1], got {self.loop_closure_density!r}")
        if not 0.0 <= self.outlier_fraction < 1.0:
            raise ValueError(f"outlier_fraction must be in [0, 1), got {self.outlier_fraction!r}")


@dataclass(frozen=True, eq=False)
class SyntheticDataset:
    """A generated pose graph and its ground truth.

    Unpacks as ``graph, ground_truth = sphere(...)``.
    """

    name: str
    """Shape and size, e.g. ``"sphere_50x50"``."""
    graph: PoseGraph
    """The noisy graph; its poses are the composed noisy odometry (vertex 0 at the ground truth)."""
    ground_truth: np.ndarray
    """``(n, 4, 4)`` true poses (``(n, 3, 3)`` for a planar shape)."""
    outliers: np.ndarray
    """``(m,)`` bool — True for the outlier loop closures."""
    odometry: np.ndarray
    """``(m,)`` bool — True for the odometry edges (``k → k+1``)."""
    parameters: dict = field(default_factory=dict)
    """The arguments it was generated with (shape parameters, noise, seed)."""

    def __iter__(self):
        return iter((self.graph, self.ground_truth))

    @property
    def num_loop_closures(self) -> int:
        """Loop closures, outliers included."""
        return int(np.count_nonzero(~self.odometry))


# --------------------------------------------------------------------------------------------
# Shared machinery: ground truth + candidate loop closures -> noisy graph


def _rotation_z(angle: np.ndarray) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    axis = np.zeros(angle.shape + (3,))
    axis[..., 2] = angle
    return so3.exp(axis)


def _rotation_y(angle: np.ndarray) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    axis = np.zeros(angle.shape + (3,))
    axis[..., 1] = angle
    return so3.exp(axis)


def _random_rotations(rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, 3, 3)`` rotations uniform on SO(3): normalised 4D Gaussians are uniform unit quaternions
    (and so is any permutation of their components, so the quaternion order does not matter)."""
    q = rng.standard_normal((count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return so3.from_quaternion(q)


def _frames_from_axes(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` whose x axis is ``forward`` and whose z axis is ``up`` made
    orthogonal to it (Gram-Schmidt); y = z × x completes a right-handed frame."""
    x = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    z = up - np.sum(up * x, axis=-1, keepdims=True) * x
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def _compose_chain(first: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses ``X_0 = first``, ``X_{k+1} = X_k · Z_k`` for steps ``(n-1, k, k)``; returns ``(n, k, k)``
    (any matrix group: the products are plain matrix products).

    An inclusive prefix product by recursive doubling (Hillis & Steele): after the pass with
    shift ``s`` entry ``k`` holds ``Z_{k-2s+1} ⋯ Z_k``; the earlier factor always stays on the
    left, so the non-commutative product is exact in ⌈log₂ n⌉ batched compositions.
    """
    prefix = np.array(steps, dtype=np.float64, copy=True)
    shift = 1
    while shift < len(prefix):
        prefix[shift:] = prefix[:-shift] @ prefix[shift:]
        shift *= 2
    return np.concatenate([first[None], first[None] @ prefix], axis=0)


def _sigmas(rotation_sigma: float, translation_sigma: float, group: LieGroup = SE3, scale_sigma: float = 1.0) -> np.ndarray:
    """``(d,)`` standard deviations in the group's tangent order: ``σ_rot`` at its rotation axes,
    ``scale_sigma`` at its log-scale axis (Sim(3))."""
    sigmas = np.full(group.dim, float(translation_sigma))
    sigmas[list(group.rotation_axes)] = rotation_sigma
    sigmas[list(group.scale_axes)] = scale_sigma
    return sigmas


def _information(rotation_sigma: float, translation_sigma: float, group: LieGroup = SE3, scale_sigma: float = 1.0) -> np.ndarray:
    """``diag(σ⁻²)`` of :func:`_sigmas` (``diag(σ_rot⁻² I₃, σ_trans⁻² I₃)`` in 3D) rounded to 12
    significant digits, so that files read ``400`` rather than ``399.99999999999994`` for σ = 0.05
    (a 1e-16 relative change)."""
    diagonal = _sigmas(rotation_sigma, translation_sigma, group, scale_sigma) ** -2
    return np.diag([float(f"{value:.12g}") for value in diagonal])


def _noise_arguments(noise: NoiseParams, group: LieGroup) -> tuple[tuple, tuple]:
    """The arguments of :func:`_sigmas` / :func:`_information` for odometry edges and for loop closures."""
    return (
        (noise.odometry_rotation_sigma, noise.odometry_translation_sigma, group, noise.odometry_scale_sigma),
        (noise.loop_rotation_sigma, noise.loop_translation_sigma, group, noise.loop_scale_sigma),
    )


def _build(
    name: str,
    truth: np.ndarray,
    loop_candidates: np.ndarray,
    noise: NoiseParams,
    rng: np.random.Generator,
    parameters: dict,
    group: LieGroup = SE3,
) -> SyntheticDataset:
    """Noisy graph of ``group`` from ground truth ``(n, k, k)`` and candidate loop-closure pairs ``(L, 2)`` (older, newer)."""
    n = len(truth)
    if n < 2:
        raise ValueError(f"{name}: a pose graph needs at least 2 poses, got {n}")
    loop_candidates = np.asarray(loop_candidates, dtype=np.int64).reshape(-1, 2)
    # A candidate joining consecutive poses would duplicate an odometry edge (the sphere's ring seam).
    loop_candidates = loop_candidates[np.abs(loop_candidates[:, 1] - loop_candidates[:, 0]) != 1]
    pairs, is_odometry, is_outlier = _edge_pairs(name, n, loop_candidates, noise, rng)
    exact = _exact_measurements(truth, pairs, is_outlier, loop_candidates, rng, group)
    measurements, information = _noisy(exact, is_odometry, noise, rng, group)

    # Initial values: noisy odometry composed from the true first pose.
    initial = _compose_chain(truth[0], measurements[: n - 1])

    # Front-end order: by newer vertex, then older.
    order = np.lexsort((pairs[:, 0], pairs[:, 1]))
    graph = PoseGraph(
        ids=np.arange(n, dtype=np.int64),
        poses=initial,
        edge_from=pairs[order, 0].copy(),
        edge_to=pairs[order, 1].copy(),
        measurements=measurements[order],
        information=information[order],
        group=group,
    )
    return SyntheticDataset(
        name=name,
        graph=graph,
        ground_truth=truth,
        outliers=is_outlier[order],
        odometry=is_odometry[order],
        parameters=parameters,
    )


def _edge_pairs(name: str, n: int, loop_candidates: np.ndarray, noise: NoiseParams, rng) -> tuple:
    """``(pairs (m, 2), is_odometry (m,), is_outlier (m,))``: the chain, the loop closures kept (a
    ``loop_closure_density`` share of the candidates) and the outliers (``outlier_fraction`` of all
    loop closures), in that order."""
    keep = int(round(noise.loop_closure_density * len(loop_candidates)))
    chosen = np.sort(rng.choice(len(loop_candidates), size=keep, replace=False)) if keep else np.zeros(0, np.int64)
    loops = loop_candidates[chosen]
    f = noise.outlier_fraction  # outliers / (inliers + outliers)
    num_outliers = int(round(f / (1.0 - f) * len(loops))) if f > 0 else 0
    outlier_pairs = _outlier_pairs(name, n, num_outliers, loop_candidates, rng)
    odometry_pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    pairs = np.concatenate([odometry_pairs, loops, outlier_pairs])
    m = len(pairs)
    is_odometry = np.zeros(m, bool)
    is_odometry[: n - 1] = True
    is_outlier = np.zeros(m, bool)
    is_outlier[m - num_outliers :] = True
    return pairs, is_odometry, is_outlier


def _exact_measurements(truth, pairs, is_outlier, loop_candidates, rng, group: LieGroup) -> np.ndarray:
    """``(m, k, k)`` true relative poses; an outlier borrows a random true loop closure's (or, when
    the shape has no loop closures to borrow from, a random relative pose)."""
    exact = group.between(truth[pairs[:, 0]], truth[pairs[:, 1]])
    count = int(np.count_nonzero(is_outlier))
    if count:
        if len(loop_candidates):
            donors = loop_candidates[rng.integers(0, len(loop_candidates), size=count)]
            exact[is_outlier] = group.between(truth[donors[:, 0]], truth[donors[:, 1]])
        else:
            exact[is_outlier] = _random_poses(rng, count, 1.0, group)
    return exact


def _noisy(exact, is_odometry, noise: NoiseParams, rng, group: LieGroup) -> tuple[np.ndarray, np.ndarray]:
    """``(measurements Z = Z_true · Exp(δ), information)``, ``δ ~ N(0, diag(σ²))`` in the tangent
    order with the odometry's or the loop closures' σ."""
    m, d = len(exact), group.dim
    odometry, loop = _noise_arguments(noise, group)
    sigmas = np.where(is_odometry[:, None], _sigmas(*odometry), _sigmas(*loop))
    delta = rng.standard_normal((m, d)) * sigmas
    if noise.noiseless:
        delta[:] = 0.0
    information = np.empty((m, d, d))
    information[is_odometry] = _information(*odometry)
    information[~is_odometry] = _information(*loop)
    return exact @ group.exp(delta), information


def _outlier_pairs(name: str, n: int, num_outliers: int, loop_candidates: np.ndarray, rng) -> np.ndarray:
    """``(num_outliers, 2)`` random pairs (older, newer): never a self-loop, an odometry pair, a true
    loop-closure candidate (its measurement could be nearly right) or a pair drawn twice."""
    if num_outliers and n < 3:
        raise ValueError(f"{name}: outliers need at least 3 poses")
    true_codes = np.sort(loop_candidates, axis=1) @ np.array([n, 1]) if len(loop_candidates) else np.zeros(0, np.int64)
    outlier_pairs = np.zeros((0, 2), np.int64)
    possible = n * (n - 1) // 2 - (n - 1) - len(np.unique(true_codes))
    if num_outliers > possible:
        raise ValueError(f"{name}: {num_outliers} outliers asked but only {possible} vertex pairs are free")
    while len(outlier_pairs) < num_outliers:
        draw = np.sort(rng.integers(0, n, size=(2 * num_outliers + 8, 2)), axis=1)
        draw = draw[draw[:, 1] - draw[:, 0] > 1]
        draw = draw[~np.isin(draw @ np.array([n, 1]), true_codes)]
        merged = np.concatenate([outlier_pairs, draw])
        _, first = np.unique(merged @ np.array([n, 1]), return_index=True)
        outlier_pairs = merged[np.sort(first)][:num_outliers]
    return outlier_pairs


def _ring_neighbours(older_start: np.ndarray, newer_start: np.ndarray, ring: int, offsets=(-1, 0, 1)) -> np.ndarray:
    """Pairs tying node ``k`` of each newer ring to nodes ``k + d (mod ring)`` of the older ring."""
    k = np.arange(ring)
    pairs = [
        np.stack(
            [
                (older_start[:, None] + (k[None, :] + d) % ring).ravel(),
                (newer_start[:, None] + k[None, :]).ravel(),
            ],
            axis=1,
        )
        for d in offsets
    ]
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)


def _check_count(name: str, value: int, minimum: int) -> int:
    if int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------------------------
# Shapes


def sphere(
    rings: int = 50,
    nodes_per_ring: int = 50,
    radius: float = 100.0,
    *,
    noise: NoiseParams = NoiseParams(),
    seed: int = 0,
) -> SyntheticDataset:
    """A robot circling a sphere ring by ring, as g2o's ``create_sphere`` (``sphere2500`` is 50 × 50).

    Pose ``k = f·N + j`` (ring ``f``, node ``j``, ``N = nodes_per_ring``) has rotation
    ``R = R_z(−π + 2πj/N) · R_y(−π/2 + (k+1)π/(rings·N))`` and position ``R · [radius, 0, 0]``:
    the latitude climbs a little at every step, so the rings form one spiral from pole to pole.
    Loop closures tie node ``j`` of ring ``f`` to nodes ``j−1, j, j+1`` (mod N) of ring ``f−1``,
    except the pair at each ring seam that is already an odometry edge: ``3N − 1`` per ring after
    the first.
    """
    L = _check_count("rings", rings, 1)
    N = _check_count("nodes_per_ring", nodes_per_ring, 3)
    k = np.arange(L * N)
    j = k % N
    rotation = _rotation_z(-np.pi + 2 * np.pi * j / N) @ _rotation_y(-0.5 * np.pi + (k + 1) * np.pi / (L * N))
    position = radius * rotation[:, :, 0]
    truth = se3.from_rotation_translation(rotation, position)
    ring_start = np.arange(L) * N
    candidates = _ring_neighbours(ring_start[:-1], ring_start[1:], N)
    rng = np.random.default_rng(seed)
    params = dict(shape="sphere", rings=L, nodes_per_ring=N, radius=radius, noise=noise, seed=seed)
    return _build(f"sphere_{L}x{N}", truth, candidates, noise, rng, params)


def torus(
    rings: int = 40,
    nodes_per_ring: int = 100,
    major_radius: float = 15.0,
    minor_radius: float = 5.0,
    *,
    noise: NoiseParams = NoiseParams(),
    seed: int = 0,
) -> SyntheticDataset:
    """A robot driving laps around a torus, each lap a little further round the tube.

    Pose ``k = f·N + j`` sits at major angle ``φ = 2πj/N`` and minor angle
    ``θ = 2πk/(rings·N)`` (a helix that covers the surface once), at
    ``((R + r cos θ) cos φ, (R + r cos θ) sin φ, r sin θ)``, facing along the lap (x axis) with z
    along the surface normal. Loop closures tie node ``j`` of lap ``f`` to nodes ``j−1, j, j+1``
    (mod N) of lap ``f−1``, and the last lap to the first, which closes the tube (minus the pair at
    each lap seam that is already an odometry edge: ``3N·rings − (rings − 1)`` in all).
    """
    L = _check_count("rings", rings, 2)
    N = _check_count("nodes_per_ring", nodes_per_ring, 3)
    if not 0 < minor_radius < major_radius:
        raise ValueError(f"need 0 < minor_radius < major_radius, got {minor_radius!r}, {major_radius!r}")
    k = np.arange(L * N)
    phi = 2 * np.pi * (k % N) / N
    theta = 2 * np.pi * k / (L * N)
    ring_radius = major_radius + minor_radius * np.cos(theta)
    position = np.stack([ring_radius * np.cos(phi), ring_radius * np.sin(phi), minor_radius * np.sin(theta)], axis=1)
    forward = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], axis=1)
    normal = np.stack([np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), np.sin(theta)], axis=1)
    truth = se3.from_rotation_translation(_frames_from_axes(forward, normal), position)
    ring_start = np.arange(L) * N
    candidates = np.concatenate(
        [
            _ring_neighbours(ring_start[:-1], ring_start[1:], N),
            # closing the tube: the first lap is the older one
            _ring_neighbours(ring_start[-1:], ring_start[:1], N)[:, ::-1],
        ]
    )
    rng = np.random.default_rng(seed)
    params = dict(
        shape="torus", rings=L, nodes_per_ring=N, major_radius=major_radius, minor_radius=minor_radius, noise=noise, seed=seed
    )
    return _build(f"torus_{L}x{N}", truth, candidates, noise, rng, params)


def grid(
    nx: int = 10,
    ny: int = 10,
    nz: int = 10,
    spacing: float = 1.0,
    *,
    random_orientation: bool = True,
    noise: NoiseParams = NoiseParams(),
    seed: int = 0,
) -> SyntheticDataset:
    """A robot visiting every point of an ``nx × ny × nz`` lattice in a snake (boustrophedon) path.

    Odometry follows the path (consecutive points are lattice neighbours); every other pair of
    lattice neighbours (6-connectivity) is a candidate loop closure, as in ``smallGrid3D``. With
    ``random_orientation`` each pose has a rotation uniform on SO(3) (``smallGrid3D`` does too),
    otherwise it faces along its direction of travel.
    """
    nx = _check_count("nx", nx, 1)
    ny = _check_count("ny", ny, 1)
    nz = _check_count("nz", nz, 1)
    # Snake path: rows along x, alternating direction with the global row number; rows snake in y
    # within a layer, alternating direction with the layer.
    z = np.repeat(np.arange(nz), ny * nx)
    y_in_layer = np.tile(np.repeat(np.arange(ny), nx), nz)
    y = np.where(z % 2 == 0, y_in_layer, ny - 1 - y_in_layer)
    row = z * ny + y_in_layer
    x_in_row = np.tile(np.arange(nx), ny * nz)
    x = np.where(row % 2 == 0, x_in_row, nx - 1 - x_in_row)
    n = nx * ny * nz
    position = spacing * np.stack([x, y, z], axis=1).astype(np.float64)

    rng = np.random.default_rng(seed)
    if random_orientation:
        rotation = _random_rotations(rng, n)
    else:
        step = np.diff(position, axis=0)
        forward = np.concatenate([step, step[-1:]]) if n > 1 else np.array([[1.0, 0, 0]])
        up = np.where(np.abs(forward[:, 2:3]) > 0.5 * spacing, np.array([[1.0, 0, 0]]), np.array([[0, 0, 1.0]]))
        rotation = _frames_from_axes(forward, up)
    truth = se3.from_rotation_translation(rotation, position)

    # Path index of every lattice point, then all neighbour pairs along each axis.
    index = np.empty((nx, ny, nz), np.int64)
    index[x, y, z] = np.arange(n)
    neighbours = np.concatenate(
        [
            np.stack([index[:-1, :, :].ravel(), index[1:, :, :].ravel()], axis=1),
            np.stack([index[:, :-1, :].ravel(), index[:, 1:, :].ravel()], axis=1),
            np.stack([index[:, :, :-1].ravel(), index[:, :, 1:].ravel()], axis=1),
        ]
    )
    neighbours = np.sort(neighbours, axis=1)
    candidates = neighbours[neighbours[:, 1] - neighbours[:, 0] > 1]
    candidates = candidates[np.lexsort((candidates[:, 0], candidates[:, 1]))]
    params = dict(shape="grid", nx=nx, ny=ny, nz=nz, spacing=spacing, random_orientation=random_orientation, noise=noise, seed=seed)
    return _build(f"grid_{nx}x{ny}x{nz}", truth, candidates, noise, rng, params)


def garage(
    floors: int = 4,
    laps_per_floor: int = 2,
    nodes_per_lap: int = 200,
    length: float = 60.0,
    width: float = 20.0,
    floor_height: float = 3.0,
    ramp_nodes: int = 12,
    lateral_jitter: float = 0.3,
    *,
    noise: NoiseParams = NoiseParams(),
    seed: int = 0,
) -> SyntheticDataset:
    """A car driving laps of a rectangular parking deck, floor after floor, up a ramp between floors.

    The path runs along the deck's ``length × width`` rectangle at a constant step
    (``perimeter / nodes_per_lap``), ``laps_per_floor`` times per floor, each lap shifted sideways
    by a random offset (uniform in ±``lateral_jitter``); between floors it climbs
    ``floor_height`` over ``ramp_nodes`` steps while following the same rectangle. The pose faces
    along the path and pitches with the ramp. Loop closures tie each node of a lap to the nodes
    ``−1, 0, +1`` steps along the previous lap on the same floor (less the pair at the lap seam,
    which is odometry) — a long, thin graph with few
    loop closures per pose, like ``parking-garage``. A long corridor is the same with a large
    ``length / width``.
    """
    F = _check_count("floors", floors, 1)
    laps = _check_count("laps_per_floor", laps_per_floor, 1)
    N = _check_count("nodes_per_lap", nodes_per_lap, 4)
    ramp = _check_count("ramp_nodes", ramp_nodes, 1) if F > 1 else 0
    if not (length > 0 and width > 0):
        raise ValueError("length and width must be positive")
    perimeter = 2.0 * (length + width)
    step = perimeter / N

    rng = np.random.default_rng(seed)
    s, z, lateral, lap_of = _garage_path(F, laps, N, ramp, step, floor_height, lateral_jitter, rng)
    climb = np.where(lap_of < 0, floor_height / max(ramp, 1), 0.0)
    truth = _on_rectangle(s % perimeter, z, lateral, climb, length, width, step)
    candidates = _lap_neighbours(lap_of, F, laps, N)
    params = dict(
        shape="garage",
        floors=F,
        laps_per_floor=laps,
        nodes_per_lap=N,
        length=length,
        width=width,
        floor_height=floor_height,
        ramp_nodes=ramp,
        lateral_jitter=lateral_jitter,
        noise=noise,
        seed=seed,
    )
    return _build(f"garage_{F}x{laps}x{N}", truth, candidates, noise, rng, params)


def _garage_path(F: int, laps: int, N: int, ramp: int, step: float, floor_height: float, jitter: float, rng) -> tuple:
    """``(arc length s, height z, lateral offset, lap index (−1 on ramps))`` per pose, ``(n,)`` each,
    in path order: each floor's laps, then (but for the last floor) its ramp; one random lateral
    offset per lap, uniform in ±``jitter``."""
    arc, height, offset, lap_id = [], [], [], []
    s0 = 0.0
    for f in range(F):
        for lap in range(laps):
            arc.append(s0 + step * np.arange(N))
            height.append(np.full(N, f * floor_height))
            offset.append(np.full(N, rng.uniform(-jitter, jitter)))
            lap_id.append(np.full(N, f * laps + lap))
        if f < F - 1:
            arc.append(s0 + step * np.arange(ramp))
            height.append(f * floor_height + floor_height * np.arange(ramp) / ramp)
            offset.append(np.zeros(ramp))
            lap_id.append(np.full(ramp, -1))
            s0 += step * ramp  # the next floor's laps start where the ramp ends
    return np.concatenate(arc), np.concatenate(height), np.concatenate(offset), np.concatenate(lap_id)


def _on_rectangle(s, z, lateral, climb, length: float, width: float, step: float) -> np.ndarray:
    """``(n, 4, 4)`` poses at arc length ``s`` along the rectangle (0,0) → (length,0) → (length,width)
    → (0,width) → (0,0), ``lateral`` to the left of travel (inwards), at height ``z``, facing along
    the path and pitched by ``climb`` per step."""
    corners = np.array([[0.0, 0.0], [length, 0.0], [length, width], [0.0, width]])
    directions = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    bounds = np.array([0.0, length, length + width, 2 * length + width])
    side = np.searchsorted(bounds, s, side="right") - 1
    along = s - bounds[side]
    xy = corners[side] + along[:, None] * directions[side]
    inward = np.stack([-directions[side, 1], directions[side, 0]], axis=1)  # left of travel = inside
    xy = xy + lateral[:, None] * inward
    position = np.concatenate([xy, z[:, None]], axis=1)
    forward = np.concatenate([directions[side] * step, climb[:, None]], axis=1)
    return se3.from_rotation_translation(_frames_from_axes(forward, np.tile([0.0, 0.0, 1.0], (len(s), 1))), position)


def _lap_neighbours(lap_of: np.ndarray, F: int, laps: int, N: int) -> np.ndarray:
    """Loop-closure candidates: lap l of a floor against lap l−1 of the same floor, offsets −1, 0, +1 (mod N)."""
    start_of_lap = np.flatnonzero(np.r_[True, lap_of[1:] != lap_of[:-1]])
    lap_starts = {int(lap_of[i]): int(i) for i in start_of_lap if lap_of[i] >= 0}
    older = [lap_starts[f * laps + lap - 1] for f in range(F) for lap in range(1, laps)]
    newer = [lap_starts[f * laps + lap] for f in range(F) for lap in range(1, laps)]
    return _ring_neighbours(np.array(older, np.int64), np.array(newer, np.int64), N)


def manhattan(
    steps: int = 3500,
    side: int | None = None,
    turn_probability: float = 0.3,
    noise: NoiseParams = NoiseParams(),
    seed: int = 0,
) -> SyntheticDataset:
    """A planar (SE(2)) robot walking the streets of a ``side × side`` lattice, like M3500 (Olson 2006).

    Each step moves one unit forward; before it the robot turns ±90° with probability
    ``turn_probability`` (either way alike). The walk is drawn without bounds, as cumulative sums,
    and folded into ``[0, side − 1]²`` by reflection (a triangle wave per axis): where it bounces off
    a wall the robot's heading stays as drawn, so that step is sideways or backwards, which the
    odometry measures like any other relative pose. Loop closures: each visit of a lattice cell with
    the cell's previous visit (non-consecutive poses), as a front end recognising the place would
    emit them. ``side`` defaults to ``√(steps/2)``: about two visits per cell, ~0.6 loop closures per
    pose (M3500 has 0.56). Every step is vectorised, so a million poses take about a second.
    """
    n = _check_count("steps", steps, 2)
    side = _check_count("side", side if side is not None else max(3, round((n / 2) ** 0.5)), 2)
    rng = np.random.default_rng(seed)
    turns = np.where(rng.random(n) < turn_probability, rng.choice([-1, 1], size=n), 0)
    turns[0] = 0
    heading = np.cumsum(turns) % 4  # in quarter turns
    step = np.stack([np.cos(heading * np.pi / 2), np.sin(heading * np.pi / 2)], axis=1).round()
    step[0] = 0.0
    unfolded = np.cumsum(step, axis=0).astype(np.int64)
    period = 2 * (side - 1)
    folded = (side - 1) - np.abs(unfolded % period - (side - 1))  # triangle wave into [0, side − 1]
    angles = np.where(heading > 2, heading - 4, heading) * (np.pi / 2)  # in (−π, π]
    truth = se2.from_rotation_translation(so2.from_angle(angles), folded.astype(np.float64))
    cell = folded[:, 0] * side + folded[:, 1]
    order = np.lexsort((np.arange(n), cell))  # by cell, then time
    same = cell[order][1:] == cell[order][:-1]
    candidates = np.stack([order[:-1][same], order[1:][same]], axis=1)
    params = dict(shape="manhattan", steps=n, side=side, turn_probability=turn_probability, noise=noise, seed=seed)
    return _build(f"manhattan_{n}", truth, candidates, noise, rng, params, group=SE2)


def monocular(
    laps: int = 10,
    nodes_per_lap: int = 250,
    radius: float = 50.0,
    *,
    noise: NoiseParams = NoiseParams(odometry_translation_sigma=0.02, loop_translation_sigma=0.02),
    seed: int = 0,
) -> SyntheticDataset:
    """A monocular camera's keyframes driving ``laps`` laps of a wavy loop: a Sim(3) graph with scale drift.

    As in monocular SLAM's essential graph (Strasdat et al., "Scale drift-aware large scale
    monocular SLAM", RSS 2010). The map's scale ``c_k`` random-walks, ``log c_{k+1} − log c_k ~
    N(0, odometry_scale_sigma²)``; keyframe ``k``'s true Sim(3) pose is ``[R_k / c_k, p_k]`` (true
    rotation and position, the map's local scale), so a relative pose measures a step in the
    local scale, ``c_k R_kᵀ (p_{k+1} − p_k)``. The odometry edges ``k → k+1`` measure no scale change
    (scale 1: the drift is their log-scale error, hence ``Ω_λλ = odometry_scale_sigma⁻²``), so the
    composed start is the drifted trajectory a monocular tracker reports; the loop closures, tying
    each keyframe to the three nearest of the previous lap, carry the true relative scale
    ``c_i / c_j`` (``σ = loop_scale_sigma``), as a Sim(3) loop detector measures it. Lap ``l`` node ``k``
    is at angle ``φ = 2πk/N`` on a circle of ``radius`` squashed to an ellipse (0.6 in y), height
    ``2 sin 3φ``, laps 0.5 m apart, facing along the path. The graph's group is
    :data:`~posegraph.lie.group.SIM3_G2O` (g2o's ``EDGE_SIM3`` cost); it is written as
    ``VERTEX_SIM3:EXPMAP`` / ``EDGE_SIM3:EXPMAP`` lines. ``ground_truth`` is ``[R_k / c_k, p_k]``: with
    each pose's scale applied (``eval``, ``export``), the true trajectory.
    """
    L = _check_count("laps", laps, 1)
    N = _check_count("nodes_per_lap", nodes_per_lap, 4)
    k = np.arange(L * N)
    phi = 2 * np.pi * (k % N) / N
    ring = radius + 0.5 * (k // N)
    position = np.stack([ring * np.cos(phi), 0.6 * ring * np.sin(phi), 2.0 * np.sin(3 * phi)], axis=1)
    forward = np.stack([-ring * np.sin(phi), 0.6 * ring * np.cos(phi), 6.0 * np.cos(3 * phi)], axis=1)
    rotation = _frames_from_axes(forward, np.broadcast_to([0.0, 0.0, 1.0], forward.shape))
    rng = np.random.default_rng(seed)
    drift = np.concatenate([[0.0], np.cumsum(rng.normal(scale=noise.odometry_scale_sigma, size=L * N - 1))])
    truth = se3.from_rotation_translation(rotation * np.exp(-drift)[:, None, None], position)  # [R / c, p]
    lap_start = np.arange(L) * N
    candidates = _ring_neighbours(lap_start[:-1], lap_start[1:], N)
    params = dict(shape="monocular", laps=L, nodes_per_lap=N, radius=radius, noise=noise, seed=seed)
    no_drift_noise = replace(noise, odometry_scale_sigma=1e-9)  # the drift is in the truth; odometry then drops scale
    dataset = _build(f"monocular_{L}x{N}", truth, candidates, no_drift_noise, rng, params, group=SIM3_G2O)
    return _odometry_without_scale(dataset, noise.odometry_scale_sigma)


def _odometry_without_scale(dataset: SyntheticDataset, drift_sigma: float) -> SyntheticDataset:
    """A monocular tracker's odometry: scale 1 on every odometry edge (its rotation block divided by its
    scale), ``Ω_λλ = drift_sigma⁻²``, and the start composed from those edges again."""
    graph, odometry = dataset.graph, dataset.odometry
    measurements, information = graph.measurements.copy(), graph.information.copy()
    block = measurements[odometry, :3, :3]
    measurements[odometry, :3, :3] = block / np.cbrt(np.linalg.det(block))[:, None, None]
    information[odometry, 6, 6] = _information(1.0, 1.0, graph.group, drift_sigma)[6, 6]
    chain = np.flatnonzero(odometry)[np.argsort(graph.edge_from[odometry])]  # edges k → k+1 in k order
    start = _compose_chain(dataset.ground_truth[0], measurements[chain])
    return replace(dataset, graph=replace(graph, poses=start, measurements=measurements, information=information))


SHAPES = {"sphere": sphere, "torus": torus, "grid": grid, "garage": garage, "manhattan": manhattan, "monocular": monocular}


def shape_arguments(shape: str, size: int) -> dict:
    """Shape parameters for about ``size`` poses (the exact count is in the result)."""
    size = _check_count("size", size, 8)
    if shape == "sphere":
        side = max(3, round(size**0.5))
        return dict(rings=side, nodes_per_ring=side)
    if shape == "torus":
        rings = max(2, round((size / 2.5) ** 0.5))  # laps : nodes per lap = 1 : 2.5 as the defaults
        return dict(rings=rings, nodes_per_ring=max(3, round(size / rings)))
    if shape == "grid":
        side = max(2, round(size ** (1 / 3)))
        return dict(nx=side, ny=side, nz=max(1, round(size / side**2)))
    if shape == "manhattan":
        return dict(steps=size)
    if shape == "monocular":
        laps = max(1, round((size / 25) ** 0.5))  # 10 laps of 250 for 2,500
        return dict(laps=laps, nodes_per_lap=max(4, round(size / laps)))
    if shape == "garage":
        floors, laps, ramp = 4, 2, 12
        return dict(floors=floors, laps_per_floor=laps, ramp_nodes=ramp, nodes_per_lap=max(4, round((size - (floors - 1) * ramp) / (floors * laps))))
    raise ValueError(f"unknown shape {shape!r}; one of {sorted(SHAPES)}")


def generate(shape: str, size: int | None = None, *, noise: NoiseParams = NoiseParams(), seed: int = 0, **shape_kwargs) -> SyntheticDataset:
    """One of :data:`SHAPES` by name; ``size`` (about that many poses) sets its shape parameters,
    which ``shape_kwargs`` may override."""
    if shape not in SHAPES:
        raise ValueError(f"unknown shape {shape!r}; one of {sorted(SHAPES)}")
    arguments = shape_arguments(shape, size) if size is not None else {}
    arguments.update(shape_kwargs)
    return SHAPES[shape](**arguments, noise=noise, seed=seed)


# --------------------------------------------------------------------------------------------
# Random outliers in any graph


def random_relative_poses(rng: np.random.Generator, count: int, translation_range: float) -> np.ndarray:
    """``(count, 4, 4)`` poses: rotation uniform on SO(3), translation uniform in ``[−r, r]³``."""
    translation = rng.uniform(-translation_range, translation_range, size=(count, 3))
    return se3.from_rotation_translation(_random_rotations(rng, count), translation)


def _random_poses(rng: np.random.Generator, count: int, translation_range: float, group: LieGroup) -> np.ndarray:
    """``(count, k, k)`` poses of ``group``: rotation uniform (on SO(3), or an angle in [−π, π)),
    then translation uniform in ``[−r, r]`` per axis (drawn in that order)."""
    if group.matrix_size == 3:
        rotations = so2.from_angle(rng.uniform(-np.pi, np.pi, count))
        return se2.from_rotation_translation(rotations, rng.uniform(-translation_range, translation_range, (count, 2)))
    rotations = _random_rotations(rng, count)
    return se3.from_rotation_translation(rotations, rng.uniform(-translation_range, translation_range, (count, 3)))


def _free_pairs(rng: np.random.Generator, graph: PoseGraph, count: int) -> np.ndarray:
    """``(count, 2)`` distinct vertex pairs (older, newer by id), none an edge of ``graph`` nor
    neighbours in id order (those are odometry), in the order drawn."""
    n = graph.num_vertices
    rank = vertex_ranks(graph)
    by_rank = np.argsort(graph.ids, kind="stable")
    taken = np.unique(np.sort(np.stack([rank[graph.edge_from], rank[graph.edge_to]], 1), axis=1) @ np.array([n, 1]))
    taken_older, taken_newer = np.divmod(taken, n)
    free = n * (n - 1) // 2 - max(n - 1, 0) - np.count_nonzero(taken_newer - taken_older > 1)
    if count > free:
        raise ValueError(f"{count} outliers asked but only {free} vertex pairs are free")
    codes = np.zeros(0, np.int64)
    while len(codes) < count:
        draw = np.sort(rng.integers(0, n, size=(2 * count + 8, 2)), axis=1)
        draw = draw[draw[:, 1] - draw[:, 0] > 1] @ np.array([n, 1])
        merged = np.concatenate([codes, draw[~np.isin(draw, taken)]])
        _, first = np.unique(merged, return_index=True)
        codes = merged[np.sort(first)][:count]
    older, newer = np.divmod(codes, n)
    return np.stack([by_rank[older], by_rank[newer]], axis=1)


def _parallel_edges(rng: np.random.Generator, graph: PoseGraph, on_odometry: int, on_loop_closures: int) -> np.ndarray:
    """Indices of ``on_odometry`` distinct odometry edges and ``on_loop_closures`` distinct loop
    closures of ``graph`` (:meth:`PoseGraph.odometry_mask`), drawn at random, for outliers parallel to them."""
    odometry = graph.odometry_mask()
    chosen = []
    for pool, k in ((np.flatnonzero(odometry), on_odometry), (np.flatnonzero(~odometry), on_loop_closures)):
        if k > len(pool):
            raise ValueError(f"{k} parallel outliers asked but the graph has only {len(pool)} such edges")
        chosen.append(rng.choice(pool, size=k, replace=False) if k else np.zeros(0, np.int64))  # k = 0 draws nothing
    return np.concatenate(chosen).astype(np.int64)


def _front_end_positions(graph: PoseGraph, pairs: np.ndarray) -> np.ndarray:
    """``(k,)`` insertion positions (into the original edge order) of edges joining ``pairs``: after
    the last original edge whose newer vertex (by id) comes no later than the pair's newer one."""
    ids = graph.ids
    newest_so_far = np.maximum.accumulate(np.maximum(ids[graph.edge_from], ids[graph.edge_to])) if graph.num_edges else np.zeros(0, np.int64)
    return np.searchsorted(newest_so_far, np.maximum(ids[pairs[:, 0]], ids[pairs[:, 1]]), side="right")


def inject_outliers(
    graph: PoseGraph,
    *,
    count: int | None = None,
    fraction: float | None = None,
    seed: int = 0,
    translation_range: float | None = None,
    on_odometry: int = 0,
    on_loop_closures: int = 0,
    wrong_first: bool = False,
) -> tuple[PoseGraph, np.ndarray]:
    """``graph`` plus random wrong loop closures; returns the new graph and their edge indices.

    ``count`` outliers, or ``fraction`` × the graph's loop closures (edges that are not odometry,
    :meth:`PoseGraph.odometry_mask`): sphere2500's 2,449 loop closures at 0.2 give 490. Each joins a
    random pair of vertices that are neither neighbours in id order nor already joined, measures a
    :func:`random_relative_poses` pose (``translation_range`` default: half the diagonal of the
    bounding box of the graph's positions, at least 1) and carries the information of a random
    loop closure of the graph (of a random edge if it has none), so it looks like one. Each is
    inserted after the last edge whose newer vertex comes no later (by id) than its own, the
    order a front end emits edges in; the original edges keep their order. Returns
    ``(graph, indices)`` with ``indices`` ``(count,)`` sorted 0-based positions of the outliers
    in the new graph's edge order, which is its g2o file's edge-line order.

    Of the ``count`` outliers, ``on_odometry`` join a random odometry pair (neighbours in id order)
    and ``on_loop_closures`` the two vertices of a random loop closure, each parallel to the edge
    already there (as a front end's duplicate or false match between consecutive frames); the rest
    join free pairs as above. A parallel outlier follows the edge it duplicates in edge order, or,
    with ``wrong_first``, precedes it (the front end emitted the wrong one first).
    """
    loops = np.flatnonzero(~graph.odometry_mask())
    count = _outlier_count(count, fraction, len(loops))
    parallel = _check_count("on_odometry", on_odometry, 0) + _check_count("on_loop_closures", on_loop_closures, 0)
    if parallel > count:
        raise ValueError(f"on_odometry + on_loop_closures = {parallel} exceeds the {count} outliers")
    rng = np.random.default_rng(seed)
    pairs = _free_pairs(rng, graph, count - parallel)
    duplicated = _parallel_edges(rng, graph, on_odometry, on_loop_closures)
    pairs = np.concatenate([pairs, np.stack([graph.edge_from[duplicated], graph.edge_to[duplicated]], axis=1)])
    measurements = _outlier_measurements(rng, graph, count, translation_range)
    donors = rng.choice(loops if len(loops) else np.arange(graph.num_edges), size=count)

    positions = _front_end_positions(graph, pairs)
    if wrong_first:
        positions[count - parallel:] = duplicated
    order = np.lexsort((graph.ids[pairs].max(axis=1), positions))  # by position, then newer id, then as drawn
    return _insert_edges(graph, positions[order], pairs[order], measurements[order], graph.information[donors[order]])


def _outlier_count(count: int | None, fraction: float | None, loop_closures: int) -> int:
    """``count``, or ``fraction`` × ``loop_closures`` rounded; exactly one of the two is given."""
    if (count is None) == (fraction is None):
        raise ValueError("give exactly one of count and fraction")
    if fraction is not None:
        if not (np.isfinite(fraction) and fraction >= 0):
            raise ValueError(f"fraction must be a number >= 0, got {fraction!r}")
        count = int(round(fraction * loop_closures))
    return _check_count("count", count, 0)


def _outlier_measurements(rng: np.random.Generator, graph: PoseGraph, count: int, translation_range: float | None) -> np.ndarray:
    """``(count, k, k)`` random measurements in ``graph``'s group; ``translation_range`` default: half
    the diagonal of the bounding box of the graph's positions, at least 1."""
    if translation_range is None:
        positions = graph.poses[:, :-1, -1]  # (n, 3) or, for SE(2), (n, 2)
        translation_range = max(1.0, 0.5 * float(np.linalg.norm(np.ptp(positions, axis=0)))) if len(positions) else 1.0
    if graph.group.matrix_size == 3:  # SE(2): a random angle and planar translation
        return _random_poses(rng, count, translation_range, graph.group)
    return random_relative_poses(rng, count, translation_range)  # SE(3): same seed, same outliers as always


def _insert_edges(graph: PoseGraph, positions, pairs, measurements, information) -> tuple[PoseGraph, np.ndarray]:
    """``graph`` with edge ``k`` (``pairs[k]``, ``measurements[k]``, ``information[k]``) inserted
    before original edge ``positions[k]`` (sorted); returns it and the new edges' indices in it."""
    count = len(positions)
    indices = positions + np.arange(count)
    keep = np.ones(graph.num_edges + count, bool)
    keep[indices] = False

    def merged(original: np.ndarray, added: np.ndarray) -> np.ndarray:
        out = np.empty((graph.num_edges + count,) + original.shape[1:], dtype=original.dtype)
        out[keep], out[indices] = original, added
        return out

    injected = replace(
        graph,
        edge_from=merged(graph.edge_from, pairs[:, 0]),
        edge_to=merged(graph.edge_to, pairs[:, 1]),
        measurements=merged(graph.measurements, measurements),
        information=merged(graph.information, information),
        edge_source=None,
        edge_lines=None,  # the injected edges have no line in any file
    )
    return injected, indices

# --------------------------------------------------------------------------------------------
# Landmark graphs: poses and points (posegraph.model.landmarks)

LANDMARK_TAGS = {
    ("position", 2): "EDGE_SE2_XY", ("position", 3): "EDGE_SE3_TRACKXYZ", ("bearing", 2): "EDGE_BEARING_SE2_XY",
    ("bearing_range", 2): "BR", ("prior", 2): "EDGE_PRIOR_XY", ("prior", 3): "EDGE_PRIOR_XYZ",
}  # fmt: skip
"""File tag of each ``(kind, space dimension)`` the generator writes into :attr:`Observations.tag`."""


def _landmark_truth(group: LieGroup, num_poses: int, num_landmarks: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """True poses ``(n, k, k)``, a random walk from the identity (steps of ~1 m, ~0.3 rad), and points
    ``(L, s)``, each at 2–6 m in front of a random pose (a cone of ±60° about its x axis)."""
    scale = np.full(group.dim, 0.3)
    scale[list(group.translation_axes)] = 0.2
    tangent = rng.normal(size=(num_poses - 1, group.dim)) * scale
    tangent[:, group.translation_axes[0]] += 1.0
    truth = _compose_chain(np.eye(group.matrix_size), group.exp(tangent))
    s = group.space_dim
    direction = np.concatenate([np.ones((num_landmarks, 1)), rng.uniform(-1.5, 1.5, (num_landmarks, s - 1))], axis=1)
    body = direction / np.linalg.norm(direction, axis=1, keepdims=True) * rng.uniform(2.0, 6.0, (num_landmarks, 1))
    seer = truth[rng.integers(0, num_poses, num_landmarks)]
    return truth, np.einsum("lij,lj->li", seer[:, :s, :s], body) + seer[:, :s, s]


def _landmark_family(group, kind, truth, points, per_landmark, noise, offsets, rng):
    """One :class:`Observations` family of ``kind``: ``per_landmark`` distinct poses per landmark (one
    prior per landmark), measurements predicted at the truth plus ``N(0, noise²)`` per row, Ω = I/σ²
    (σ = ``noise``, or 1 for exact measurements when ``noise`` is 0)."""
    from posegraph.model.landmarks import Observations, measurement_size
    from posegraph.solve.landmark_residuals import landmark_residuals

    n, L, s = len(truth), len(points), group.space_dim
    r = measurement_size(kind, s)
    if kind == "prior":
        pose, landmark = np.full(L, -1, np.int64), np.arange(L, dtype=np.int64)
    else:
        count = min(per_landmark, n)
        pose = np.argsort(rng.random((L, n)), axis=1)[:, :count].reshape(-1).astype(np.int64)  # distinct per landmark
        landmark = np.repeat(np.arange(L, dtype=np.int64), count)
    q = len(landmark)
    O = group.exp(rng.normal(scale=0.3, size=(q, group.dim))) if offsets and kind == "position" else None
    zero = Observations(kind, pose, landmark, np.zeros((q, r)), np.zeros((q, r, r)), O)
    z = landmark_residuals(group, truth, points, zero) + noise * rng.standard_normal((q, r))  # predicted − 0
    information = np.broadcast_to(np.eye(r) / (noise**2 if noise > 0 else 1.0), (q, r, r)).copy()
    return Observations(kind, pose, landmark, z, information, O, tag=LANDMARK_TAGS[(kind, s)])


def landmark_graph(
    group: LieGroup = SE2,
    num_poses: int = 10,
    num_landmarks: int = 8,
    kinds=("position",),
    noise: float = 0.01,
    seed: int = 0,
    *,
    per_landmark: int = 3,
    offsets: bool = False,
) -> tuple[PoseGraph, np.ndarray, np.ndarray]:
    """A small landmark graph with its ground truth: ``(graph, truth_poses (n, k, k), truth_points (L, s))``.

    The poses walk from the identity (:func:`_landmark_truth`); the pose edges are the odometry chain
    ``k → k+1``, ``Z = X_k⁻¹X_{k+1}·Exp(δ)`` with ``δ ~ N(0, noise² I)`` and Ω = I/σ²; each kind of
    ``kinds`` (:data:`posegraph.model.landmarks.KINDS`; ``"bearing"`` and ``"bearing_range"`` need SE(2))
    is one family in which every landmark is seen from ``per_landmark`` distinct random poses (a
    ``"prior"`` family: one prior per landmark), measured as predicted at the truth plus
    ``N(0, noise²)`` per row (angles too, in radians), Ω = I/σ². ``offsets``: the ``"position"``
    family gets random sensor offsets. ``noise = 0``: exact measurements and unit information.

    Initial values: the poses are the noisy odometry composed from the true first pose; the landmark
    positions are the truth plus ``N(0, (10·noise)²)`` per coordinate (exactly the truth when
    ``noise = 0``). No pose or landmark is fixed (the first pose anchors the gauge, as in
    :func:`posegraph.model.graph.component_anchors`). Same arguments, same graph.
    """
    from posegraph.model.landmarks import Landmarks

    n, L = _check_count("num_poses", num_poses, 2), _check_count("num_landmarks", num_landmarks, 1)
    rng = np.random.default_rng(seed)
    truth, points = _landmark_truth(group, n, L, rng)
    exact = group.between(truth[:-1], truth[1:])
    steps = exact @ group.exp(noise * rng.standard_normal((n - 1, group.dim)))
    information = np.broadcast_to(np.eye(group.dim) / (noise**2 if noise > 0 else 1.0), (n - 1, group.dim, group.dim))
    families = tuple(_landmark_family(group, kind, truth, points, per_landmark, noise, offsets, rng) for kind in kinds)
    initial_points = points + 10.0 * noise * rng.standard_normal(points.shape)
    landmarks = Landmarks(
        ids=np.arange(n, n + L, dtype=np.int64), positions=initial_points, observations=families,
        vertex_tag="VERTEX_XY" if group.space_dim == 2 else "VERTEX_TRACKXYZ",
    )  # fmt: skip
    graph = PoseGraph(
        ids=np.arange(n, dtype=np.int64), poses=_compose_chain(truth[0], steps), edge_from=np.arange(n - 1, dtype=np.int64),
        edge_to=np.arange(1, n, dtype=np.int64), measurements=steps, information=information.copy(), group=group,
        landmarks=landmarks,
    )  # fmt: skip
    return graph, truth, points


# --------------------------------------------------------------------------------------------
# Files



def groundtruth_path(path: str | Path) -> Path:
    """``dir/name.g2o`` → ``dir/name_groundtruth.g2o`` (the naming of gtsam's example data)."""
    path = Path(path)
    return path.with_name(f"{path.stem}_groundtruth{path.suffix or '.g2o'}")


def outliers_path(path: str | Path) -> Path:
    """``dir/name.g2o`` → ``dir/name.outliers.txt``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.outliers.txt")


def write_outlier_indices(path: str | Path, indices: np.ndarray, graph_name: str) -> None:
    """Write the 0-based outlier edge indices, one per line, after a ``#`` comment naming the graph."""
    lines = [
        f"# 0-based indices of the {len(indices)} outlier edges of {graph_name}, in its edge-line order",
        *(str(int(k)) for k in np.sort(np.asarray(indices, dtype=np.int64))),
    ]
    Path(path).write_text("\n".join(lines) + "\n")


def read_outlier_indices(path: str | Path) -> np.ndarray:
    """``(k,)`` int64 indices written by :func:`write_outlier_indices`."""
    return np.atleast_1d(np.loadtxt(path, dtype=np.int64, comments="#", ndmin=1))


def _check_outputs(*paths: Path) -> None:
    from posegraph.errors import OutputError

    resolved = [p.resolve() for p in paths]
    if len(set(resolved)) < len(resolved):
        raise OutputError("two outputs would be the same file: give other names", str(paths[0]))
    for target in paths:
        if not target.resolve().parent.is_dir():
            raise OutputError(f"the output folder {target.resolve().parent} does not exist", str(target))


def write_injected(path: str | Path, graph: PoseGraph, indices: np.ndarray, source: str | Path | None = None) -> tuple[Path, Path]:
    """Write a graph from :func:`inject_outliers` to ``path`` and its outlier indices to
    :func:`outliers_path` (both or neither); ``source``, the file it was read from, is never
    overwritten. Returns both paths."""
    from posegraph.io.atomic import StagedOutputs
    from posegraph.errors import OutputError
    from posegraph.io.g2o import write_g2o

    path = Path(path)
    if source is not None and path.resolve() == Path(source).resolve():
        raise OutputError("the output would overwrite the input graph: give another -o", str(path))
    indices_path = outliers_path(path)
    _check_outputs(path, indices_path)
    with StagedOutputs() as outputs:
        write_g2o(outputs.stage(path), graph)
        write_outlier_indices(outputs.stage(indices_path), indices, path.name)
        outputs.commit()
    return path, indices_path


def write_dataset(path: str | Path, dataset: SyntheticDataset, groundtruth: str | Path | None = None) -> tuple[Path, Path]:
    """Write the noisy graph to ``path`` and the same graph with its vertices at the ground truth
    to ``groundtruth`` (default :func:`groundtruth_path`); when the graph has outliers, their
    indices to :func:`outliers_path`. Returns the first two paths."""
    from posegraph.io.atomic import StagedOutputs
    from posegraph.errors import OutputError
    from posegraph.io.g2o import write_g2o

    path = Path(path)
    truth_path = Path(groundtruth) if groundtruth is not None else groundtruth_path(path)
    if path.resolve() == truth_path.resolve():
        raise OutputError("the ground truth would overwrite the graph: give another --groundtruth", str(path))
    outputs_list = [path, truth_path] + ([outliers_path(path)] if dataset.outliers.any() else [])
    _check_outputs(*outputs_list)
    # All files appear together or not at all.
    with StagedOutputs() as outputs:
        write_g2o(outputs.stage(path), dataset.graph)
        write_g2o(outputs.stage(truth_path), dataset.graph, dataset.ground_truth)
        if dataset.outliers.any():
            write_outlier_indices(outputs.stage(outliers_path(path)), np.flatnonzero(dataset.outliers), path.name)
        outputs.commit()
    return path, truth_path


# --------------------------------------------------------------------------------------------
# Command line


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m datasets.synthetic",
        description="Write a synthetic 3D pose graph (g2o) and its ground truth (NAME_groundtruth.g2o); "
        "with outliers, also NAME.outliers.txt. 'python -m datasets.synthetic inject -h': add outliers to a g2o file.",
    )
    parser.add_argument("shape", choices=sorted(SHAPES), help="sphere (as g2o's create_sphere), torus, grid (3D lattice), garage (multi-floor laps), "
                        "manhattan (2D: a walk on a street lattice, like M3500)")
    parser.add_argument("--size", type=int, default=None, help="about this many poses (default: the shape's defaults, e.g. sphere 50×50)")
    parser.add_argument("-o", "--output", required=True, help="output g2o file; the ground truth goes next to it")
    parser.add_argument("--groundtruth", default=None, help="ground-truth file (default: OUTPUT with _groundtruth before the suffix)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    default = NoiseParams()
    parser.add_argument(
        "--odometry-noise", nargs=2, type=float, metavar=("ROT", "TRANS"),
        default=(default.odometry_rotation_sigma, default.odometry_translation_sigma),
        help="odometry σ: rotation (rad), translation (m) (default %(default)s)",
    )
    parser.add_argument(
        "--loop-noise", nargs=2, type=float, metavar=("ROT", "TRANS"),
        default=(default.loop_rotation_sigma, default.loop_translation_sigma),
        help="loop-closure σ: rotation (rad), translation (m) (default %(default)s)",
    )
    parser.add_argument("--loop-density", type=float, default=1.0, help="fraction of candidate loop closures kept (default 1)")
    parser.add_argument("--outliers", type=float, default=0.0, help="fraction of loop closures that are outliers (default 0)")
    parser.add_argument("--noiseless", action="store_true", help="exact measurements (the ground truth is then the optimum)")
    return parser


def _inject_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m datasets.synthetic inject",
        description="Add random wrong loop closures to a g2o graph; writes OUTPUT and OUTPUT.outliers.txt "
        "(the 0-based edge-line indices of the added edges).",
    )
    parser.add_argument("input", help="g2o file to add outliers to (never overwritten)")
    parser.add_argument("-o", "--output", required=True, help="output g2o file; NAME.outliers.txt goes next to it")
    how_many = parser.add_mutually_exclusive_group(required=True)
    how_many.add_argument("--fraction", type=float, help="outliers per loop closure of the input (e.g. 0.2)")
    how_many.add_argument("--count", type=int, help="number of outliers")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--translation-range", type=float, default=None, help="outlier translations uniform in ±this per axis (default: half the graph's bounding-box diagonal)")
    parser.add_argument("--on-odometry", type=int, default=0, metavar="K",
                        help="K of the outliers parallel to random odometry edges (between consecutive vertices; default 0)")
    parser.add_argument("--on-loop-closures", type=int, default=0, metavar="K",
                        help="K of the outliers parallel to random loop closures (default 0)")
    parser.add_argument("--wrong-first", action="store_true",
                        help="each parallel outlier precedes the edge it duplicates (default: follows it)")
    return parser


def inject_main(argv: list[str]) -> int:
    """``python -m datasets.synthetic inject IN -o OUT (--fraction F | --count N) [--seed S] [--on-odometry K]
    [--on-loop-closures K] [--wrong-first]``."""
    parser = _inject_parser()
    args = parser.parse_args(argv)
    from posegraph.errors import InputError
    from posegraph.io.g2o import read_g2o

    try:
        graph = read_g2o(args.input)
        injected, indices = inject_outliers(
            graph, count=args.count, fraction=args.fraction, seed=args.seed, translation_range=args.translation_range,
            on_odometry=args.on_odometry, on_loop_closures=args.on_loop_closures, wrong_first=args.wrong_first,
        )  # fmt: skip
        path, indices_path = write_injected(args.output, injected, indices, source=args.input)
    except (InputError, OSError) as error:  # InputError is a ValueError: caught first
        print(f"error: {error}", file=sys.stderr)
        return 1
    except ValueError as error:
        parser.error(str(error))
    print(f"{args.input}: {graph.num_edges} edges + {len(indices)} outliers -> {path}, {indices_path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["inject"]:
        return inject_main(argv[1:])
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        noise = NoiseParams(
            odometry_rotation_sigma=args.odometry_noise[0],
            odometry_translation_sigma=args.odometry_noise[1],
            loop_rotation_sigma=args.loop_noise[0],
            loop_translation_sigma=args.loop_noise[1],
            loop_closure_density=args.loop_density,
            outlier_fraction=args.outliers,
            noiseless=args.noiseless,
        )
        dataset = generate(args.shape, args.size, noise=noise, seed=args.seed)
    except ValueError as error:
        parser.error(str(error))
    from posegraph.errors import InputError

    try:
        path, truth_path = write_dataset(args.output, dataset, args.groundtruth)
    except (InputError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    graph = dataset.graph
    print(
        f"{dataset.name}: {graph.num_vertices} poses, {graph.num_edges} edges "
        f"({dataset.num_loop_closures} loop closures, {int(dataset.outliers.sum())} outliers) -> {path}, {truth_path}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
