"""Read and write 3D pose graphs in g2o's text format.

Format
------
One record per line; fields are separated by spaces or tabs (any number);
``#`` starts a comment that runs to the end of the line; blank lines and CRLF
line ends are fine. The records read are::

    VERTEX_SE3:QUAT id x y z qx qy qz qw
    EDGE_SE3:QUAT   i j x y z qx qy qz qw  I11 I12 I13 I14 I15 I16 I22 ... I66
    FIX id [id ...]

* The quaternion is in g2o's order ``qx qy qz qw`` (scalar last).
* The 21 ``Irc`` are the upper triangle of the 6×6 information matrix, row by
  row, in g2o's order ``[x y z | rotation]``: translation first. The model
  (:class:`posegraph.graph.PoseGraph`) stores it permuted to the tangent order
  ``[ω; v]`` (rotation first), exactly as ``gtsam.readG2o`` does::

      Ω = [[I_RR, I_Rt],      where the file holds  [[I_tt, I_tR],
           [I_tR, I_tt]]                              [I_Rt, I_RR]]

  so that ½ Σ eᵀ Ω e with ``e = Log(Z⁻¹ Xi⁻¹ Xj)`` equals gtsam's
  ``NonlinearFactorGraph.error`` for the graph ``gtsam.readG2o`` builds.
* Edges name vertices by id; the model refers to them by index into ``ids``.

gtsam's older 3D tags are read too, exactly as ``gtsam.readG2o(path, is3D=True)`` reads them::

    VERTEX3 id x y z roll pitch yaw
    EDGE3   i j x y z roll pitch yaw  I11 I12 ... I66

* The rotation is ``Rz(yaw) · Ry(pitch) · Rx(roll)`` (gtsam's ``Rot3::Ypr(yaw, pitch, roll)``;
  :func:`rotations_from_roll_pitch_yaw`).
* The 21 entries are the upper triangle of the information in gtsam's ``[ω; v]`` order, taken
  as is (no permutation, unlike ``EDGE_SE3:QUAT``).
* Both kinds of lines may be mixed in one file; vertices and edges keep the file's order.

A file with edges but no vertex line at all (gtsam's ``sphere2500.txt``) is read as a graph to
optimise with the vertices its edges name (ids sorted ascending) at the identity pose, and one
warning that the initial values are missing (an initialiser provides them). A trajectory
(``require_edges=False``) needs vertex lines.

Tags this module does not read (other vertex and edge types, ``PARAMS_*``…)
are skipped with one :class:`~posegraph.errors.InputWarning` that counts them
per tag. 2D graphs (``VERTEX_SE2``/``EDGE_SE2``) are refused with a clear
message: they are not supported yet.

Checks
------
Every problem raises an :class:`~posegraph.errors.InputError` subclass whose
message is ``file:line: reason``. The first problem in the file is reported,
in this order of stages: the format of each line (:class:`G2oFormatError`:
2D tags, field count, a field that is not a number or an id that is not an
integer, a negative vertex id), the values (:class:`G2oFormatError`: NaN or
infinite numbers, a zero-norm quaternion, an information matrix that is zero
or not positive semi-definite), an empty graph (:class:`GraphError`, no line:
neither vertices nor edges, no edges unless ``require_edges=False``, no
vertices when ``require_edges=False``), then the graph
(:class:`GraphError`: duplicate vertex id, an edge or ``FIX`` naming a missing
vertex, a self-loop).

Repairs, each reported once by an :class:`~posegraph.errors.InputWarning`:

* Every quaternion is normalised (as gtsam does); those whose norm is off by
  more than :data:`QUATERNION_NORM_TOLERANCE` are counted in a warning that
  names the first line.
* Information policy: a matrix is rejected when its smallest eigenvalue is
  below ``−PSD_TOLERANCE · max|λ|`` (a sign error, not rounding: values written
  with 6 significant digits move the eigenvalues of a singular matrix by at
  most ~3e-6·max|λ|) — unless ``repair_information=True``, which replaces it
  by the nearest matrix (Frobenius norm) whose eigenvalues are at least
  ``REPAIR_EIGENVALUE_FLOOR · λ_max`` — or when it is all zero (the edge would
  constrain nothing yet still connect its vertices, hiding a gauge freedom
  from the solver). A
  singular but non-zero positive semi-definite matrix (e.g. a constraint on
  the translation only) is accepted and stored exactly, with a warning: gtsam's
  ``noiseModel.Gaussian.Information`` does not represent such matrices
  exactly, so costs can differ from gtsam's on those edges.
* A graph with several connected components is accepted with a warning; the
  solver anchors each component separately (see
  :func:`posegraph.graph.component_anchors`).

Writing
-------
:func:`write_g2o` writes vertices (in the graph's order, with their ids),
one ``FIX id`` line per fixed vertex, then edges, with every float in its
shortest exact decimal form (``repr``), so read → write → read reproduces
translations and information exactly and rotation matrices to rounding
(a few 1e-16: the quaternion is recomputed from the matrix).
It writes a temporary file in the target folder and renames it over the
target, so no partial file is ever left, and it refuses to replace the file
the graph was read from unless ``overwrite_input=True``.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from posegraph.atomic import atomic_path
from posegraph.errors import G2oFormatError, GraphError, InputError, InputWarning, OutputError
from posegraph.graph import EdgeSource, PoseGraph, connected_components
from posegraph.lie import so3

__all__ = [
    "read_g2o",
    "write_g2o",
    "format_g2o",
    "VERTEX_TAG",
    "EDGE_TAG",
    "VERTEX3_TAG",
    "EDGE3_TAG",
    "FIX_TAG",
    "G2O_TO_TANGENT",
    "QUATERNION_NORM_TOLERANCE",
    "ZERO_QUATERNION_NORM",
    "PSD_TOLERANCE",
    "SINGULAR_TOLERANCE",
    "REPAIR_EIGENVALUE_FLOOR",
    "rotations_from_roll_pitch_yaw",
]

VERTEX_TAG = "VERTEX_SE3:QUAT"
EDGE_TAG = "EDGE_SE3:QUAT"
FIX_TAG = "FIX"
VERTEX3_TAG = "VERTEX3"
"""gtsam's older 3D vertex: ``VERTEX3 id x y z roll pitch yaw``."""
EDGE3_TAG = "EDGE3"
"""gtsam's older 3D edge: ``EDGE3 i j x y z roll pitch yaw`` and 21 information entries in ``[ω; v]`` order."""
# 2D tags of g2o and of the older TORO/gtsam formats: refused, not skipped,
# because skipping them would silently leave an empty or partial graph.
TWO_D_TAGS = frozenset({"VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2"})

