"""g2o's unary edges (priors) and their offset parameters: reading into :class:`~posegraph.model.priors.Priors`, writing back.

Tags (g2o's ``types_slam3d`` / ``types_slam2d``; fields after the tag):

* ``PARAMS_SE3OFFSET pid x y z qx qy qz qw`` — an offset ``O`` (normalised quaternion, as g2o does);
* ``EDGE_SE3_PRIOR v pid x y z qx qy qz qw`` + 21 information entries in g2o's ``[t; R]`` order,
  permuted to ``[ω; v]`` as for ``EDGE_SE3:QUAT``; residual ``Log(Z⁻¹ X O)``, ``O`` of ``pid``;
* ``EDGE_SE3_XYZ_PRIOR v pid x y z`` + 6 entries (3×3); residual ``t(X) − z`` (g2o reads ``pid`` but
  its error does not use the offset; ``pid`` −1, what g2o writes when no offset is installed, is accepted
  and written back as read);
* ``EDGE_PRIOR_SE2 v x y θ`` + 6 entries in ``[x, y, θ]`` order; residual ``Log(Z⁻¹ X)``;
* ``EDGE_PRIOR_SE2_XY v x y`` + 3 entries (2×2); residual ``t(X) − z``.

Lines are checked like the other edges (syntax, finite values, quaternions, information matrices,
the vertex and the parameter they name), each error as ``file:line: reason``. The writer copies
the lines as read while the priors are unchanged, else formats them (``repr`` floats).
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o_checks import check_finite, check_information, raise_first, unit_quaternions
from posegraph.io.g2o_format import G2O_TO_TANGENT, TANGENT_FROM_UPPER, Record, _entry_of_upper, _information_fields, pose_values
from posegraph.io.g2o_lines import Lines, parse_records
from posegraph.lie import so2, so3
from posegraph.model.priors import Priors

PARAMS_TAG = "PARAMS_SE3OFFSET"
SE3_PRIOR_TAG = "EDGE_SE3_PRIOR"
SE3_XYZ_PRIOR_TAG = "EDGE_SE3_XYZ_PRIOR"
SE2_PRIOR_TAG = "EDGE_PRIOR_SE2"
SE2_XY_PRIOR_TAG = "EDGE_PRIOR_SE2_XY"


class PriorRecord(NamedTuple):
    """How one prior tag is read: its line layout and what it means."""

    record: Record
    """Field layout (``ids`` = vertex and, in 3D, parameter id; ``t``; ``q`` or ``theta``; ``info``)."""
    kind: str
    """``"pose"`` or ``"position"``."""
    space_dim: int
    """3 or 2."""
    information_from_upper: np.ndarray
    """Indices into the upper-triangular entries giving the tangent-order matrix, row-major."""


_ROTATION_FIELDS = {"quaternion": ([("q", np.float64, (4,))], ("qx", "qy", "qz", "qw")),
                    "angle": ([("theta", np.float64)], ("theta",)), None: ([], ())}
"""Per rotation kind of a prior line: its dtype fields and their names (a position prior has none)."""


def _prior_record(ids: int, translation: int, rotation: str | None, size: int, space_dim: int) -> Record:
    """The layout of a prior line: ``ids`` integers (vertex, and in 3D the parameter id), the measured
    ``translation`` entries, the rotation (``"quaternion"``, ``"angle"`` or None), then the
    ``size·(size+1)/2`` upper-triangular information entries."""
    rotation_dtype, rotation_names = _ROTATION_FIELDS[rotation]
    dtype = np.dtype([("ids", np.int64, (ids,)), ("t", np.float64, (translation,))] + rotation_dtype
                     + [("info", np.float64, (size * (size + 1) // 2,))])
    names = ("id", "param_id")[:ids] + ("x", "y", "z")[:translation] + rotation_names + _information_fields(size)
    return Record("edge", dtype, names, ids, rotation or "none", None, space_dim)


PRIOR_RECORDS = {
    SE3_PRIOR_TAG: PriorRecord(_prior_record(2, 3, "quaternion", 6, 3), "pose", 3, TANGENT_FROM_UPPER),
    SE3_XYZ_PRIOR_TAG: PriorRecord(_prior_record(2, 3, None, 3, 3), "position", 3, _entry_of_upper(3).reshape(-1)),
    SE2_PRIOR_TAG: PriorRecord(_prior_record(1, 2, "angle", 3, 2), "pose", 2, _entry_of_upper(3).reshape(-1)),
    SE2_XY_PRIOR_TAG: PriorRecord(_prior_record(1, 2, None, 2, 2), "position", 2, _entry_of_upper(2).reshape(-1)),
}
"""The prior tags read, in the order their checks run."""

PARAMS_RECORD = Record(
    "parameter", np.dtype([("id", np.int64), ("t", np.float64, (3,)), ("q", np.float64, (4,))]),
    ("id", "x", "y", "z", "qx", "qy", "qz", "qw"), 1, "quaternion",
)  # fmt: skip

PRIOR_TAGS = frozenset(PRIOR_RECORDS) | {PARAMS_TAG}
"""Every tag this module reads."""


class _Parsed(NamedTuple):
    """The priors of one tag, values checked."""

    tag: str
    ids: np.ndarray  # (u, 1 or 2): vertex id (and parameter id)
    rotations: np.ndarray | None  # (u, r, r) for pose priors
    translations: np.ndarray  # (u, r)
    information: np.ndarray  # (u, s, s) tangent order
    numbers: np.ndarray  # (u,) lines


def read_priors(groups: dict[str, Lines], space_dim: int, ids: np.ndarray, path: str, repair: bool):
    """``(Priors or None, warning texts)`` from the prior lines of ``groups`` (a file's lines by tag).

    ``ids`` are the graph's vertex ids (priors name vertices by id); ``space_dim`` the file's
    dimension (a prior tag of the other one is refused). None when the file has no prior line.
    """
    present = [tag for tag in PRIOR_RECORDS if tag in groups]
    if not present:
        return None, []
    wrong = [tag for tag in present if PRIOR_RECORDS[tag].space_dim != space_dim]
    if wrong:
        raise G2oFormatError(
            f"{wrong[0]} in a {space_dim}D file: a prior must be of the graph's dimension", path,
            int(groups[wrong[0]].numbers[0]),
        )  # fmt: skip
    parsed, notes = [], []
    for tag in present:
        part, part_notes = _parse_tag(groups[tag], tag, path, repair)
        parsed.append(part)
        notes += part_notes
    offsets = parse_offsets(groups.get(PARAMS_TAG), path) if space_dim == 3 else {}
    priors = _assemble(parsed, offsets, ids, space_dim, path)
    lines = _text(groups, present + ([PARAMS_TAG] if PARAMS_TAG in groups else []))
    return replace(priors, text=(lines, priors.checksum(ids))), notes


def gauge_note(graph, path: str) -> list[str]:
    """A warning for the components whose priors leave a rotation free (:mod:`posegraph.model.priors`), or none."""
    from posegraph.model.graph import connected_components
    from posegraph.model.priors import underdetermined_components

    if graph.priors is None or graph.priors.num_position == 0:
        return []
    count, labels = connected_components(graph)
    free = np.flatnonzero(underdetermined_components(graph.priors, labels, count) & ~_has_fixed(graph, labels, count))
    if free.size == 0:
        return []
    lines = graph.priors.position_lines
    first = int(lines[np.isin(labels[graph.priors.position_vertex], free)].min()) if lines is not None else None
    where = f"{path}:{first}" if first is not None else path
    return [f"{where}: the position priors of {free.size} connected component(s) leave a rotation free (one point, or "
            "points on a line): no vertex is held there, Levenberg-Marquardt's damping fixes that rotation where the "
            "start has it (Gauss-Newton will find the system singular)"]


def _has_fixed(graph, labels: np.ndarray, count: int) -> np.ndarray:
    """``(count,)`` bool: the components with a ``FIX`` vertex."""
    out = np.zeros(count, dtype=bool)
    out[labels[graph.fixed]] = True
    return out


def _parse_tag(lines: Lines, tag: str, path: str, repair: bool) -> tuple[_Parsed, list[str]]:
    """One tag's lines parsed and checked (syntax, finite values, quaternion, information)."""
    spec = PRIOR_RECORDS[tag]
    records, error = parse_records(lines, tag, spec.record, path)
    raise_first([error])
    numbers = lines.numbers
    errors = [check_finite(records, numbers, tag, spec.record.fields, path)]
    rotations = None
    if spec.kind == "pose" and spec.space_dim == 3:
        q, zero = unit_quaternions(records["q"], numbers, tag, path)
        errors.append(zero)
        rotations = so3.from_quaternion(q) if zero is None else None
    elif spec.kind == "pose":
        with np.errstate(invalid="ignore"):
            rotations = so2.from_angle(records["theta"])
    size = int(round(np.sqrt(spec.information_from_upper.size)))
    information = records["info"][:, spec.information_from_upper].reshape(-1, size, size)
    tags = np.full(len(records), tag, dtype=object)
    information, info_error, notes = check_information(information, numbers, tags, path, repair=repair)
    errors.append(info_error)
    raise_first(errors)
    return _Parsed(tag, records["ids"], rotations, records["t"], information, numbers), notes


def parse_offsets(lines: Lines | None, path: str) -> dict[int, np.ndarray]:
    """``{parameter id: (4, 4) offset}`` of the ``PARAMS_SE3OFFSET`` lines (a repeated id refused)."""
    if lines is None:
        return {}
    records, error = parse_records(lines, PARAMS_TAG, PARAMS_RECORD, path)
    raise_first([error])
    q, zero = unit_quaternions(records["q"], lines.numbers, PARAMS_TAG, path)
    raise_first([check_finite(records, lines.numbers, PARAMS_TAG, PARAMS_RECORD.fields, path), zero])
    offsets: dict[int, np.ndarray] = {}
    for k, identifier in enumerate(records["id"].tolist()):
        if identifier in offsets:
            raise G2oFormatError(f"{PARAMS_TAG} id {identifier} is defined twice", path, int(lines.numbers[k]))
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = so3.from_quaternion(q[k]), records["t"][k]
        offsets[identifier] = matrix
    return offsets


def _vertex_indices(part: _Parsed, ids: np.ndarray, path: str) -> np.ndarray:
    """Indices of the vertices the priors of ``part`` name; a :class:`GraphError` for an unknown one."""
    order = np.argsort(ids, kind="stable")
    wanted = part.ids[:, 0]
    position = np.clip(np.searchsorted(ids, wanted, sorter=order), 0, max(len(ids) - 1, 0))
    found = order[position] if len(ids) else np.zeros(len(wanted), dtype=np.int64)
    missing = np.flatnonzero(ids[found] != wanted) if len(ids) else np.arange(len(wanted))
    if missing.size:
        k = missing[0]
        raise GraphError(f"{part.tag} names vertex {wanted[k]}, which no vertex line defines", path,
                         int(part.numbers[k]))
    return found


def _offset_matrices(part: _Parsed, offsets: dict, path: str) -> np.ndarray:
    """``(u, 4, 4)`` offsets of a 3D tag's priors by their parameter ids (an unknown id refused)."""
    out = np.empty((len(part.ids), 4, 4))
    for k, identifier in enumerate(part.ids[:, 1].tolist()):
        if identifier not in offsets:
            raise G2oFormatError(
                f"{part.tag} names parameter {identifier}, which no {PARAMS_TAG} line defines", path,
                int(part.numbers[k]),
            )  # fmt: skip
        out[k] = offsets[identifier]
    return out


def _assemble(parsed: list[_Parsed], offsets: dict, ids: np.ndarray, space_dim: int, path: str) -> Priors:
    """The :class:`Priors` of the checked parts (pose priors of one tag, position priors of another)."""
    from posegraph.lie.group import SE2, SE3

    priors = Priors.empty(SE3 if space_dim == 3 else SE2)
    fields: dict = {"offsets": offsets}
    for part in parsed:
        vertex = _vertex_indices(part, ids, path)
        has_parameter = part.ids.shape[1] == 2
        if PRIOR_RECORDS[part.tag].kind == "pose":
            k = space_dim + 1
            measurements = np.zeros((len(vertex), k, k))
            measurements[:, :space_dim, :space_dim], measurements[:, :space_dim, space_dim] = part.rotations, part.translations
            measurements[:, space_dim, space_dim] = 1.0
            pose_offsets = _offset_matrices(part, offsets, path) if has_parameter else np.broadcast_to(np.eye(k), measurements.shape).copy()
            fields.update(pose_vertex=vertex, pose_measurements=measurements, pose_offsets=pose_offsets,
                          pose_information=part.information, pose_lines=part.numbers,
                          pose_offset_ids=part.ids[:, 1].copy() if has_parameter else None)
        else:
            if has_parameter:  # the parameter must exist, as g2o requires, but for −1: what g2o writes without one
                _offset_matrices(part._replace(ids=part.ids[part.ids[:, 1] != -1], numbers=part.numbers[part.ids[:, 1] != -1]),
                                 offsets, path)
            fields.update(position_vertex=vertex, position_measurements=part.translations,
                          position_information=part.information, position_lines=part.numbers,
                          position_offset_ids=part.ids[:, 1].copy() if has_parameter else None)
    return replace(priors, **fields)


def _text(groups: dict[str, Lines], tags: list[str]) -> list[str]:
    """``"TAG rest"`` of every line of ``tags``, parameters first, then the priors in file order."""
    entries = []
    for tag in tags:
        first = 0 if tag == PARAMS_TAG else 1
        entries += [(first, int(n), f"{tag} {rest.rstrip()}") for n, rest in zip(groups[tag].numbers, groups[tag].rests)]
    return [text for _, _, text in sorted(entries)]


def format_priors(graph) -> list[str]:
    """The lines of ``graph.priors`` (each ``"TAG fields"``, no newline): as read while unchanged, else formatted."""
    priors = graph.priors
    if priors is None or len(priors) == 0:
        return []
    copied = priors.copied_text(graph.ids)
    if copied is not None:
        return copied
    return _formatted(graph, priors)


def _formatted(graph, priors: Priors) -> list[str]:
    """Prior lines formatted from the arrays (``repr`` floats, information back in g2o's order)."""
    planar = graph.group.matrix_size == 3
    offsets = dict(priors.offsets)
    pose_tag, position_tag = (SE2_PRIOR_TAG, SE2_XY_PRIOR_TAG) if planar else (SE3_PRIOR_TAG, SE3_XYZ_PRIOR_TAG)
    pose_info = priors.pose_information if planar else priors.pose_information[:, G2O_TO_TANGENT][:, :, G2O_TO_TANGENT]
    pose_fields = pose_values(priors.pose_measurements, planar)
    pose_heads = _heads(graph.ids[priors.pose_vertex], priors.pose_offset_ids, planar, offsets)
    position_heads = _heads(graph.ids[priors.position_vertex], priors.position_offset_ids, planar, offsets)
    lines = [f"{PARAMS_TAG} {i} " + " ".join(map(repr, pose_values(m[None], False)[0].tolist()))
             for i, m in sorted(offsets.items())]
    for tag, heads, values, information in (
        (pose_tag, pose_heads, pose_fields, pose_info),
        (position_tag, position_heads, priors.position_measurements, priors.position_information),
    ):  # fmt: skip
        rows, cols = np.triu_indices(information.shape[-1])
        upper = information[:, rows, cols]
        lines += [f"{tag} {head} " + " ".join(map(repr, v + u)) for head, v, u in
                  zip(heads, values.tolist(), upper.tolist())]
    return lines


def _heads(vertex_ids: np.ndarray, offset_ids, planar: bool, offsets: dict) -> list[str]:
    """``"v"`` (2D) or ``"v pid"`` (3D) per prior; ``offsets`` (a copy) gains an identity 0 when needed."""
    if planar:
        return [str(v) for v in vertex_ids.tolist()]
    if offset_ids is None:
        if 0 not in offsets:
            offsets[0] = np.eye(4)  # an identity offset for priors made without one
        offset_ids = np.zeros(len(vertex_ids), dtype=np.int64)
    return [f"{v} {p}" for v, p in zip(vertex_ids.tolist(), offset_ids.tolist())]

