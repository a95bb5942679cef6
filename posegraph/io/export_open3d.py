"""Export a pose graph to Open3D: a ``PoseGraph`` JSON file and a trajectory ``LineSet`` PLY.

Open3D (``pip install open3d`` or ``pip install "posegraph[open3d]"``; on Debian/Ubuntu its wheel
also needs ``apt install libusb-1.0-0``) is imported only inside these functions.

Mapping to ``open3d.pipelines.registration.PoseGraph``
------------------------------------------------------
* Node ``k`` is our vertex ``k`` (file order) with ``pose = X_k`` (world-from-body, as ours).
  Open3D nodes carry no id: the vertex ids are the node order, listed in ``ids`` if needed.
* Open3D's edge ``(source s, target t, T, Ω)`` states ``T ≈ P_t⁻¹ P_s`` (T moves points of s into
  the frame of t) and its global optimisation scores ``Log(T⁻¹ P_t⁻¹ P_s)`` in ``[rotation;
  translation]`` order with Ω. Our edge ``i → j`` states ``Z ≈ X_i⁻¹ X_j`` and scores
  ``Log(Z⁻¹ X_i⁻¹ X_j)`` in ``[ω; v]`` order, so it is exported as ``source = j``, ``target = i``,
  ``T = Z``, ``information = Ω`` unchanged: the same residual in the same order.
* ``uncertain`` is False for every edge by default: a g2o file has no notion of an uncertain
  edge, and Open3D's line process prunes uncertain edges that disagree with the current poses —
  on smallGrid3D it drops most loop closures and ends at a cost 170 times the optimum
  (``docs/interop.md``). ``uncertain_loop_closures=True`` marks loop closures (not odometry,
  :meth:`~posegraph.model.graph.PoseGraph.odometry_mask`) uncertain, as Open3D's multiway-registration
  tutorial does for loop closures found by registration.

2D graphs (SE(2) poses ``(n, 3, 3)``, information ``(m, 3, 3)`` in ``[v_x, v_y, ω]`` order) are
embedded at ``z = 0`` (:func:`posegraph.lie.se2.to_se3`): ``v_x, v_y, ω`` become Open3D's ``x, y``
and rotation about ``z``, and the three out-of-plane directions (rotation about x and y,
translation along z) get the largest diagonal entry of the edge's in-plane information, so that
Open3D's optimiser keeps a planar graph planar (a zero there would leave its system singular).
"""

from __future__ import annotations

import os

import numpy as np

from posegraph.io.atomic import atomic_path
from posegraph.lie import se2

__all__ = [
    "require_open3d",
    "embed_information_2d",
    "to_open3d_pose_graph",
    "write_open3d_pose_graph",
    "trajectory_line_set",
    "write_trajectory_ply",
]

INSTALL_HINT = (
    'pip install open3d (or pip install "posegraph[open3d]"); '
    "on Debian/Ubuntu also: apt install libusb-1.0-0"
)


def require_open3d():
    """Import and return ``open3d``, or raise ImportError with the install command."""
    try:
        import open3d
    except Exception as exc:  # ImportError, or OSError from a missing shared library such as libusb
        if isinstance(exc, ModuleNotFoundError) and exc.name == "open3d":
            raise ImportError(f"this command needs Open3D, which is not installed; install it: {INSTALL_HINT}", name="open3d") from exc
        reason = " ".join(str(exc).split())
        raise ImportError(
            f"this command needs Open3D, which is installed but cannot load ({type(exc).__name__}: {reason}); "
            "on Debian/Ubuntu its wheel needs the system's libusb: apt install libusb-1.0-0", name="open3d",
        ) from exc
    return open3d


# Open3D index ([rotation; translation]) of each se(2) tangent component [v_x, v_y, ω].
_OPEN3D_INDEX_OF_SE2 = np.array([3, 4, 2])
_OUT_OF_PLANE = np.array([0, 1, 5])


def embed_information_2d(information: np.ndarray) -> np.ndarray:
    """Open3D ``(m, 6, 6)`` information from SE(2) information ``(m, 3, 3)`` (module docstring)."""
    information = np.asarray(information, dtype=np.float64)
    out = np.zeros(information.shape[:-2] + (6, 6))
    index = _OPEN3D_INDEX_OF_SE2
    out[..., index[:, None], index] = information
    stiffest = np.diagonal(information, axis1=-2, axis2=-1).max(axis=-1)
    out[..., _OUT_OF_PLANE, _OUT_OF_PLANE] = stiffest[..., None]
    return out