QUATERNION_NORM_TOLERANCE = 1e-6
"""A quaternion whose norm differs from 1 by more than this is reported when normalised."""
ZERO_QUATERNION_NORM = 1e-12
"""A quaternion with a norm at or below this has no direction: rejected."""
PSD_TOLERANCE = 1e-5
"""Information with an eigenvalue below ``−PSD_TOLERANCE · max|λ|`` is not PSD: rejected."""
SINGULAR_TOLERANCE = 1e-12
"""Information with ``λ_min ≤ SINGULAR_TOLERANCE · max|λ|`` is singular: accepted with a warning."""
REPAIR_EIGENVALUE_FLOOR = 1e-9
"""With ``repair_information=True``, a non-PSD matrix's eigenvalues are raised to at least this times its largest."""
MAX_MAGNITUDE = 1e50
"""Numbers above this in magnitude are refused: the cost multiplies an information entry by two
residual entries and the Hessian one by two Jacobian entries (≤ 1e150), and the Cholesky
factorisation squares those (≤ 1e300, below double precision's ~1.8e308)."""

G2O_TO_TANGENT = np.array([3, 4, 5, 0, 1, 2])
"""Index permutation from g2o's ``[t; R]`` order to ``[ω; v]`` (its own inverse)."""

_UPPER_ROWS, _UPPER_COLS = np.triu_indices(6)


def _entry_of_upper() -> np.ndarray:
    """``(6, 6)``: which of the 21 upper-triangular entries (row by row) each element of the symmetric matrix is."""
    entry = np.empty((6, 6), dtype=np.int64)
    entry[_UPPER_ROWS, _UPPER_COLS] = np.arange(21)
    entry[_UPPER_COLS, _UPPER_ROWS] = np.arange(21)
    return entry


# (36,) indices into the 21 entries giving the 6×6 matrix row-major: permuted from g2o's [t; R]
# to [ω; v] (EDGE_SE3:QUAT), or as is (EDGE3, whose entries gtsam reads in its own [ω; v] order).
_TANGENT_FROM_UPPER = _entry_of_upper()[G2O_TO_TANGENT][:, G2O_TO_TANGENT].reshape(-1)
_SYMMETRIC_FROM_UPPER = _entry_of_upper().reshape(-1)
_INFORMATION_FIELDS = tuple(f"information({r + 1},{c + 1})" for r, c in zip(_UPPER_ROWS, _UPPER_COLS))
_VERTEX_FIELDS = ("id", "x", "y", "z", "qx", "qy", "qz", "qw")
_EDGE_FIELDS = ("id_from", "id_to", "x", "y", "z", "qx", "qy", "qz", "qw") + _INFORMATION_FIELDS
_VERTEX3_FIELDS = ("id", "x", "y", "z", "roll", "pitch", "yaw")
_EDGE3_FIELDS = ("id_from", "id_to", "x", "y", "z", "roll", "pitch", "yaw") + _INFORMATION_FIELDS
_VERTEX_DTYPE = np.dtype([("id", np.int64), ("t", np.float64, (3,)), ("q", np.float64, (4,))])
_EDGE_DTYPE = np.dtype(
    [("ids", np.int64, (2,)), ("t", np.float64, (3,)), ("q", np.float64, (4,)), ("info", np.float64, (21,))]
)
_VERTEX3_DTYPE = np.dtype([("id", np.int64), ("t", np.float64, (3,)), ("rpy", np.float64, (3,))])
_EDGE3_DTYPE = np.dtype(
    [("ids", np.int64, (2,)), ("t", np.float64, (3,)), ("rpy", np.float64, (3,)), ("info", np.float64, (21,))]
)
# The record tags read: (dtype, field names, number of leading integer ids).
_RECORDS = {
    VERTEX_TAG: (_VERTEX_DTYPE, _VERTEX_FIELDS, 1),
    VERTEX3_TAG: (_VERTEX3_DTYPE, _VERTEX3_FIELDS, 1),
    EDGE_TAG: (_EDGE_DTYPE, _EDGE_FIELDS, 2),
    EDGE3_TAG: (_EDGE3_DTYPE, _EDGE3_FIELDS, 2),
}
_READ_TAGS = frozenset(_RECORDS) | {FIX_TAG}
_INTEGER = re.compile(r"[+-]?[0-9]+")


class _Lines(NamedTuple):
    """The lines of one tag: 1-based line numbers and the text after the tag."""

    numbers: np.ndarray
    rests: list[str]


