"""Landmark graphs: point vertices and the measurements of them, read into :class:`~posegraph.model.landmarks.Landmarks`.

Tags (fields after the tag; g2o's ``types_slam2d`` / ``types_slam3d``, gtsam's ``dataset.cpp``, iSAM's
``Loader.cpp``; each line parsed by one numpy call per tag, :mod:`posegraph.io.g2o_lines`):

============================  ===============  =========================================================
line                          kind             noise entries
============================  ===============  =========================================================
``VERTEX_XY l x y``           2D landmark      —
``VERTEX_TRACKXYZ l x y z``   3D landmark      —
``EDGE_SE2_XY i l x y``       position         3: information, upper triangle (``EdgeSE2PointXY``)
``EDGE_BEARING_SE2_XY i l θ`` bearing          1: information (``EdgeSE2PointXYBearing``)
``EDGE_PRIOR_XY l x y``       prior (2D)       3: information (``EdgeXYPrior``)
``EDGE_POINTXYZ_PRIOR l x y z``  prior (3D)    6: information (``EdgeXYZPrior``)
``EDGE_SE3_TRACKXYZ i l p x y z``  position    6: information; ``p`` a ``PARAMS_SE3OFFSET`` id: the
                                               sensor offset ``O`` (``EdgeSE3PointXYZ``)
``BR i l θ r σθ σr``          bearing_range    2 standard deviations: Ω = diag(1/σ²) (gtsam's ``load2D``)
``LANDMARK2 i l x y``         position         3: information (TORO-era, gtsam's ``victoriaPark_reduced_1k``)
``LANDMARK i l x y``          position         3: iSAM's square-root information (:mod:`posegraph.io.g2o_isam`)
``POINT3 i l x y z``          position (3D)    6 (or none: R = I): iSAM's square-root information
============================  ===============  =========================================================

``i`` is a pose id, ``l`` a landmark id. g2o files define every landmark by a vertex line, in the one
id space of all vertices; a measurement naming an undefined vertex is refused. Files whose landmark
vertex ids meet the poses' ids (gtsam's ``known_landmark_localization_*.g2o``: g2o cannot load them)
are read as gtsam's ``readG2o`` reads every file, the landmarks in their own id space (``L(l)``): all
landmark ids are shifted by a power of ten above the largest id, with one warning, the measurement
lines then written from their values with the shifted ids (a file g2o loads). ``BR``, ``LANDMARK2``, ``LANDMARK`` and ``POINT3`` come from files without landmark
vertex lines whose landmark ids are their own id space (gtsam's ``L(l)``): a landmark they name that
no vertex line defines is created, placed by its first measurement; when such ids meet pose ids, all
created ids are shifted by a power of ten above the largest pose id (one warning says by how much).
``FIX l`` holds a landmark. Every error names ``file:line``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o_checks import check_finite, check_information, check_negative_ids, raise_first
from posegraph.io.g2o_format import Record, _information_fields
from posegraph.io.g2o_isam import information_of
from posegraph.io.g2o_lines import Lines, parse_records

VERTEX_XY_TAG = "VERTEX_XY"
VERTEX_TRACKXYZ_TAG = "VERTEX_TRACKXYZ"
LANDMARK_VERTEX_TAG = {2: VERTEX_XY_TAG, 3: VERTEX_TRACKXYZ_TAG}
"""The landmark vertex tag of each space dimension (read and written)."""


class LandmarkTag(NamedTuple):
    """How the lines of one landmark measurement tag are read."""

    kind: str
    """One of :data:`posegraph.model.landmarks.KINDS`."""
    space_dim: int
    record: Record
    """Fields ``ids`` (pose, landmark[, parameter]; a prior: landmark), ``z``, ``info`` (the noise entries)."""
    entries: str
    """What the noise entries are: ``"information"``, ``"isam"`` (as ``isam_information`` says) or ``"sigmas"``."""
    own_ids: bool = False
    """Landmark ids in their own id space, landmarks created from the measurements (no vertex lines)."""


def _layout(ids: tuple, values: tuple, entries: int, space_dim: int, noise: tuple | None = None) -> Record:
    dtype = np.dtype([("ids", np.int64, (len(ids),)), ("z", np.float64, (len(values),)), ("info", np.float64, (entries,))])
    size = int(round((np.sqrt(8 * entries + 1) - 1) / 2))
    return Record("edge", dtype, ids + values + (noise or _information_fields(size)), len(ids), "none", None, space_dim)


MEASUREMENT_TAGS = {
    "EDGE_SE2_XY": LandmarkTag("position", 2, _layout(("pose", "landmark"), ("x", "y"), 3, 2), "information"),
    "EDGE_BEARING_SE2_XY": LandmarkTag("bearing", 2, _layout(("pose", "landmark"), ("theta",), 1, 2), "information"),
    "EDGE_PRIOR_XY": LandmarkTag("prior", 2, _layout(("landmark",), ("x", "y"), 3, 2), "information"),
    "EDGE_POINTXYZ_PRIOR": LandmarkTag("prior", 3, _layout(("landmark",), ("x", "y", "z"), 6, 3), "information"),
    "EDGE_SE3_TRACKXYZ": LandmarkTag(
        "position", 3, _layout(("pose", "landmark", "param_id"), ("x", "y", "z"), 6, 3), "information"),
    "BR": LandmarkTag("bearing_range", 2, _layout(("pose", "landmark"), ("bearing", "range"), 2, 2,
                                                  ("bearing_std", "range_std")), "sigmas", True),
    "LANDMARK2": LandmarkTag("position", 2, _layout(("pose", "landmark"), ("x", "y"), 3, 2), "information", True),
    "LANDMARK": LandmarkTag("position", 2, _layout(("pose", "landmark"), ("x", "y"), 3, 2, ("sxx", "sxy", "syy")),
                            "isam", True),
    "POINT3": LandmarkTag("position", 3, _layout(("pose", "landmark"), ("x", "y", "z"), 6, 3,
                                                 ("s11", "s12", "s13", "s22", "s23", "s33")), "isam", True),
}  # fmt: skip
"""The landmark measurement tags read, in the order their checks run."""

VERTEX_RECORDS = {
    tag: Record("vertex", np.dtype([("id", np.int64), ("t", np.float64, (dim,))]), ("id", "x", "y", "z")[: dim + 1], 1,
                "none", None, dim)
    for dim, tag in LANDMARK_VERTEX_TAG.items()
}  # fmt: skip
LANDMARK_TAGS = frozenset(MEASUREMENT_TAGS) | frozenset(VERTEX_RECORDS)
"""Every tag this module reads (skipped, with the other unread tags, when the poses alone are asked for)."""
UNREAD_LANDMARK_TAGS = frozenset({
    "EDGE_SE2_XY_CALIB", "EDGE_SE2_POINTXY_OFFSET", "EDGE_SE2_POINTXY", "EDGE_SE3_POINTXYZ", "EDGE_PROJECT_DISPARITY",
    "EDGE_PROJECT_DEPTH", "EDGE_SE3_LOTSOF_XYZ", "EDGE_SE2_LOTSOFXY",
})  # fmt: skip
"""Measurements of landmarks posegraph does not read (calibrated, projective or multi-point): a file made
largely of them is refused (:func:`landmark_refusal`)."""
LANDMARK_SHARE = 0.25
"""A file whose unread landmark measurement lines are at least this share of its measurement lines is refused."""
ISAM_POINT3_IDENTITY = " 1 0 0 1 0 1"
"""The entries iSAM assumes for a ``POINT3`` line without any (``R = I``)."""


class _Family(NamedTuple):
    """The checked lines of one measurement tag."""

    tag: str
    ids: np.ndarray  # (q, 1..3): pose, landmark[, parameter]; a prior: landmark
    z: np.ndarray  # (q, r)
    information: np.ndarray  # (q, r, r)
    numbers: np.ndarray  # (q,)
    rests: list


class _Vertices(NamedTuple):
    """The landmark vertex lines, in file order."""

    ids: np.ndarray
    positions: np.ndarray
    numbers: np.ndarray


class ParsedLandmarks(NamedTuple):
    """Stages 1 and 2 of the landmark lines: their syntax and values checked, nothing resolved yet."""

    space_dim: int
    families: list
    vertices: _Vertices


def landmark_space_dim(groups: dict) -> int | None:
    """The dimension of the landmark tags of ``groups``, when no pose tag says it (the first one's), or None."""
    present = sorted((int(groups[tag].numbers[0]), tag) for tag in LANDMARK_TAGS & groups.keys())
    if not present:
        return None
    tag = present[0][1]
    return MEASUREMENT_TAGS[tag].space_dim if tag in MEASUREMENT_TAGS else VERTEX_RECORDS[tag].space_dim


def parse_landmarks(groups: dict, space_dim: int, path: str, repair: bool, isam_information: str) -> ParsedLandmarks | None:
    """Stages 1 and 2 for the landmark lines of ``groups``: syntax, a tag of the other dimension, finite
    values, information matrices (repaired if asked); the first problem raised. None without landmark lines."""
    present = sorted((int(groups[tag].numbers[0]), tag) for tag in LANDMARK_TAGS & groups.keys())
    if not present:
        return None
    for number, tag in present:
        dim = MEASUREMENT_TAGS[tag].space_dim if tag in MEASUREMENT_TAGS else VERTEX_RECORDS[tag].space_dim
        if dim != space_dim:
            raise G2oFormatError(f"{tag} in a {space_dim}D file: a landmark must be of the graph's dimension", path, number)
    families, errors = [], []
    for _, tag in present:
        if tag in MEASUREMENT_TAGS:
            family, family_errors = _parse_family(groups[tag], tag, path, repair, isam_information)
            families.append(family)
            errors += family_errors
    vertices, vertex_error = _parse_vertices(groups.get(LANDMARK_VERTEX_TAG[space_dim]), space_dim, path)
    raise_first(errors + [vertex_error])
    return ParsedLandmarks(space_dim, families, vertices)


def _parse_family(lines: Lines, tag: str, path: str, repair: bool, isam_information: str):
    """``(_Family, [errors])`` of one measurement tag; a syntax error raised at once (stage 1)."""
    spec = MEASUREMENT_TAGS[tag]
    if tag == "POINT3":  # iSAM: a line without noise entries means R = I
        lines = Lines(lines.numbers, [rest + ISAM_POINT3_IDENTITY if len(rest.split()) == 5 else rest for rest in lines.rests])
    records, error = parse_records(lines, tag, spec.record, path)
    raise_first([error] + [check_negative_ids(records["ids"][:, k], lines.numbers, tag, path)
                           for k in range(min(2, records["ids"].shape[1]))])
    size = records["z"].shape[1] if spec.kind != "bearing_range" else 2
    meaning = isam_information if spec.entries == "isam" else spec.entries
    numbers = lines.numbers
    finite = check_finite(records, numbers, tag, spec.record.fields, path)
    omega = information_of(records["info"], size, meaning, numbers, tag, path) if finite is None else \
        np.broadcast_to(np.eye(size), (len(records), size, size))
    tags = np.full(len(records), tag, dtype=object)
    omega, info_error, _notes = check_information(omega, numbers, tags, path, repair=repair)
    family = _Family(tag, records["ids"], records["z"], omega, numbers, lines.rests)
    return family, [finite, info_error]


def _parse_vertices(lines: Lines | None, space_dim: int, path: str):
    """``(_Vertices, error or None)`` of the landmark vertex lines."""
    tag = LANDMARK_VERTEX_TAG[space_dim]
    if lines is None:
        return _Vertices(np.zeros(0, np.int64), np.zeros((0, space_dim)), np.zeros(0, np.int64)), None
    records, error = parse_records(lines, tag, VERTEX_RECORDS[tag], path)
    raise_first([error])
    errors = [check_negative_ids(records["id"], lines.numbers, tag, path),
              check_finite(records, lines.numbers, tag, VERTEX_RECORDS[tag].fields, path)]
    found = [e for e in errors if e is not None]
    return _Vertices(records["id"], records["t"], lines.numbers), (min(found, key=lambda e: e.line) if found else None)


def measured_pose_ids(parsed: ParsedLandmarks | None) -> np.ndarray:
    """The pose ids the landmark measurements name (for a file without pose vertex lines)."""
    if parsed is None:
        return np.zeros(0, np.int64)
    ids = [family.ids[:, 0] for family in parsed.families if MEASUREMENT_TAGS[family.tag].kind != "prior"]
    return np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)


