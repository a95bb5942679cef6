"""Small pose graphs for the certification tests: a random walk with loop closures, isotropic
information, exact or noisy measurements (noise drawn per edge in the tangent space)."""

from __future__ import annotations

import dataclasses

import numpy as np

from posegraph.lie.group import SE3
from tests.init.synthetic import build_graph, loop_graph_edges, trajectory


def isotropic_information(count: int, rotation_sigma: float, translation_sigma: float, group=SE3) -> np.ndarray:
    """``(count, D, D)`` diagonal information ``1/σ²`` on the rotation and translation axes."""
    information = np.zeros((count, group.dim, group.dim))
    rot, tra = np.array(group.rotation_axes), np.array(group.translation_axes)
    information[:, rot, rot] = 1.0 / rotation_sigma**2
    information[:, tra, tra] = 1.0 / translation_sigma**2
    return information


def loop_graph(seed: int, n: int = 12, loops: int = 8, rotation_noise: float = 0.0, translation_noise: float = 0.0,
               group=SE3):  # fmt: skip
    """``(graph, truth)``: ``n`` poses, ``loops`` loop closures, measurements ``Z Exp(ε)`` with ε's rotation
    part ~ N(0, rotation_noise²) and translation part ~ N(0, translation_noise²) (0: exact); the
    information says σ = 0.1 rad and 0.1 m whatever the noise is."""
    rng = np.random.default_rng(seed)
    truth = trajectory(rng, n, group=group)
    edge_from, edge_to = loop_graph_edges(rng, n, loops)
    information = isotropic_information(edge_from.size, 0.1, 0.1, group)
    graph = build_graph(truth, edge_from, edge_to, information, rng=rng, group=group)
    if rotation_noise or translation_noise:
        sigma = np.zeros(group.dim)
        sigma[list(group.rotation_axes)] = rotation_noise
        sigma[list(group.translation_axes)] = translation_noise
        noisy = graph.measurements @ group.exp(sigma * rng.normal(size=(edge_from.size, group.dim)))
        graph = dataclasses.replace(graph, measurements=noisy)
    return graph, truth

