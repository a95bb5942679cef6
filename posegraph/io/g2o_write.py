"""Writing g2o files: vertices, ``FIX`` lines and edges as text, written atomically.

Every float is written in its shortest exact decimal form (``repr``), so read → write → read
reproduces translations and information exactly and rotation matrices to rounding; edges read
from ``EDGE_SE3:QUAT`` lines and unchanged since are copied as read. The file is written to a
temporary file in the target folder and renamed over the target, so no partial file is ever
left, and the file the graph was read from is replaced only when asked. See ``docs/g2o.md``.
"""

from __future__ import annotations

import os

import numpy as np

from posegraph.io.atomic import atomic_path
from posegraph.errors import OutputError
from posegraph.model.graph import PoseGraph
from posegraph.io.g2o_format import (
    FIX_TAG, G2O_TO_TANGENT, PRIMARY_EDGE_TAG, UPPER_COLS, UPPER_COLS_2D, UPPER_ROWS,
    UPPER_ROWS_2D, VERTEX_SE2_TAG, VERTEX_TAG, pose_values,
)
from posegraph.io.g2o_sim3 import format_sim3


def format_g2o(graph: PoseGraph, poses: np.ndarray | None = None) -> str:
    """The g2o text of ``graph`` with vertex poses ``poses (n,k,k)`` (default ``graph.poses``).

    Vertices in the graph's order with their ids, one ``FIX id`` line per fixed
    vertex, then the edges. 3D graphs (``k = 4``) as ``VERTEX_SE3:QUAT`` / ``EDGE_SE3:QUAT``: the
    information permuted back to g2o's ``[t; R]`` order (upper triangle, row by row), quaternions
    ``qx qy qz qw`` with ``qw ≥ 0``. 2D graphs (SE(2), ``k = 3``) as ``VERTEX_SE2 id x y θ`` /
    ``EDGE_SE2 i j dx dy dθ`` and the 6 upper-triangular entries in ``[x, y, θ]`` order (the
    tangent order, unpermuted), ``θ = atan2`` of the rotation in ``[−π, π]``, as gtsam's
    ``writeG2o`` writes ``Pose2.theta()``. Floats are written with ``repr``, the shortest decimal
    that reads back to the same double.

    Edges read from ``EDGE_SE3:QUAT`` (``EDGE_SE2``) lines and unchanged since
    (``graph.edge_source``, see :class:`posegraph.model.graph.EdgeSource`) are written as they were
    read, trailing blanks and comments dropped: their numbers read back to the same edges either way.
    """
    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    k = graph.group.matrix_size
    if poses.shape != (graph.num_vertices, k, k):
        raise ValueError(f"poses must have shape {(graph.num_vertices, k, k)}, got {poses.shape}")
    if graph.group.scale_axes:  # Sim(3): g2o's VERTEX_SIM3:EXPMAP / EDGE_SIM3:EXPMAP
        return format_sim3(graph, poses)
    planar = k == 3
    vertex_tag = VERTEX_SE2_TAG if planar else VERTEX_TAG
    vertex_values = pose_values(poses, planar)
    vertex_line = vertex_tag + " %d" + " %r" * vertex_values.shape[1] + "\n"
    parts = [vertex_line % (i, *v) for i, v in zip(graph.ids.tolist(), vertex_values.tolist())]
    parts += [f"{FIX_TAG} {i}\n" for i in graph.ids[graph.fixed].tolist()]
    edge_tag = PRIMARY_EDGE_TAG[k - 1]
    source = graph.edge_source
    if source is not None and source.format == edge_tag and source.matches(graph):
        parts.append(_copied_lines(edge_tag, source.lines))
        return "".join(parts + _prior_lines(graph))
    measurement_values = pose_values(graph.measurements, planar)
    if planar:
        upper = graph.information[:, UPPER_ROWS_2D, UPPER_COLS_2D]
    else:
        upper = graph.information[:, G2O_TO_TANGENT][:, :, G2O_TO_TANGENT][:, UPPER_ROWS, UPPER_COLS]
    edge_line = edge_tag + " %d %d" + " %r" * measurement_values.shape[1] + "%s\n"
    ends = zip(
        graph.ids[graph.edge_from].tolist(),
        graph.ids[graph.edge_to].tolist(),
        measurement_values.tolist(),
        _information_texts(upper),
    )
    parts += [edge_line % (i, j, *v, information) for i, j, v, information in ends]
    return "".join(parts + _prior_lines(graph))