def landmark_vertex_ids(groups: dict) -> set:
    """The ids of the landmark vertex lines (their first fields), for ``FIX`` lines when landmarks are skipped."""
    ids = set()
    for tag in VERTEX_RECORDS.keys() & groups.keys():
        for rest in groups[tag].rests:
            head = rest.split(None, 1)
            if head and head[0].lstrip("+-").isdigit():
                ids.add(int(head[0]))
    return ids


def landmark_refusal(groups: dict, measurement_tags, poses_only: bool, path: str) -> GraphError | None:
    """A :class:`GraphError` for a file whose measurements are largely of landmarks posegraph does not read
    (:data:`UNREAD_LANDMARK_TAGS`), or None; ``measurement_tags``: the tags of every measurement it reads."""
    landmark = {tag: len(groups[tag].rests) for tag in UNREAD_LANDMARK_TAGS & groups.keys()}
    if poses_only or not landmark:
        return None
    count = sum(landmark.values())
    total = count + sum(len(groups[tag].rests) for tag in set(measurement_tags) & groups.keys())
    if count < LANDMARK_SHARE * total or count == total:  # (no measurement read at all: the reader says so)
        return None
    first_tag = min(landmark, key=lambda tag: groups[tag].numbers[0])
    listing = ", ".join(f"{tag} ×{n}" for tag, n in sorted(landmark.items()))
    return GraphError(
        f"{count} of the file's {total} measurement lines observe landmarks in ways posegraph does not read "
        f"({listing}): without them the rest answers another problem; pass --poses-only "
        "(read_g2o(..., poses_only=True)) to optimise the poses alone",
        path, int(groups[first_tag].numbers[0]),
    )  # fmt: skip


