"""Reading g2o files: text to :class:`~posegraph.model.graph.PoseGraph`, in four checked stages.

The stages, in the order their errors are reported (the first problem in the file wins within a
stage): the format of each line (:mod:`posegraph.io.g2o_lines`), the values (finite numbers,
quaternions, information matrices: :mod:`posegraph.io.g2o_checks`), an empty graph, then the
graph (duplicate ids, unknown vertices, self-loops). Each vertex and edge tag is read as its
entry of :data:`posegraph.io.g2o_format.RECORDS` says; a new tag of the same kind is a new
entry there. The format, checks and repairs are described in ``docs/g2o.md``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from posegraph.errors import G2oFormatError, GraphError, InputError, InputWarning, MissingPosesWarning, excerpt
from posegraph.model.graph import EdgeSource, PoseGraph
from posegraph.io.g2o_checks import (
    check_finite, check_information, check_negative_ids, components_note, quaternion_note, raise_first,
    space_dimension, topology, unit_quaternions,
)
from posegraph.io.g2o_format import FIX_TAG, PRIMARY_EDGE_TAG, READ_TAGS, RECORDS, Record, records_of
from posegraph.io.g2o_isam import odometry_noise_note, odometry_records_in_g2o_order
from posegraph.io.g2o_landmarks import (
    LANDMARK_TAGS, assemble_landmarks, landmark_refusal, landmark_space_dim, landmark_vertex_ids, measured_pose_ids,
    parse_landmarks,
)
from posegraph.io.g2o_priors import PARAMS_TAG, PRIOR_RECORDS, PRIOR_TAGS, gauge_note, parse_offsets, read_priors
from posegraph.io.g2o_toro import EQUIV_TAG, edge2_records_in_g2o_order, merge_equivalent
from posegraph.io.g2o_lines import Lines, group_lines, parse_fix, parse_records
from posegraph.io.g2o_sim3 import is_sim3_file, read_sim3
from posegraph.linalg.heap import release_free_memory
from posegraph.io.text_input import Block, read_blocks
from posegraph.lie import so2, so3
from posegraph.lie.group import SE2, SE3

_GROUP = {3: SE3, 2: SE2}
"""The group of a file's poses by its space dimension (3D or 2D tags)."""


class _Poses(NamedTuple):
    """Vertices of every vertex tag, in file order."""

    ids: np.ndarray  # (n,) int64
    rotations: np.ndarray  # (n, r, r), r = 3 (3D) or 2 (2D)
    translations: np.ndarray  # (n, r)
    numbers: np.ndarray  # (n,) 1-based line numbers


class _Measurements(NamedTuple):
    """Edges of every edge tag, in file order."""

    ids: np.ndarray  # (m, 2) int64 vertex ids
    rotations: np.ndarray  # (m, r, r)
    translations: np.ndarray  # (m, r)
    information: np.ndarray  # (m, d, d) in tangent order ([ω; v] for SE(3), [v_x, v_y, ω] for SE(2))
    numbers: np.ndarray  # (m,) 1-based line numbers
    tags: np.ndarray  # (m,) the tag of each line (for messages)


class _Fix(NamedTuple):
    """Ids of the ``FIX`` lines and the line each came from."""

    ids: np.ndarray  # (k,) int64
    numbers: np.ndarray  # (k,)


