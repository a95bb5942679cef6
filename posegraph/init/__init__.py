"""Initial poses for the solver: from the file, along a spanning tree, or by chordal relaxation.

Gauss-Newton and Levenberg-Marquardt only find the optimum from a good start. Three starts:

* ``"file"`` — the poses as read (:func:`file_initialization`);
* ``"odometry"`` — measurements composed along a spanning tree from each component's held vertex
  (:func:`posegraph.init.odometry.odometry_initialization`);
* ``"chordal"`` (default) — rotations by the chordal relaxation, then the translations minimising
  the cost given them (:func:`posegraph.init.chordal.chordal_initialization`).

Every method keeps fixed vertices and each unfixed component's anchor at their file pose
(:func:`posegraph.model.graph.held_vertices`), as the solver does. ``docs/initialisation.md`` explains the weight
choices and records measured costs and timings against gtsam's ``InitializePose3``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.model.graph import PoseGraph
from posegraph.init.chordal import chordal_initialization, chordal_rotations, translations_given_rotations
from posegraph.model.graph import held_vertices
from posegraph.linalg.heap import release_free_memory
from posegraph.init.odometry import odometry_initialization, spanning_tree

__all__ = [
    "METHODS",
    "initialize",
    "file_initialization",
    "odometry_initialization",
    "chordal_initialization",
    "chordal_rotations",
    "translations_given_rotations",
    "spanning_tree",
    "held_vertices",
]

METHODS = ("chordal", "odometry", "file")


def file_initialization(graph: PoseGraph) -> np.ndarray:
    """``(n, k, k)`` — a copy of the poses as read."""
    return np.array(graph.poses, dtype=np.float64, copy=True)


def initialize(graph: PoseGraph, method: str = "chordal", **options) -> np.ndarray:
    """Initial poses ``(n, k, k)`` (``k = graph.group.matrix_size``) for ``graph`` by ``method`` (``"chordal"``, ``"odometry"``, ``"file"``).

    A landmark graph's chordal start is the relaxation over poses and points together
    (:func:`posegraph.init.relaxation.relaxed_start`; with priors, or when that system is singular,
    and for ``"odometry"``: the pose edges alone, each component of them anchored as in a pose graph);
    :func:`posegraph.init.landmarks.initialize_landmarks` then places the landmarks.

    ``options`` go to the method's function: ``linear_solver=`` for ``"chordal"``, ``tree=`` for
    ``"odometry"``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if graph.landmarks is not None and method != "file":
        return _landmark_graph_start(graph, method, options)
    if graph.num_vertices == 0:
        k = graph.group.matrix_size
        return np.zeros((0, k, k))
    if method == "file":
        if options:
            raise TypeError(f"method 'file' takes no options, got {sorted(options)}")
        return file_initialization(graph)
    if method == "odometry":
        return odometry_initialization(graph, **options)
    poses = chordal_initialization(graph, **options)
    release_free_memory()  # its systems' pages, which the solver's large arrays would not reuse
    return poses


def _landmark_graph_start(graph: PoseGraph, method: str, options: dict) -> np.ndarray:
    """A landmark graph's poses: the relaxation with its landmarks (``"chordal"``, no priors), else the
    start of its pose edges alone (:func:`initialize`'s docstring)."""
    from posegraph.init.relaxation import MAX_ENTRIES, relaxation_entries, relaxed_start

    # (linear_solver: the relaxation solves by CHOLMOD, or SuperLU without cvxopt)
    if method == "chordal" and graph.priors is None and set(options) <= {"linear_solver"} and relaxation_entries(graph) <= MAX_ENTRIES:
        from posegraph.linalg.cholmod import NotPositiveDefiniteError

        try:
            return relaxed_start(graph)
        except NotPositiveDefiniteError:
            pass  # a pose or point its linear terms do not fix: the pose edges' start, as below
    return initialize(replace(graph, landmarks=None), method, **options)


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