def _prior_lines(graph: PoseGraph) -> list[str]:
    """The priors' lines after the edges (:mod:`posegraph.io.g2o_priors`), the landmarks' lines
    (:mod:`posegraph.io.g2o_landmarks_write`), then ``graph.kept_lines`` (TORO's ``EQUIV`` merges, as read),
    each ending in a newline."""
    from posegraph.io.g2o_landmarks_write import format_landmarks
    from posegraph.io.g2o_priors import format_priors

    return [line + "\n" for line in format_priors(graph) + format_landmarks(graph) + list(graph.kept_lines)]


def _copied_lines(tag: str, lines: list) -> str:
    """``tag rest\n`` for each kept line, trailing blanks dropped (one C-level join when none has any)."""
    if not lines:
        return ""
    head = "\n" + tag + " "
    text = head.join(lines)
    if " \n" in text or "\t\n" in text or "\r\n" in text or text[-1:].isspace():
        text = head.join(line.rstrip() for line in lines)
    return tag + " " + text + "\n"


def _information_texts(upper: np.ndarray) -> list[str]:
    """Per edge, its information entries ``upper (m, 21)`` (2D: ``(m, 6)``) as text, each preceded by a space.

    Formatting floats is most of the writer's time, and information matrices repeat: all edges of
    torus3D and of the grids carry the same one, and on sphere2500 and parking-garage the 104k and
    132k entries take ~21k and ~24k distinct values. So each distinct value (by bit pattern, so
    that −0.0 keeps its sign) is formatted once, and when every edge has the same matrix its text
    is made once (the writer: 78 → 58 ms on torus3D, 54 → 49 ms on parking-garage).
    """
    m = upper.shape[0]
    if m == 0:
        return []
    upper = np.ascontiguousarray(upper, dtype=np.float64)
    bits = upper.view(np.int64)
    if np.array_equal(bits, np.broadcast_to(bits[0], bits.shape)):
        return ["".join(" " + repr(x) for x in upper[0].tolist())] * m
    distinct, inverse = np.unique(bits, return_inverse=True)
    texts = np.array([" " + repr(x) for x in distinct.view(np.float64).tolist()], dtype=object)
    return ["".join(row) for row in texts[inverse.reshape(upper.shape)].tolist()]


def write_g2o(
    path: str | os.PathLike,
    graph: PoseGraph,
    poses: np.ndarray | None = None,
    *,
    overwrite_input: bool = False,
) -> None:
    """Write ``graph`` with vertex poses ``poses (n,k,k)`` (default ``graph.poses``) to a g2o file.

    The text (see :func:`format_g2o`) is written to a temporary file in the
    target's folder, flushed to disk, then renamed over ``path``: on any
    exception, ``KeyboardInterrupt`` included, the temporary file is removed
    and ``path`` is left as it was.

    Raises
    ------
    OutputError
        ``path`` is the file the graph was read from (``graph.source``) and
        ``overwrite_input`` is False; the folder does not exist; ``path`` is a
        folder; ``poses`` hold NaN or infinite values; the file cannot be written.
    ValueError
        ``poses`` has the wrong shape.
    """
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise OutputError(f"the output folder {folder} does not exist", target)
    if os.path.isdir(target):
        raise OutputError("the output path is a folder", target)
    if not overwrite_input and _is_same_file(target, graph.source):
        raise OutputError(
            "refusing to overwrite the input file the graph was read from "
            "(write elsewhere, or pass overwrite_input=True)",
            target,
        )
    values = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    if values.shape == graph.poses.shape and not np.isfinite(values).all():
        raise OutputError("the poses to write contain NaN or infinite values", target)
    text = format_g2o(graph, values)  # everything that can fail is done before the disk is touched
    _replace_atomically(target, text)


def _is_same_file(target: str, source: str | None) -> bool:
    if source is None:
        return False
    try:
        return os.path.samefile(target, source)
    except OSError:  # one of them does not exist: nothing to overwrite
        return False


def _replace_atomically(target: str, text: str) -> None:
    try:
        with atomic_path(target) as temporary:
            with open(temporary, "w", encoding="utf-8", newline="\n") as handle:
                handle.write(text)
                handle.flush()
                os.fsync(handle.fileno())  # on disk before the rename makes it the target
    except OSError as err:
        raise OutputError(f"cannot write the file: {err.strerror or err}", target) from err