def read_g2o(
    path: str | os.PathLike, *, require_edges: bool = True, repair_information: bool = False,
    edge2_information: str = "auto", poses_only: bool = False, isam_information: str = "sqrt",
) -> PoseGraph:
    """Read a 3D or 2D pose graph from a g2o file.

    Parameters
    ----------
    path:
        The ``.g2o`` file: 3D (``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT``, gtsam's older ``VERTEX3`` /
        ``EDGE3``) or 2D (``VERTEX_SE2``, ``EDGE_SE2``), with ``FIX`` lines; see ``docs/g2o.md``
        for the format and the checks. Plain or gzip/bzip2/xz-compressed
        (:func:`posegraph.io.text_input.read_blocks`, which streams it). A file mixing 2D and 3D lines is refused.
        ``"-"`` reads standard input (messages then name ``<stdin>``).
    require_edges:
        True (default) reads a graph to optimise: edges are required, and a
        file with edges but no vertex lines (gtsam's ``sphere2500.txt``) gets
        the vertices its edges name, at the identity pose, with a warning
        (:class:`~posegraph.errors.MissingPosesWarning`; the initialisers provide a start). False reads a trajectory: vertex
        lines are required (a file without any is a :class:`GraphError`:
        there are no poses to read) and a file without edges gives ``m = 0``.
    repair_information:
        If True, an information matrix that is not positive semi-definite
        is replaced by the nearest matrix in Frobenius norm whose eigenvalues
        are at least :data:`~posegraph.io.g2o_checks.REPAIR_EIGENVALUE_FLOOR` times its largest (the
        nearest PSD matrix, kept positive definite), with one warning; by
        default such a matrix is an error.
    edge2_information:
        The order of TORO's ``EDGE2`` information entries: ``"auto"`` (default) tells it per file
        (:func:`posegraph.io.g2o_toro.edge2_information_order`), ``"toro"`` / ``"g2o"`` name it.
    poses_only:
        If True, the landmark lines (:mod:`posegraph.io.g2o_landmarks`) are skipped like other unread tags
        (one warning) and ``graph.landmarks`` is None; by default they are read into ``graph.landmarks``.
    isam_information:
        What the noise entries of iSAM's ``ODOMETRY``, ``LANDMARK`` and ``POINT3`` lines are
        (:mod:`posegraph.io.g2o_isam`): ``"sqrt"`` (iSAM's square-root information, the default),
        ``"information"`` (as gtsam's ``readG2o`` reads ``ODOMETRY``) or ``"covariance"``.

    Returns a :class:`PoseGraph`: ``ids (n,)`` in file order, ``poses (n,4,4)``, ``edge_from``/``edge_to
    (m,)`` vertex *indices*, ``measurements (m,4,4)``, ``information (m,6,6)`` in ``[ω; v]`` order
    (g2o's ``[t; R]`` permuted, as ``gtsam.readG2o`` does), ``fixed (n,)``, ``source`` (the absolute
    path read), ``edge_lines (m,)`` (each edge's line) and ``group`` SE(3); for a 2D file
    :data:`~posegraph.lie.group.SE2`, ``(·,3,3)`` poses and measurements and ``(m,3,3)`` information
    in ``[x, y, θ]`` order (g2o's and se(2)'s, unpermuted).

    Raises :class:`G2oFormatError` for a malformed line or an invalid number (``docs/g2o.md``),
    :class:`GraphError` for neither vertices nor edges, no edges (unless ``require_edges=False``), no
    vertices with ``require_edges=False``, a duplicate vertex id, an edge or ``FIX`` naming a missing
    vertex, or a self-loop; :class:`InputError` when the file cannot be opened or is not text. Warns
    (:class:`InputWarning`, one each, after all checks pass) of skipped tags, normalised quaternions,
    vertices created for a file without vertex lines, repaired or singular information matrices,
    several connected components.
    """
    name = os.fspath(path)
    shown, source = ("<stdin>", None) if name == "-" else (name, os.path.abspath(name))  # "-": as Unix tools
    blocks = read_blocks(name)  # gzip/bzip2/xz undone; a binary file refused at its first block
    reading = (edge2_information, poses_only, isam_information)
    graph = _parse(blocks, shown, source, require_edges, repair_information, reading)
    release_free_memory()  # the lines' and the tokens' pages, which the solver's large arrays would not reuse
    return graph