class _Poses(NamedTuple):
    """Vertices of every vertex tag, in file order."""

    ids: np.ndarray  # (n,) int64
    rotations: np.ndarray  # (n, 3, 3)
    translations: np.ndarray  # (n, 3)
    numbers: np.ndarray  # (n,) 1-based line numbers


class _Measurements(NamedTuple):
    """Edges of every edge tag, in file order."""

    ids: np.ndarray  # (m, 2) int64 vertex ids
    rotations: np.ndarray  # (m, 3, 3)
    translations: np.ndarray  # (m, 3)
    information: np.ndarray  # (m, 6, 6) in [ω; v] order
    numbers: np.ndarray  # (m,) 1-based line numbers
    tags: np.ndarray  # (m,) the tag of each line (for messages)


# ----------------------------------------------------------------------------- reading


def read_g2o(
    path: str | os.PathLike, *, require_edges: bool = True, repair_information: bool = False
) -> PoseGraph:
    """Read a 3D pose graph from a g2o file.

    Parameters
    ----------
    path:
        The ``.g2o`` file (``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT`` and ``FIX``
        lines, and gtsam's older ``VERTEX3`` / ``EDGE3``; see the module
        docstring for the format and the checks).
    require_edges:
        True (default) reads a graph to optimise: edges are required, and a
        file with edges but no vertex lines (gtsam's ``sphere2500.txt``) gets
        the vertices its edges name, at the identity pose, with a warning
        (the initialisers provide a start). False reads a trajectory: vertex
        lines are required (a file without any is a :class:`GraphError`:
        there are no poses to read) and a file without edges gives ``m = 0``.
    repair_information:
        If True, an information matrix that is not positive semi-definite
        is replaced by the nearest matrix in Frobenius norm whose eigenvalues
        are at least :data:`REPAIR_EIGENVALUE_FLOOR` times its largest (the
        nearest PSD matrix, kept positive definite), with one warning; by
        default such a matrix is an error.

    Returns
    -------
    PoseGraph
        ``ids (n,)`` in file order, ``poses (n,4,4)``, ``edge_from``/``edge_to
        (m,)`` vertex *indices*, ``measurements (m,4,4)``, ``information
        (m,6,6)`` in ``[ω; v]`` order (g2o's ``[t; R]`` permuted, as
        ``gtsam.readG2o`` does), ``fixed (n,)`` and ``source`` (the absolute
        path read).

    Raises
    ------
    G2oFormatError
        A malformed line or an invalid number (see the module docstring).
    GraphError
        Neither vertices nor edges, no edges (unless ``require_edges=False``),
        no vertices with ``require_edges=False``, a duplicate vertex id, an
        edge or ``FIX`` naming a missing vertex, or a self-loop.
    InputError
        The file cannot be opened.

    Warns
    -----
    InputWarning
        Skipped tags, normalised quaternions, vertices created for a file
        without vertex lines, repaired or singular information matrices,
        several connected components (one warning each, after all checks pass).
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as handle:
            data = handle.read()
    except OSError as err:
        raise InputError(f"cannot read the file: {err.strerror or err}", name) from err
    # utf-8-sig drops a byte-order mark, which would otherwise glue itself to the first tag.
    text = data.decode("utf-8-sig", errors="replace")
    return _parse(
        text, name, source=os.path.abspath(name), require_edges=require_edges, repair_information=repair_information
    )


def _parse(text: str, path: str, source: str | None, require_edges: bool, repair_information: bool) -> PoseGraph:
    groups, first_line = _group_lines(text)
    empty = _Lines(np.zeros(0, dtype=np.int64), [])
    lines = {tag: groups.get(tag, empty) for tag in _RECORDS}
    skipped = {tag: len(group.rests) for tag, group in groups.items() if tag not in _READ_TAGS}
    notes: list[str] = []

    # Stage 1: the format of each line.
    _refuse_two_d(groups, first_line, path)
    records: dict[str, np.ndarray] = {}
    errors: list[InputError | None] = []
    for tag, (dtype, fields, n_ints) in _RECORDS.items():
        records[tag], error = _parse_records(lines[tag], tag, dtype, fields, n_ints, path)
        errors.append(error)
        if error is None and n_ints == 1:
            errors.append(_check_negative_ids(records[tag]["id"], lines[tag].numbers, tag, path))
    fix_ids, fix_numbers, fix_error = _parse_fix(groups.get(FIX_TAG, empty), path)
    _raise_first(errors + [fix_error])
    if skipped:
        listing = ", ".join(f"{tag} ×{count}" for tag, count in sorted(skipped.items()))
        first = min(first_line[tag] for tag in skipped)
        count = sum(skipped.values())
        notes.append(f"{path}:{first}: skipped {count} line(s) with tags posegraph does not read: {listing}")

    # Stage 2: the values.
    quaternion_vertices, quaternion_edges = records[VERTEX_TAG], records[EDGE_TAG]
    vertex_q, vertex_zero = _unit_quaternions(quaternion_vertices["q"], lines[VERTEX_TAG].numbers, VERTEX_TAG, path)
    edge_q, edge_zero = _unit_quaternions(quaternion_edges["q"], lines[EDGE_TAG].numbers, EDGE_TAG, path)
    vertices = _merge_vertices(records, lines, _rotations_or_identity(vertex_q))
    edges = _merge_edges(records, lines, _rotations_or_identity(edge_q))
    information, info_error, info_notes = _information(
        edges.information, edges.numbers, edges.tags, path, repair=repair_information
    )
    finite = [
        _check_finite(records[tag], lines[tag].numbers, tag, fields, path) for tag, (_, fields, _) in _RECORDS.items()
    ]
    _raise_first(finite + [vertex_zero, edge_zero, info_error])
    notes += _quaternion_note(
        [quaternion_vertices["q"], quaternion_edges["q"]], [lines[VERTEX_TAG].numbers, lines[EDGE_TAG].numbers], path
    )
    notes += info_notes

    # Stage 3: an empty graph.
    if len(vertices.ids) == 0:
        if len(edges.ids) == 0:
            also = f" (the file has only: {', '.join(sorted(skipped))})" if skipped else ""
            raise GraphError(
                f"the file has no {VERTEX_TAG} lines (nor {VERTEX3_TAG}, nor edges): there is no 3D pose graph "
                f"to read{also}",
                path,
            )
        if not require_edges:
            raise GraphError(
                f"the file has no {VERTEX_TAG} lines (nor {VERTEX3_TAG}): its {len(edges.ids)} edge(s) name "
                "vertices but it gives no poses to read",
                path,
            )
        vertices, note = _vertices_named_by_edges(edges, path)
        notes.append(note)
    elif len(edges.ids) == 0 and require_edges:
        raise GraphError(f"the file has no {EDGE_TAG} lines (nor {EDGE3_TAG}): there is nothing to optimise", path)

    # Stage 4: the graph.
    edge_index, fixed = _topology(
        vertices.ids, vertices.numbers, edges.ids, edges.numbers, fix_ids, fix_numbers, path
    )

    graph = PoseGraph(
        ids=vertices.ids.copy(),
        poses=_matrices(vertices.rotations, vertices.translations),
        edge_from=edge_index[:, 0].copy(),
        edge_to=edge_index[:, 1].copy(),
        measurements=_matrices(edges.rotations, edges.translations),
        information=information,
        fixed=fixed,
        source=source,
    )
    if len(edges.ids) and len(edges.ids) == len(lines[EDGE_TAG].rests) and information is edges.information:
        # Every edge is an EDGE_SE3:QUAT line and none was repaired (a repair returns a copy): the
        # lines state the edges exactly, and the writer copies them (EdgeSource).
        graph = replace(graph, edge_source=EdgeSource.of(graph, EDGE_TAG, lines[EDGE_TAG].rests))
    if graph.num_edges:
        notes += _components_note(graph, path)
    for note in notes:
        warnings.warn(note, InputWarning, stacklevel=3)
    return graph


def _rotations_or_identity(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions ``(k, 4)``; the identity for a zero or non-finite one.

    Such a quaternion is reported by the checks of the same stage; the placeholder only lets
    the checks of all lines run before the first problem in the file is raised.
    """
    norm = np.einsum("ij,ij->i", q, q)
    usable = np.isfinite(norm) & (norm > 0)
    return so3.from_quaternion(q if usable.all() else np.where(usable[:, None], q, [0.0, 0.0, 0.0, 1.0]))