def _in_3d(graph, poses):
    """``(poses, measurements, information)`` as SE(3) arrays, 2D graphs embedded at z = 0."""
    X = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    if X.shape[-1] == 4:
        return X, graph.measurements, graph.information
    return se2.to_se3(X), se2.to_se3(graph.measurements), embed_information_2d(graph.information)


def to_open3d_pose_graph(graph, poses: np.ndarray | None = None, *, uncertain_loop_closures: bool = False):
    """An ``open3d.pipelines.registration.PoseGraph`` with the graph's vertices and edges.

    ``poses`` ``(n, 4, 4)`` (or ``(n, 3, 3)`` for a 2D graph) replaces ``graph.poses`` when
    given. Every edge is certain unless ``uncertain_loop_closures``. See the module docstring for
    how edges map and how 2D graphs are embedded.
    """
    o3d = require_open3d()
    reg = o3d.pipelines.registration
    X, measurements, information = _in_3d(graph, poses)
    pose_graph = reg.PoseGraph()
    for pose in X:
        pose_graph.nodes.append(reg.PoseGraphNode(np.ascontiguousarray(pose)))
    uncertain_edges = ~graph.odometry_mask() if uncertain_loop_closures else np.zeros(graph.num_edges, bool)
    for i, j, Z, info, uncertain in zip(graph.edge_from, graph.edge_to, measurements, information, uncertain_edges):
        pose_graph.edges.append(
            reg.PoseGraphEdge(int(j), int(i), np.ascontiguousarray(Z), np.ascontiguousarray(info), bool(uncertain))
        )
    return pose_graph


def write_open3d_pose_graph(
    path, graph, poses: np.ndarray | None = None, *, uncertain_loop_closures: bool = False
) -> None:
    """Write :func:`to_open3d_pose_graph` as an Open3D PoseGraph JSON file (``open3d.io.write_pose_graph``), atomically."""
    o3d = require_open3d()
    pose_graph = to_open3d_pose_graph(graph, poses, uncertain_loop_closures=uncertain_loop_closures)
    with atomic_path(path, suffix=".json") as tmp:
        # Some Open3D versions return None rather than a success flag: check the file too.
        if o3d.io.write_pose_graph(tmp, pose_graph) is False or os.path.getsize(tmp) == 0:
            raise OSError(f"Open3D could not write {path}")


def trajectory_line_set(graph, poses: np.ndarray | None = None, *, loop_closures: bool = False):
    """An ``open3d.geometry.LineSet``: vertex positions in id order joined by segments.

    Points are the vertex positions sorted by id; lines join consecutive points (the trajectory,
    coloured blue). With ``loop_closures`` every loop-closure edge is added as a grey line. 2D
    positions are placed at ``z = 0``.
    """
    o3d = require_open3d()
    X = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    if X.shape[-1] == 3:
        X = se2.to_se3(X)
    order = np.argsort(graph.ids, kind="stable")
    points = X[order, :3, 3]
    n = len(order)
    lines = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1) if n > 1 else np.zeros((0, 2), int)
    colours = np.tile([0.0, 0.447, 0.698], (len(lines), 1))
    if loop_closures:
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n)  # position of vertex k in the id-sorted points
        closing = ~graph.odometry_mask()
        extra = np.stack([rank[graph.edge_from[closing]], rank[graph.edge_to[closing]]], axis=1)
        lines = np.concatenate([lines, extra])
        colours = np.concatenate([colours, np.tile([0.6, 0.6, 0.6], (len(extra), 1))])
    line_set = o3d.geometry.LineSet()
    line_set.points = o3d.utility.Vector3dVector(np.ascontiguousarray(points))
    line_set.lines = o3d.utility.Vector2iVector(np.ascontiguousarray(lines, dtype=np.int32))
    line_set.colors = o3d.utility.Vector3dVector(np.ascontiguousarray(colours))
    return line_set


def write_trajectory_ply(path, graph, poses: np.ndarray | None = None, *, loop_closures: bool = False) -> None:
    """Write :func:`trajectory_line_set` to a PLY file (``open3d.io.write_line_set``), atomically."""
    o3d = require_open3d()
    line_set = trajectory_line_set(graph, poses, loop_closures=loop_closures)
    with atomic_path(path, suffix=".ply") as tmp:
        if o3d.io.write_line_set(tmp, line_set, write_ascii=False) is False or os.path.getsize(tmp) == 0:
            raise OSError(f"Open3D could not write {path}")