def _parse(
    blocks: Iterable[Block], path: str, source: str | None, require_edges: bool, repair_information: bool, reading: tuple
) -> PoseGraph:
    groups, first_line = group_lines(blocks)
    if is_sim3_file(groups):  # VERTEX_SIM3:EXPMAP / EDGE_SIM3:EXPMAP: their own module
        return read_sim3(groups, first_line, path, source, require_edges=require_edges, repair_information=repair_information)
    edge2_information, poses_only, isam_information = reading
    empty = Lines(np.zeros(0, dtype=np.int64), [])
    skipped = {tag: len(group.rests) for tag, group in groups.items() if tag not in _read_here(groups, poses_only)}
    # Stage 1: the format of each line (stage 2 of the landmark lines with it).
    space_dim = _space_dim(groups, first_line, path, poses_only)
    table = records_of(space_dim)
    lines = {tag: groups.get(tag, empty) for tag in table}
    records, fix = _parse_lines(groups.get(FIX_TAG, empty), lines, table, path)
    records = edge2_records_in_g2o_order(records, lines, path, edge2_information)  # TORO's order told apart
    isam_notes = odometry_noise_note(records, lines, path, isam_information)  # covariances read as square roots
    records = odometry_records_in_g2o_order(records, lines, path, isam_information)  # iSAM's square roots
    refusal = landmark_refusal(groups, set(_tags_of("edge", table)) | PRIOR_TAGS | LANDMARK_TAGS, poses_only, path)
    if refusal is not None and require_edges:
        raise refusal
    notes = _skipped_note(skipped, first_line, path) + ([str(refusal)] if refusal is not None else []) + isam_notes
    parsed = None if poses_only else parse_landmarks(groups, space_dim, path, repair_information, isam_information)
    # Stage 2: the values.
    vertices, edges, information, value_notes = _values(records, lines, table, path, repair_information)
    notes += value_notes
    # Stage 3: an empty graph.
    vertices, empty_notes = _vertices_or_refusal(
        vertices, edges, (skipped, first_line), require_edges, table, path, measured_pose_ids(parsed)
    )
    notes += empty_notes
    # Stage 4: the graph.
    fix, landmark_fix = _split_fix(fix, vertices.ids, groups, parsed, poses_only)
    edge_index, fixed = topology(
        vertices.ids, vertices.numbers, edges.ids, edges.numbers, fix.ids, fix.numbers, path,
        _tag_names(table, "vertex", "line"),
    )  # fmt: skip
    graph = _pose_graph(vertices, edges, information, (edge_index, fixed), source, space_dim)
    graph = _with_edge_source(graph, edges, information, lines[PRIMARY_EDGE_TAG[space_dim]], PRIMARY_EDGE_TAG[space_dim])
    if parsed is not None:
        graph, landmark_notes = _with_landmarks(graph, parsed, groups, landmark_fix, _tag_names(table, "vertex", "line"), path)
        notes += landmark_notes
    priors, prior_notes = read_priors(groups, space_dim, graph.ids, path, repair_information)  # unary edges
    if priors is not None:
        graph, notes = replace(graph, priors=priors), notes + prior_notes
        notes += gauge_note(graph, path)
    graph, merge_notes = merge_equivalent(graph, groups, tuple(_tags_of("vertex", table)), path)  # TORO's EQUIV
    notes += merge_notes
    if graph.num_edges or graph.landmarks is not None:
        notes += components_note(graph, path)
    for note in notes:
        warnings.warn(note, InputWarning, stacklevel=3)
    return graph


def _with_edge_source(graph: PoseGraph, edges: _Measurements, information: np.ndarray, lines: Lines, edge_tag: str):
    """``graph`` with its edge lines kept for the writer when every edge is an ``EDGE_SE3:QUAT`` (``EDGE_SE2``)
    line and none was repaired (a repair returns a copy): the lines state the edges exactly (EdgeSource)."""
    if len(edges.ids) and len(edges.ids) == len(lines.rests) and information is edges.information:
        return replace(graph, edge_source=EdgeSource.of(graph, edge_tag, lines.rests))
    return graph