def _merge_vertices(records: dict[str, np.ndarray], lines: dict[str, _Lines], quaternion_rotations) -> _Poses:
    """``VERTEX_SE3:QUAT`` and ``VERTEX3`` vertices together, in file order."""
    euler = records[VERTEX3_TAG]
    parts = _Poses(
        ids=np.concatenate([records[VERTEX_TAG]["id"], euler["id"]]),
        rotations=np.concatenate([quaternion_rotations, _euler_rotations(euler["rpy"])]),
        translations=np.concatenate([records[VERTEX_TAG]["t"], euler["t"]]),
        numbers=np.concatenate([lines[VERTEX_TAG].numbers, lines[VERTEX3_TAG].numbers]),
    )
    if len(euler) == 0 or len(records[VERTEX_TAG]) == 0:
        return parts
    order = np.argsort(parts.numbers, kind="stable")
    return _Poses(*(array[order] for array in parts))


def _merge_edges(records: dict[str, np.ndarray], lines: dict[str, _Lines], quaternion_rotations) -> _Measurements:
    """``EDGE_SE3:QUAT`` and ``EDGE3`` edges together, in file order, information in ``[ω; v]`` order.

    g2o's ``EDGE_SE3:QUAT`` information is ``[t; R]`` and is permuted; gtsam reads ``EDGE3``'s 21
    entries as the upper triangle of its own ``[ω; v]`` matrix, unpermuted, and so do we.
    """
    quaternion, euler = records[EDGE_TAG], records[EDGE3_TAG]
    parts = _Measurements(
        ids=np.concatenate([quaternion["ids"], euler["ids"]]),
        rotations=np.concatenate([quaternion_rotations, _euler_rotations(euler["rpy"])]),
        translations=np.concatenate([quaternion["t"], euler["t"]]),
        information=np.concatenate(
            [
                quaternion["info"][:, _TANGENT_FROM_UPPER].reshape(-1, 6, 6),
                euler["info"][:, _SYMMETRIC_FROM_UPPER].reshape(-1, 6, 6),
            ]
        ),
        numbers=np.concatenate([lines[EDGE_TAG].numbers, lines[EDGE3_TAG].numbers]),
        tags=np.array([EDGE_TAG] * len(quaternion) + [EDGE3_TAG] * len(euler), dtype=object),
    )
    if len(euler) == 0 or len(quaternion) == 0:
        return parts
    order = np.argsort(parts.numbers, kind="stable")
    return _Measurements(*(array[order] for array in parts))


def _euler_rotations(angles: np.ndarray) -> np.ndarray:
    """:func:`rotations_from_roll_pitch_yaw`, silent on infinite angles (reported by the value checks)."""
    with np.errstate(invalid="ignore"):
        return rotations_from_roll_pitch_yaw(angles)