def _lookup(sorted_ids: np.ndarray, order: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(indices, found)``: where each of ``wanted`` is among the ids sorted by ``order``."""
    if len(sorted_ids) == 0:
        return np.zeros(len(wanted), np.int64), np.zeros(len(wanted), bool)
    pos = np.clip(np.searchsorted(sorted_ids, wanted), 0, len(sorted_ids) - 1)
    return order[pos], sorted_ids[pos] == wanted


def _vertex_errors(vertices: _Vertices, space_dim: int, path: str) -> list:
    """A duplicate landmark id, on its line."""
    tag = LANDMARK_VERTEX_TAG[space_dim]
    order = np.argsort(vertices.ids, kind="stable")
    sorted_ids = vertices.ids[order]
    repeat = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1]) + 1
    errors = []
    if repeat.size:
        r = repeat[np.argmin(order[repeat])]
        errors.append(GraphError(f"duplicate {tag} id {sorted_ids[r]} (first defined on line "
                                 f"{int(vertices.numbers[order[r - 1]])})", path, int(vertices.numbers[order[r]])))
    return errors


def _own_space_shift(parsed: ParsedLandmarks, pose_ids: np.ndarray, path: str) -> tuple[int, list]:
    """``(shift, notes)``: 0 when the landmark vertex ids are apart from the poses' (g2o's one id space), else
    the power of ten above every id that all landmark ids get (gtsam's ``L(l)``: module docstring)."""
    vertices = parsed.vertices
    clash = np.flatnonzero(np.isin(vertices.ids, pose_ids))
    if not clash.size:
        return 0, []
    named = [f.ids[:, 0 if MEASUREMENT_TAGS[f.tag].kind == "prior" else 1] for f in parsed.families]
    largest = int(np.max(np.concatenate([pose_ids, vertices.ids, *named])))
    shift = 10 ** len(str(largest))
    tag = LANDMARK_VERTEX_TAG[parsed.space_dim]
    note = (f"{path}:{int(vertices.numbers[clash[0]])}: {tag} id {int(vertices.ids[clash[0]])} is also a pose's id "
            f"({clash.size} such): read as gtsam reads it, the landmarks in their own id space, each given the id "
            f"{shift} + its file id (the output names them so)")
    return shift, [note]


def _created_ids(parsed: ParsedLandmarks, pose_ids: np.ndarray, path: str) -> tuple[np.ndarray, int, list]:
    """``(file ids of the landmarks to create, shift, notes)``: the landmarks named by the tags of their own id
    space (:attr:`LandmarkTag.own_ids`) that no vertex line defines, sorted; ``shift`` added to their ids."""
    named = [f.ids[:, 1] for f in parsed.families if MEASUREMENT_TAGS[f.tag].own_ids]
    if not named:
        return np.zeros(0, np.int64), 0, []
    created = np.setdiff1d(np.concatenate(named), parsed.vertices.ids)
    if not np.isin(created, pose_ids).any():
        return created, 0, []
    shift = 10 ** len(str(int(max(pose_ids.max(), created.max()))))
    tags = sorted({f.tag for f in parsed.families if MEASUREMENT_TAGS[f.tag].own_ids})
    note = (f"{path}: the landmark ids of the {', '.join(tags)} lines are their own id space and meet the poses' ids: "
            f"the {created.size} landmarks they name are given the ids {shift} + their file id")
    return created, shift, [note]


def _placed(family: _Family, spec: LandmarkTag, poses: np.ndarray, offsets: np.ndarray | None) -> np.ndarray:
    """``(q, s)`` where each measurement of ``family`` puts its landmark, seen from the pose's value as read:
    ``X O z`` (position), the point at range ``r`` along the bearing (bearing_range, bearing at 1), ``z`` (prior)."""
    if spec.kind == "prior":
        return family.z.copy()
    s = spec.space_dim
    if spec.kind == "position":
        local = family.z
    else:
        theta = family.z[:, 0]
        distance = family.z[:, 1] if spec.kind == "bearing_range" else np.ones(len(theta))
        local = np.stack([distance * np.cos(theta), distance * np.sin(theta)], axis=1)
    pose = poses
    if offsets is not None:
        pose = poses @ offsets
    return np.einsum("qij,qj->qi", pose[:, :s, :s], local) + pose[:, :s, s]


class _Index(NamedTuple):
    """Ids sorted for look-ups."""

    ids: np.ndarray
    order: np.ndarray
    sorted: np.ndarray

    @classmethod
    def of(cls, ids: np.ndarray) -> "_Index":
        order = np.argsort(ids, kind="stable")
        return cls(ids, order, ids[order])

    def find(self, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _lookup(self.sorted, self.order, wanted)


def _offset_matrices(family: _Family, offsets: dict, path: str) -> tuple[np.ndarray | None, G2oFormatError | None]:
    """``(q, 4, 4)`` sensor offsets of a family with parameter ids (None without), or the first undefined id's error."""
    if family.ids.shape[1] < 3:
        return None, None
    out = np.empty((len(family.ids), 4, 4))
    for k, identifier in enumerate(family.ids[:, 2].tolist()):
        if identifier not in offsets:
            return None, G2oFormatError(f"{family.tag} names parameter {identifier}, which no PARAMS_SE3OFFSET line "
                                        "defines", path, int(family.numbers[k]))
        out[k] = offsets[identifier]
    return out, None


def _resolve(family: _Family, landmarks: _Index, poses: _Index, shifts: tuple, vertex_ids: np.ndarray, names: tuple,
             path: str) -> tuple[np.ndarray, np.ndarray, list]:  # fmt: skip
    """``(pose indices (−1 for priors), landmark indices, [errors])`` of one family's measurements;
    ``shifts`` = ``(own space, created)``: added to every landmark id, and to those no vertex line defines."""
    spec = MEASUREMENT_TAGS[family.tag]
    named = family.ids[:, 0 if spec.kind == "prior" else 1]
    own, shift = shifts
    if own:
        named = named + own
    elif spec.own_ids and shift:
        named = np.where(np.isin(named, vertex_ids), named, named + shift)
    landmark, found = landmarks.find(named)
    errors = []
    if not found.all():
        k = int(np.flatnonzero(~found)[0])
        also = " (it is a pose's id)" if np.isin(named[k], poses.ids) else ""
        errors.append(GraphError(f"{family.tag} names landmark {named[k]}, which has no {names[1]}{also}", path,
                                 int(family.numbers[k])))
    if spec.kind == "prior":
        return np.full(len(named), -1, np.int64), landmark, errors
    pose, found = poses.find(family.ids[:, 0])
    if not found.all():
        k = int(np.flatnonzero(~found)[0])
        also = " (it is a landmark's id)" if np.isin(family.ids[k, 0], landmarks.ids) else ""
        errors.append(GraphError(f"{family.tag} names pose {family.ids[k, 0]}, which has no {names[0]}{also}", path,
                                 int(family.numbers[k])))
    return pose, landmark, errors


def assemble_landmarks(parsed: ParsedLandmarks, pose_ids: np.ndarray, poses: np.ndarray, fix: tuple, offsets: dict,
                       pose_names: str, path: str):  # fmt: skip
    """Stage 4: ``(Landmarks, fix ids left for the poses, their lines, warning texts)``.

    ``fix`` = ``(ids, lines)`` of the ``FIX`` lines: those naming landmarks hold them. ``offsets`` the
    ``PARAMS_SE3OFFSET`` matrices by id; ``pose_names`` names the pose vertex tags in messages.
    """
    from posegraph.model.landmarks import Landmarks, Observations  # here: a pose graph never builds them

    s, vertices = parsed.space_dim, parsed.vertices
    raise_first(_vertex_errors(vertices, s, path))
    own, notes = _own_space_shift(parsed, pose_ids, path)
    created, shift, created_notes = _created_ids(parsed, pose_ids if not own else np.zeros(0, np.int64), path)
    shift, notes = (own, notes) if own else (shift, created_notes)
    landmarks, pose_index = _Index.of(np.concatenate([vertices.ids + own, created + shift])), _Index.of(pose_ids)
    names = (pose_names, f"{LANDMARK_VERTEX_TAG[s]} line")
    families, errors, placed = [], [], []
    for family in parsed.families:
        spec = MEASUREMENT_TAGS[family.tag]
        pose, landmark, resolve_errors = _resolve(family, landmarks, pose_index, (own, shift), vertices.ids, names, path)
        offset_matrices, offset_error = _offset_matrices(family, offsets, path)
        errors += resolve_errors + [offset_error]
        if resolve_errors or offset_error is not None:
            continue
        families.append(Observations(
            kind=spec.kind, pose=pose, landmark=landmark, measurements=family.z.copy(), information=family.information,
            offsets=offset_matrices, tag=family.tag, lines=family.numbers.copy(),
            offset_ids=family.ids[:, 2].copy() if offset_matrices is not None else None,
            text=None if own else list(family.rests),  # shifted ids: the lines as read would name the old ones
        ))  # fmt: skip
        if spec.own_ids:
            placed.append((family.numbers, landmark, _placed(family, spec, poses[np.maximum(pose, 0)], offset_matrices)))
    raise_first(errors)
    positions = np.concatenate([vertices.positions, _first_placed(placed, len(vertices.ids), len(created), s)])
    # FIX names a pose where an id is both (g2o's FIX is of poses); with a shift, a landmark by its file id
    named = np.where(np.isin(fix[0], pose_ids), -1, fix[0] + own) if own else fix[0]
    held = np.isin(named, landmarks.ids)
    fixed = np.zeros(len(landmarks.ids), bool)
    fixed[landmarks.find(named[held])[0]] = True
    result = Landmarks(ids=landmarks.ids, positions=positions, observations=tuple(families), fixed=fixed,
                       vertex_tag=LANDMARK_VERTEX_TAG[s])
    # (no warning for the created ones: BR, LANDMARK, POINT3 files have no landmark vertex lines by
    # design; each landmark starts where its first measurement puts it, docs/g2o.md)
    return result, fix[0][~held], fix[1][~held], notes


def _first_placed(placed: list, first: int, count: int, s: int) -> np.ndarray:
    """``(count, s)`` positions of the created landmarks (indices ``first …``), each by its first measurement."""
    out = np.zeros((count, s))
    if not count or not placed:
        return out
    numbers = np.concatenate([p[0] for p in placed])
    landmark = np.concatenate([p[1] for p in placed])
    points = np.concatenate([p[2] for p in placed])
    order = np.lexsort((numbers, landmark))
    head = order[np.r_[True, landmark[order][1:] != landmark[order][:-1]]]
    chosen = head[landmark[head] >= first]
    out[landmark[chosen] - first] = points[chosen]
    return out