def _read_here(groups: dict, poses_only: bool) -> frozenset:
    """The tags read from a file of ``groups``: ``PARAMS_SE3OFFSET`` only for priors or landmarks, the landmark
    tags unless the poses alone are asked for."""
    landmarks = frozenset() if poses_only else LANDMARK_TAGS
    uses_offsets = (PRIOR_RECORDS.keys() | landmarks) & groups.keys()
    return READ_TAGS | {EQUIV_TAG} | landmarks | (PRIOR_TAGS if uses_offsets else frozenset())


def _space_dim(groups: dict, first_line: dict, path: str, poses_only: bool) -> int:
    """The file's dimension by its pose tags (mixed ones refused), else by its landmark tags, else 3."""
    if RECORDS.keys() & groups.keys() or poses_only:
        return space_dimension(groups, first_line, path)
    return landmark_space_dim(groups) or 3


def _split_fix(fix: _Fix, pose_ids: np.ndarray, groups: dict, parsed, poses_only: bool) -> tuple[_Fix, _Fix]:
    """``(FIX of poses, FIX of landmarks)``: ids of landmark vertices (dropped when they are skipped) and of the
    landmarks named by measurements (iSAM's) go to the landmarks; the rest, unknown ids included, to the poses."""
    if poses_only:
        candidates = np.array(sorted(landmark_vertex_ids(groups)), dtype=np.int64)
    elif parsed is not None:
        candidates = np.concatenate([parsed.vertices.ids] + [f.ids[:, min(1, f.ids.shape[1] - 1)] for f in parsed.families])
    else:
        return fix, _Fix(fix.ids[:0], fix.numbers[:0])
    landmark = np.isin(fix.ids, candidates) & ~np.isin(fix.ids, pose_ids)
    return _Fix(fix.ids[~landmark], fix.numbers[~landmark]), _Fix(fix.ids[landmark], fix.numbers[landmark])


def _with_landmarks(graph: PoseGraph, parsed, groups: dict, fix: _Fix, pose_names: str, path: str):
    """``(graph with its landmarks, warning texts)``; a ``FIX`` of a landmark not found refused."""
    uses_offsets = any(family.ids.shape[1] == 3 for family in parsed.families)
    offsets = parse_offsets(groups.get(PARAMS_TAG), path) if uses_offsets else {}
    landmarks, unknown, numbers, notes = assemble_landmarks(
        parsed, graph.ids, graph.poses, (fix.ids, fix.numbers), offsets, pose_names, path
    )
    if len(unknown):
        raise GraphError(f"FIX names vertex {unknown[0]}, which has no vertex line", path, int(numbers[0]))
    return replace(graph, landmarks=landmarks), notes
def _tag_names(table: dict[str, Record], kind: str, noun: str) -> str:
    """``"VERTEX_SE3:QUAT lines (nor VERTEX3)"`` or ``"VERTEX_SE2 lines"``: the tags of one kind, for messages."""
    tags = [tag for tag, record in table.items() if record.kind == kind]
    return f"{tags[0]} {noun}" + (f" (nor {', '.join(tags[1:])})" if len(tags) > 1 else "")


def _pose_graph(vertices, edges, information: np.ndarray, topology_: tuple, source: str | None, space_dim: int) -> PoseGraph:
    """The :class:`PoseGraph` of the merged vertices and edges; ``topology_``: ``(edge_index (m, 2), fixed (n,))``."""
    edge_index, fixed = topology_
    return PoseGraph(
        ids=vertices.ids.copy(),
        poses=_matrices(vertices.rotations, vertices.translations),
        edge_from=edge_index[:, 0].copy(),
        edge_to=edge_index[:, 1].copy(),
        measurements=_matrices(edges.rotations, edges.translations),
        information=information,
        fixed=fixed,
        source=source,
        edge_lines=edges.numbers.copy(),
        group=_GROUP[space_dim],
    )