def rotations_from_roll_pitch_yaw(angles: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from ``angles (..., 3)`` = (roll φ, pitch θ, yaw ψ), radians.

    ``R = Rz(ψ) · Ry(θ) · Rx(φ)`` — yaw about z, then pitch about the new y, then roll about the
    new x (intrinsic z-y'-x''); the convention of gtsam's ``Rot3::Ypr(yaw, pitch, roll)`` /
    ``Rot3::RzRyRx(roll, pitch, yaw)``, which gtsam's reader applies to ``VERTEX3``/``EDGE3``'s
    ``roll pitch yaw`` fields.
    """
    angles = np.asarray(angles, dtype=np.float64)
    cos, sin = np.cos(angles), np.sin(angles)
    cr, cp, cy = cos[..., 0], cos[..., 1], cos[..., 2]
    sr, sp, sy = sin[..., 0], sin[..., 1], sin[..., 2]
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def _vertices_named_by_edges(edges: _Measurements, path: str) -> tuple[_Poses, str]:
    """Vertices for a file with edges but no vertex lines: the ids its edges name, sorted, at the identity.

    This is how gtsam's ``sphere2500.txt`` comes (``EDGE3`` lines only; ``gtsam.readG2o`` returns
    no initial values for it). The identity start is meaningless; the initialisers provide one.
    """
    negative = np.flatnonzero((edges.ids < 0).any(axis=1))
    if negative.size:
        e = negative[0]
        raise G2oFormatError(
            f"{edges.tags[e]} names vertex id {edges.ids[e].min()}; vertex ids must be non-negative integers",
            path,
            int(edges.numbers[e]),
        )
    ids = np.unique(edges.ids)
    n = len(ids)
    vertices = _Poses(
        ids=ids,
        rotations=np.broadcast_to(np.eye(3), (n, 3, 3)),
        translations=np.zeros((n, 3)),
        numbers=np.zeros(n, dtype=np.int64),  # no line: duplicates are impossible
    )
    note = (
        f"{path}: the file has no vertex lines, so the initial values are missing: created the {n} vertices "
        "its edges name at the identity pose; start from an initialiser (--init chordal, the default, or "
        "--init odometry; posegraph.init.initialize), not from the file (--init file)"
    )
    return vertices, note


def _refuse_two_d(groups: dict[str, _Lines], first_line: dict[str, int], path: str) -> None:
    two_d = sorted(TWO_D_TAGS & groups.keys(), key=lambda tag: first_line[tag])
    if two_d:
        raise G2oFormatError(
            f"{two_d[0]}: 2D pose graphs are not supported yet; posegraph reads 3D graphs "
            f"({VERTEX_TAG} / {EDGE_TAG} / {FIX_TAG})",
            path,
            first_line[two_d[0]],
        )


def _topology(
    ids: np.ndarray,
    vertex_numbers: np.ndarray,
    edge_ids: np.ndarray,
    edge_numbers: np.ndarray,
    fix_ids: np.ndarray,
    fix_numbers: np.ndarray,
    path: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Edge endpoints as vertex indices ``(m, 2)`` and the fixed mask ``(n,)``, after the graph checks."""
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    duplicate = _check_duplicates(ids, order, vertex_numbers, path)
    edge_index, missing = _resolve(edge_ids.reshape(-1), order, sorted_ids, np.repeat(edge_numbers, 2), "edge", path)
    loops = np.flatnonzero(edge_ids[:, 0] == edge_ids[:, 1])
    loop = None
    if loops.size:
        e = loops[0]
        loop = GraphError(f"self-loop: the edge joins vertex {edge_ids[e, 0]} to itself", path, int(edge_numbers[e]))
    fixed_index, fix_missing = _resolve(fix_ids, order, sorted_ids, fix_numbers, FIX_TAG, path)
    _raise_first([duplicate, missing, loop, fix_missing])
    fixed = np.zeros(len(ids), dtype=bool)
    fixed[fixed_index] = True
    return edge_index.reshape(-1, 2), fixed


def _components_note(graph: PoseGraph, path: str) -> list[str]:
    count, labels = connected_components(graph)
    if count == 1:
        return []
    sizes = np.sort(np.bincount(labels))[::-1]
    shown = ", ".join(str(size) for size in sizes[:5]) + (", …" if count > 5 else "")
    return [
        f"{path}: the graph has {count} connected components (vertex counts {shown}); "
        "the solver anchors each component separately"
    ]


def _group_lines(text: str) -> tuple[dict[str, _Lines], dict[str, int]]:
    """Split ``text`` into lines once and group them by tag (comments and blank lines dropped)."""
    # Split on "\n" only: str.splitlines would also break on \x0b, \x1c… and shift line numbers.
    # A trailing "\r" (CRLF) is whitespace to str.split and to numpy's parser alike.
    lines = text.split("\n")
    if "#" in text:
        lines = [line.partition("#")[0] for line in lines]
    numbers: dict[str, list[int]] = {}
    rests: dict[str, list[str]] = {}
    for number, line in enumerate(lines, start=1):
        # Fast path for "TAG fields…"; str.split handles leading blanks, tabs and a bare tag.
        tag, _, rest = line.partition(" ")
        if not tag or not tag.isprintable():
            parts = line.split(None, 1)
            if not parts:
                continue
            tag = parts[0]
            rest = parts[1] if len(parts) > 1 else ""
        try:
            numbers[tag].append(number)
            rests[tag].append(rest)
        except KeyError:
            numbers[tag] = [number]
            rests[tag] = [rest]
    groups = {tag: _Lines(np.array(numbers[tag], dtype=np.int64), rests[tag]) for tag in numbers}
    first_line = {tag: numbers[tag][0] for tag in numbers}
    return groups, first_line


def _parse_records(
    lines: _Lines, tag: str, dtype: np.dtype, fields: tuple[str, ...], n_ints: int, path: str
) -> tuple[np.ndarray, G2oFormatError | None]:
    """Parse all lines of one tag with one call to numpy's C parser.

    Only when that fails is the first offending line searched for, by bisection
    (about two more parses of the group), and its fields examined one by one.
    """
    if not lines.rests:
        return np.zeros(0, dtype=dtype), None
    records, reason = _load(lines.rests, dtype)
    if records is not None:
        return records, None
    lo, hi = 0, len(lines.rests)  # lines [0, lo) parse; the first bad line is in [lo, hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _load(lines.rests[lo:mid], dtype)[0] is not None:
            lo = mid
        else:
            hi = mid
    number = int(lines.numbers[lo])
    error = _diagnose_line(lines.rests[lo], number, tag, fields, n_ints, path)
    if error is None:  # the token checks disagree with numpy: report what numpy said
        error = G2oFormatError(f"{tag} line could not be parsed: {reason}", path, number)
    return np.zeros(0, dtype=dtype), error


def _load(rests: list[str], dtype: np.dtype) -> tuple[np.ndarray | None, str]:
    """``(records, "")`` if every line parses into one record, else ``(None, reason)``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" when every line is empty
            records = np.loadtxt(rests, dtype=dtype, comments=None, ndmin=1)
    except ValueError as err:
        return None, str(err)
    if records.shape != (len(rests),):  # numpy skips blank lines: a tag without fields
        return None, "a line has no fields"
    return records, ""


def _diagnose_line(
    rest: str, number: int, tag: str, fields: tuple[str, ...], n_ints: int, path: str
) -> G2oFormatError | None:
    """The problem with one line's fields (count, then each field's syntax)."""
    tokens = rest.split()
    if len(tokens) != len(fields):
        return G2oFormatError(
            f"{tag} needs {len(fields)} fields after the tag ({_describe_fields(fields)}), found {len(tokens)}",
            path,
            number,
        )
    for k, token in enumerate(tokens):
        if k < n_ints:
            if not _is_integer(token):
                reason = f"{tag} field {k + 1} ({fields[k]}) is {token!r}, not an integer id"
                return G2oFormatError(reason, path, number)
        elif not _is_number(token):
            return G2oFormatError(f"{tag} field {k + 1} ({fields[k]}) is {token!r}, not a number", path, number)
    return None


def _describe_fields(fields: tuple[str, ...]) -> str:
    if len(fields) > 12:  # the edge's 21 information entries come last
        return " ".join(fields[: len(fields) - 21]) + " and the 21 upper-triangular information entries"
    return " ".join(fields)


def _is_integer(token: str) -> bool:
    """Decimal digits with an optional sign, within int64 (Python's int() would also take "1_0")."""
    return bool(_INTEGER.fullmatch(token)) and -(2**63) <= int(token) < 2**63


def _is_number(token: str) -> bool:
    # The same parser as the fast path, so that the scan finds what it rejected
    # (Python's float() would accept "1_0", which numpy's parser does not).
    try:
        np.loadtxt([token], dtype=np.float64, comments=None, ndmin=1)
    except ValueError:
        return False
    return True


def _parse_fix(lines: _Lines, path: str) -> tuple[np.ndarray, np.ndarray, G2oFormatError | None]:
    """Ids of ``FIX`` lines and the line each came from (there are few such lines)."""
    ids: list[int] = []
    numbers: list[int] = []
    for number, rest in zip(lines.numbers.tolist(), lines.rests):
        tokens = rest.split()
        if not tokens:
            error = G2oFormatError(f"{FIX_TAG} needs at least one vertex id", path, number)
            return np.zeros(0, np.int64), np.zeros(0, np.int64), error
        for k, token in enumerate(tokens):
            if not _is_integer(token):
                error = G2oFormatError(f"{FIX_TAG} field {k + 1} is {token!r}, not an integer id", path, number)
                return np.zeros(0, np.int64), np.zeros(0, np.int64), error
            ids.append(int(token))
            numbers.append(number)
    return np.array(ids, dtype=np.int64), np.array(numbers, dtype=np.int64), None


def _check_negative_ids(ids: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> G2oFormatError | None:
    bad = np.flatnonzero(ids < 0)
    if bad.size == 0:
        return None
    k = bad[0]
    return G2oFormatError(
        f"{tag} id {ids[k]} is negative; vertex ids must be non-negative integers", path, int(numbers[k])
    )


def _raise_first(errors: list[InputError | None]) -> None:
    """Raise the error that comes first in the file (errors without a line last)."""
    found = [e for e in errors if e is not None]
    if found:
        raise min(found, key=lambda e: (e.line is None, e.line or 0))


def _check_finite(
    records: np.ndarray, numbers: np.ndarray, tag: str, fields: tuple[str, ...], path: str
) -> G2oFormatError | None:
    """An error naming the first line and field holding NaN, an infinity or a number above :data:`MAX_MAGNITUDE`."""
    names = [name for name in records.dtype.names if records.dtype[name].base.kind == "f"]
    widths = [int(np.prod(records.dtype[name].shape)) for name in names]
    values = np.concatenate([records[name].reshape(len(records), w) for name, w in zip(names, widths)], axis=1)
    finite = np.abs(values) <= MAX_MAGNITUDE  # False for NaN too
    bad_rows = np.flatnonzero(~finite.all(axis=1))
    if bad_rows.size == 0:
        return None
    row = bad_rows[0]
    col = int(np.flatnonzero(~finite[row])[0])
    field = len(fields) - values.shape[1] + col  # the float fields come after the integer ids
    bound = "finite" if not np.isfinite(values[row, col]) else f"at most {MAX_MAGNITUDE:g} in magnitude (the solver squares products of them)"
    return G2oFormatError(
        f"{tag} field {field + 1} ({fields[field]}) is {values[row, col]}; values must be {bound}",
        path,
        int(numbers[row]),
    )


def _unit_quaternions(
    q: np.ndarray, numbers: np.ndarray, tag: str, path: str
) -> tuple[np.ndarray, G2oFormatError | None]:
    """``q (k,4)`` divided by its norm (as gtsam does); an error for the first zero-norm one."""
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    zero = np.flatnonzero(norm <= ZERO_QUATERNION_NORM)  # NaN rows compare False: reported as non-finite
    if zero.size:
        k = zero[0]
        error = G2oFormatError(
            f"{tag} quaternion (qx qy qz qw) = {tuple(q[k].tolist())} has zero norm: it is not a rotation",
            path,
            int(numbers[k]),
        )
        return q, error
    return q / norm[:, None], None


def _quaternion_note(quaternions: list[np.ndarray], numbers: list[np.ndarray], path: str) -> list[str]:
    """One warning for all quaternions whose norm is off by more than the tolerance."""
    norms = np.concatenate([np.sqrt(np.einsum("ij,ij->i", q, q)) for q in quaternions])
    lines = np.concatenate(numbers)
    off = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if off.size == 0:
        return []
    first = off[np.argmin(lines[off])]
    return [
        f"{path}:{int(lines[first])}: normalised {off.size} quaternion(s) whose norm was off by more "
        f"than {QUATERNION_NORM_TOLERANCE:g} (this one: {norms[first]:.9g})"
    ]


def _information(
    information: np.ndarray, numbers: np.ndarray, tags: np.ndarray, path: str, *, repair: bool
) -> tuple[np.ndarray, G2oFormatError | None, list[str]]:
    """Check (and, if ``repair``, repair) the ``(m, 6, 6)`` information matrices, ``[ω; v]`` order.

    Returns the matrices, an error for the first refused one, and warning texts (repaired or
    singular matrices); see the module docstring for the policy. Rows holding NaN or
    infinities are left to :func:`_check_finite`.
    """
    finite = np.isfinite(information).all(axis=(1, 2))
    checked = information if finite.all() else np.where(finite[:, None, None], information, np.eye(6))
    # Fast path: Cholesky succeeds for the whole batch iff every matrix is positive definite.
    try:
        np.linalg.cholesky(checked)
        return information, None, []
    except np.linalg.LinAlgError:
        pass
    eigenvalues = np.linalg.eigvalsh(checked)  # ascending
    scale = np.abs(eigenvalues).max(axis=1)
    lowest = eigenvalues[:, 0]
    zero = ~np.any(information != 0, axis=(1, 2))
    not_psd = lowest < -PSD_TOLERANCE * scale
    # Clipping a matrix without a positive eigenvalue would leave (almost) nothing: refused even when repairing.
    hopeless = not_psd & (eigenvalues[:, -1] <= 0)
    singular = (lowest <= SINGULAR_TOLERANCE * scale) & ~not_psd & ~zero
    bad = np.flatnonzero(zero | (hopeless if repair else not_psd))
    if bad.size:
        e = bad[0]
        shown = np.array2string(eigenvalues[e], precision=4, separator=", ", max_line_width=1000)
        if zero[e]:
            reason = "the information matrix is all zero: the edge would constrain nothing"
        elif hopeless[e]:
            reason = (
                f"the information matrix has no positive eigenvalue (eigenvalues {shown}): "
                "nothing would be left of it after clipping to a positive semi-definite matrix"
            )
        else:
            reason = (
                f"the information matrix is not positive semi-definite (eigenvalues {shown}); use "
                "--repair-information (read_g2o(..., repair_information=True)) to clip it to the nearest "
                "positive semi-definite matrix"
            )
        return information, G2oFormatError(f"{tags[e]}: {reason}", path, int(numbers[e])), []
    notes = []
    if repair and not_psd.any():
        repaired = np.flatnonzero(not_psd)
        information = information.copy()
        information[repaired] = _nearest_positive_definite(checked[repaired])
        first = repaired[0]
        shown = np.array2string(eigenvalues[first], precision=4, separator=", ", max_line_width=1000)
        notes.append(
            f"{path}:{int(numbers[first])}: repaired {repaired.size} information matrices that were not positive "
            f"semi-definite: each replaced by the nearest matrix (Frobenius norm) with eigenvalues at least "
            f"{REPAIR_EIGENVALUE_FLOOR:g} times its largest (this one's eigenvalues were {shown})"
        )
    if singular.any():
        first = np.flatnonzero(singular)[0]
        kinds = set(tags[singular].tolist())
        kind = kinds.pop() if len(kinds) == 1 else "edge"
        notes.append(
            f"{path}:{int(numbers[first])}: {np.count_nonzero(singular)} {kind} information matrices are "
            "singular: accepted as given; other edges must constrain the directions they leave free "
            "(gtsam's Gaussian noise model does not represent singular matrices exactly)"
        )
    return information, None, notes


def _nearest_positive_definite(matrices: np.ndarray) -> np.ndarray:
    """Symmetric ``(k, 6, 6)`` ``A = V diag(λ) Vᵀ`` to ``V diag(max(λ, f·λ_max)) Vᵀ``, f the repair floor.

    With ``f =`` :data:`REPAIR_EIGENVALUE_FLOOR`, it is the nearest symmetric matrix in Frobenius
    norm whose eigenvalues are all ``≥ f·λ_max``
    (Higham 1988, "Computing a nearest symmetric positive semidefinite matrix": clipping the
    eigenvalues; with ``f = 0`` it is the nearest positive semi-definite matrix, from which this one
    differs by at most ``√6·f·λ_max``). The floor keeps each repaired matrix positive definite, so
    that it is a proper Gaussian on its own (Cholesky succeeds; gtsam's noise model represents it
    exactly) and leaves no direction of the edge entirely free.
    """
    eigenvalues, vectors = np.linalg.eigh(matrices)
    clipped = np.maximum(eigenvalues, REPAIR_EIGENVALUE_FLOOR * eigenvalues[:, -1:])
    out = (vectors * clipped[:, None, :]) @ np.swapaxes(vectors, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))  # exactly symmetric, as the file's matrices are


def _check_duplicates(ids: np.ndarray, order: np.ndarray, numbers: np.ndarray, path: str) -> GraphError | None:
    sorted_ids = ids[order]
    repeat = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1]) + 1
    if repeat.size == 0:
        return None
    # With a stable sort, order[r] is a later line than order[r - 1]; report the earliest repeat.
    r = repeat[np.argmin(order[repeat])]
    first = r
    while first > 0 and sorted_ids[first - 1] == sorted_ids[r]:
        first -= 1
    return GraphError(
        f"duplicate vertex id {sorted_ids[r]} (first defined on line {int(numbers[order[first]])})",
        path,
        int(numbers[order[r]]),
    )