def _parse_lines(
    fix_lines: Lines, lines: dict[str, Lines], table: dict[str, Record], path: str
) -> tuple[dict[str, np.ndarray], _Fix]:
    """Stage 1: every vertex and edge tag's records (``table``, of :data:`RECORDS`) and the ``FIX``
    ids; the first malformed line or negative vertex id raised."""
    records: dict[str, np.ndarray] = {}
    errors: list[InputError | None] = []
    for tag, record in table.items():
        records[tag], error = parse_records(lines[tag], tag, record, path)
        errors.append(error)
        if error is None and record.n_ints == 1:
            errors.append(check_negative_ids(records[tag]["id"], lines[tag].numbers, tag, path))
    fix_ids, fix_numbers, fix_error = parse_fix(fix_lines, path)
    raise_first(errors + [fix_error])
    return records, _Fix(fix_ids, fix_numbers)


def _skipped_note(skipped: dict[str, int], first_line: dict[str, int], path: str) -> list[str]:
    """One warning counting the lines whose tags are not read, per tag."""
    if not skipped:
        return []
    listing = ", ".join(f"{excerpt(tag, quoted=False)} ×{count}" for tag, count in sorted(skipped.items()))
    first = min(first_line[tag] for tag in skipped)
    count = sum(skipped.values())
    return [f"{path}:{first}: skipped {count} line(s) with tags posegraph does not read: {listing}"]


def _values(
    records: dict[str, np.ndarray], lines: dict[str, Lines], table: dict[str, Record], path: str,
    repair_information: bool,
):  # fmt: skip
    """Stage 2: ``(vertices, edges, information (m,d,d), warning texts)``, the first bad value raised.

    Quaternions are normalised (a zero one is an error), Euler and planar angles turned into
    matrices, the information matrices checked (and repaired if asked), every number checked to be finite.
    """
    rotations: dict[str, np.ndarray] = {}
    zero_errors: list[InputError | None] = []
    quaternion_tags = [tag for tag, record in table.items() if record.rotation == "quaternion"]
    for tag, record in table.items():
        if record.rotation == "quaternion":
            q, error = unit_quaternions(records[tag]["q"], lines[tag].numbers, tag, path)
            rotations[tag] = _rotations_or_identity(q)
            zero_errors.append(error)
        elif record.rotation == "angle":
            with np.errstate(invalid="ignore"):  # infinite angles are reported by check_finite
                rotations[tag] = so2.from_angle(records[tag]["theta"])
        else:
            rotations[tag] = _euler_rotations(records[tag]["rpy"])
    vertices = _merge_vertices(records, lines, rotations, table)
    edges = _merge_edges(records, lines, rotations, table)
    information, info_error, info_notes = check_information(
        edges.information, edges.numbers, edges.tags, path, repair=repair_information
    )
    finite = [
        check_finite(records[tag], lines[tag].numbers, tag, record.fields, path) for tag, record in table.items()
    ]
    raise_first(finite + zero_errors + [info_error])
    notes = quaternion_note(
        [records[tag]["q"] for tag in quaternion_tags], [lines[tag].numbers for tag in quaternion_tags], path
    ) if quaternion_tags else []
    return vertices, edges, information, notes + info_notes


def _vertices_or_refusal(
    vertices: _Poses, edges: _Measurements, unread: tuple, require_edges: bool, table: dict[str, Record], path: str,
    landmark_pose_ids: np.ndarray,
) -> tuple[_Poses, list]:  # fmt: skip
    """Stage 3: a :class:`GraphError` for an empty graph; the vertices (created for an edge-only file).

    ``unread`` = ``(skipped, first_line)``: the tags not read with their counts and every tag's first
    line. ``landmark_pose_ids`` are the poses the landmark measurements name: a graph whose poses are
    joined only through landmarks has something to optimise. A file with no pose-graph line at all is
    described by its first line with data and at most three more of its tags (``skipped`` keeps the
    tags in the order they first occur), not by every word of a text file; one with vertices and
    nothing to optimise names the lines it has.
    """
    skipped, first_line = unread
    vertex_tags, edge_tags = _tag_names(table, "vertex", "lines"), _tag_names(table, "edge", "lines")
    measured = len(edges.ids) or len(landmark_pose_ids)
    if len(vertices.ids) == 0:
        if not measured:
            vertex_list = [tag for tag, record in RECORDS.items() if record.kind == "vertex"]
            raise GraphError(
                f"the file has no {vertex_list[0]} lines (nor {', '.join(vertex_list[1:])}, nor edges, nor landmark "
                f"measurements of poses): there is no pose graph to read{_first_unread_line(skipped, first_line)}",
                path,
            )  # fmt: skip
        if not require_edges:
            raise GraphError(
                f"the file has no {vertex_tags}: its {len(edges.ids)} edge(s) and {len(landmark_pose_ids)} observing "
                "pose(s) name vertices but it gives no poses to read",
                path,
            )  # fmt: skip
        vertices, note = _vertices_named_by_edges(edges, path, landmark_pose_ids)
        return vertices, [note]
    if not measured and require_edges:
        found = f"{len(vertices.ids)} pose vertex line(s)" + "".join(
            f", {tag} ×{count}" for tag, count in list(skipped.items())[:4]
        ) + (", …" if len(skipped) > 4 else "")  # fmt: skip
        raise GraphError(
            f"the file has no {edge_tags} and no landmark measurement of a pose: there is nothing to optimise "
            f"(it has {found})", path
        )  # fmt: skip
    return vertices, []


def _first_unread_line(skipped: dict[str, int], first_line: dict[str, int]) -> str:
    """``"; … line 3, begins with 'The'"``: where a file without pose-graph lines starts, and up to three
    more of its g2o-like tags (upper-case words such as ``EDGE_SE3_TRACKXYZ``), or ``""``."""
    if not skipped:
        return ""
    first = next(iter(skipped))
    text = f"; its first line with data, line {first_line[first]}, begins with {excerpt(first)}"
    others = [tag for tag in skipped if tag != first and tag[:1].isupper() and tag.replace(":", "_").isidentifier()
              and tag.upper() == tag]
    if others:
        text += " (other tags: " + ", ".join(excerpt(tag, quoted=False) for tag in others[:3]) + (", …" if len(others) > 3 else "") + ")"
    return text