def _resolve(
    wanted: np.ndarray, order: np.ndarray, sorted_ids: np.ndarray, numbers: np.ndarray, what: str, path: str
) -> tuple[np.ndarray, GraphError | None]:
    """Vertex indices of ``wanted`` ids; an error naming the first line with an unknown id."""
    pos = np.clip(np.searchsorted(sorted_ids, wanted), 0, len(sorted_ids) - 1)
    found = sorted_ids[pos] == wanted
    if found.all():
        return order[pos], None
    k = np.flatnonzero(~found)[0]
    return np.zeros(0, np.int64), GraphError(
        f"{what} names vertex {wanted[k]}, which has no {VERTEX_TAG} line (nor {VERTEX3_TAG})", path, int(numbers[k])
    )


def _matrices(rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    out = np.zeros((len(translations), 4, 4))
    out[:, :3, :3] = rotations
    out[:, :3, 3] = translations
    out[:, 3, 3] = 1.0
    return out


# ----------------------------------------------------------------------------- writing


def format_g2o(graph: PoseGraph, poses: np.ndarray | None = None) -> str:
    """The g2o text of ``graph`` with vertex poses ``poses (n,4,4)`` (default ``graph.poses``).

    Vertices in the graph's order with their ids, one ``FIX id`` line per fixed
    vertex, then the edges with the information permuted back to g2o's
    ``[t; R]`` order (upper triangle, row by row). Quaternions are
    ``qx qy qz qw`` with ``qw ≥ 0``; floats are written with ``repr``, the
    shortest decimal that reads back to the same double.

    Edges read from ``EDGE_SE3:QUAT`` lines and unchanged since (``graph.edge_source``, see
    :class:`posegraph.graph.EdgeSource`) are written as they were read, trailing blanks and
    comments dropped: their numbers read back to the same edges either way.
    """
    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    if poses.shape != (graph.num_vertices, 4, 4):
        raise ValueError(f"poses must have shape {(graph.num_vertices, 4, 4)}, got {poses.shape}")
    vertex_values = np.concatenate([poses[:, :3, 3], so3.to_quaternion(poses[:, :3, :3])], axis=1)
    vertex_line = VERTEX_TAG + " %d" + " %r" * 7 + "\n"
    parts = [vertex_line % (i, *v) for i, v in zip(graph.ids.tolist(), vertex_values.tolist())]
    parts += [f"{FIX_TAG} {i}\n" for i in graph.ids[graph.fixed].tolist()]
    source = graph.edge_source
    if source is not None and source.format == EDGE_TAG and source.matches(graph):
        parts.append(_copied_lines(EDGE_TAG, source.lines))
        return "".join(parts)
    measurement_values = np.concatenate(
        [graph.measurements[:, :3, 3], so3.to_quaternion(graph.measurements[:, :3, :3])], axis=1
    )
    g2o_information = graph.information[:, G2O_TO_TANGENT][:, :, G2O_TO_TANGENT]
    edge_line = EDGE_TAG + " %d %d" + " %r" * 7 + "%s\n"
    ends = zip(
        graph.ids[graph.edge_from].tolist(),
        graph.ids[graph.edge_to].tolist(),
        measurement_values.tolist(),
        _information_texts(g2o_information[:, _UPPER_ROWS, _UPPER_COLS]),
    )
    parts += [edge_line % (i, j, *v, information) for i, j, v, information in ends]
    return "".join(parts)


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
    """Per edge, its 21 information entries ``upper (m, 21)`` as text, each preceded by a space.

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
    """Write ``graph`` with vertex poses ``poses (n,4,4)`` (default ``graph.poses``) to a g2o file.

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