def _rotations_or_identity(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions ``(k, 4)``; the identity for a zero or non-finite one.

    Such a quaternion is reported by the checks of the same stage; the placeholder only lets
    the checks of all lines run before the first problem in the file is raised.
    """
    norm = np.einsum("ij,ij->i", q, q)
    usable = np.isfinite(norm) & (norm > 0)
    return so3.from_quaternion(q if usable.all() else np.where(usable[:, None], q, [0.0, 0.0, 0.0, 1.0]))


def _tags_of(kind: str, table: dict[str, Record]) -> list[str]:
    return [tag for tag, record in table.items() if record.kind == kind]


def _in_file_order(parts, tags: list[str], records: dict[str, np.ndarray]):
    """``parts`` (a tuple of arrays concatenated tag by tag) sorted by line number when several tags contribute."""
    if sum(len(records[tag]) > 0 for tag in tags) < 2:
        return parts
    order = np.argsort(parts.numbers, kind="stable")
    return type(parts)(*(array[order] for array in parts))


def _merge_vertices(
    records: dict[str, np.ndarray], lines: dict[str, Lines], rotations: dict[str, np.ndarray],
    table: dict[str, Record],
) -> _Poses:  # fmt: skip
    """The vertices of every vertex tag of ``table`` (``VERTEX_SE3:QUAT``, ``VERTEX3``) together, in file order."""
    tags = _tags_of("vertex", table)
    parts = _Poses(
        ids=np.concatenate([records[tag]["id"] for tag in tags]),
        rotations=np.concatenate([rotations[tag] for tag in tags]),
        translations=np.concatenate([records[tag]["t"] for tag in tags]),
        numbers=np.concatenate([lines[tag].numbers for tag in tags]),
    )
    return _in_file_order(parts, tags, records)


def _merge_edges(
    records: dict[str, np.ndarray], lines: dict[str, Lines], rotations: dict[str, np.ndarray],
    table: dict[str, Record],
) -> _Measurements:  # fmt: skip
    """The edges of every edge tag of ``table`` together, in file order, information in tangent order.

    g2o's ``EDGE_SE3:QUAT`` information is ``[t; R]`` and is permuted to ``[ω; v]``; gtsam reads
    ``EDGE3``'s 21 entries as the upper triangle of its own ``[ω; v]`` matrix, unpermuted, and so
    do we; ``EDGE_SE2``'s ``[x, y, θ]`` is se(2)'s order already (``Record.information_from_upper``).
    """
    tags = _tags_of("edge", table)
    d = _GROUP[next(iter(table.values())).space_dim].dim  # 6 (SE(3)) or 3 (SE(2))
    parts = _Measurements(
        ids=np.concatenate([records[tag]["ids"] for tag in tags]),
        rotations=np.concatenate([rotations[tag] for tag in tags]),
        translations=np.concatenate([records[tag]["t"] for tag in tags]),
        information=np.concatenate(
            [records[tag]["info"][:, table[tag].information_from_upper].reshape(-1, d, d) for tag in tags]
        ),
        numbers=np.concatenate([lines[tag].numbers for tag in tags]),
        tags=np.array([tag for tag in tags for _ in range(len(records[tag]))], dtype=object),
    )
    return _in_file_order(parts, tags, records)


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


def _vertices_named_by_edges(edges: _Measurements, path: str, extra: np.ndarray) -> tuple[_Poses, MissingPosesWarning]:
    """Vertices for a file with edges but no vertex lines: the ids its edges name, sorted, at the identity,
    and the warning that says so.

    This is how gtsam's ``sphere2500.txt`` comes (``EDGE3`` lines only; ``gtsam.readG2o`` returns
    no initial values for it), and iSAM's files (``ODOMETRY``, ``LANDMARK``); ``extra`` are the pose
    ids the landmark measurements name. The identity start is meaningless; the initialisers provide one.
    """
    negative = np.flatnonzero((edges.ids < 0).any(axis=1))
    if negative.size:
        e = negative[0]
        raise G2oFormatError(
            f"{edges.tags[e]} names vertex id {edges.ids[e].min()}; vertex ids must be non-negative integers",
            path,
            int(edges.numbers[e]),
        )
    ids = np.unique(np.concatenate([edges.ids.reshape(-1), extra]))  # extra: poses named by landmark measurements
    n, r = len(ids), edges.translations.shape[1]
    vertices = _Poses(
        ids=ids,
        rotations=np.broadcast_to(np.eye(r), (n, r, r)),
        translations=np.zeros((n, r)),
        numbers=np.zeros(n, dtype=np.int64),  # no line: duplicates are impossible
    )
    note = MissingPosesWarning(f"{path}: no vertex lines, so no initial values: created the {n} vertices its edges "
                               "name at the identity pose")
    return vertices, note


def _matrices(rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """``(k, r+1, r+1)`` homogeneous matrices from ``rotations (k, r, r)`` and ``translations (k, r)``."""
    r = translations.shape[1]
    out = np.zeros((len(translations), r + 1, r + 1))
    out[:, :r, :r] = rotations
    out[:, :r, r] = translations
    out[:, r, r] = 1.0
    return out
