"""g2o's Sim(3) pose graphs: ``VERTEX_SIM3:EXPMAP`` / ``EDGE_SIM3:EXPMAP`` in both variants, read and written.

Two variants are found in the wild (``docs/g2o.md``), told apart by the number of fields after the tag:

* **current** (the ``g2opy`` wheel, g2o's ``Sim3`` written as its data): a vertex is
  ``id qx qy qz qw x y z s`` (8 after the id), its estimate ``S_i`` world-to-camera
  (``p_c = s R p_w + t``); an edge ``i j qx qy qz qw x y z s`` and the 28 upper-triangular entries
  of the 7×7 information (36 after the ids), its measurement ``S_ji``.
* **classic** (g2o before it, ORB-SLAM's bundled copy): a vertex is ``id`` then the 7-vector
  ``[ω, υ, σ]`` of the camera-to-world similarity ``S_i⁻¹`` in g2o's ``Sim3(Vector7)``
  (:func:`posegraph.lie.sim3.g2o_exp`), then 4 camera numbers (focal lengths, principal point:
  11 after the id); an edge ``i j`` then ``[ω, υ, σ]`` of ``S_ji⁻¹`` and the 28 entries (35).

g2o's ``EdgeSim3`` error is ``e = log(S_ji · S_i · S_j⁻¹)`` in g2o's tangent order ``[ω, υ, σ]``,
with its own first-order ``Sim3::log``. With the project's poses ``X_i = S_i⁻¹`` (world-from-camera)
and ``Z = S_ji⁻¹``, ``S_ji S_i S_j⁻¹ = Z⁻¹ X_i⁻¹ X_j``: the project's residual. g2o's order is
:mod:`posegraph.lie.sim3`'s own, so the information is read unpermuted, and the graph's group is
:data:`~posegraph.lie.group.SIM3_G2O`, whose residuals use g2o's log: the χ² reported is g2o's.
A file is written back in the variant it was read in (:class:`Sim3Format`), camera numbers kept.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from posegraph.errors import G2oFormatError, GraphError, InputWarning, excerpt
from posegraph.model.graph import PoseGraph
from posegraph.io.g2o_checks import (
    check_finite, check_information, check_negative_ids, components_note, quaternion_note, raise_first, topology,
)
from posegraph.io.g2o_format import FIX_TAG, RECORDS, Record, _entry_of_upper, _information_fields
from posegraph.io.g2o_lines import Lines, parse_fix, parse_records
from posegraph.lie import sim3, so3
from posegraph.lie.group import SIM3_G2O

VERTEX_SIM3_TAG = "VERTEX_SIM3:EXPMAP"
EDGE_SIM3_TAG = "EDGE_SIM3:EXPMAP"
SIM3_TAGS = frozenset({VERTEX_SIM3_TAG, EDGE_SIM3_TAG})
CURRENT, CLASSIC = "current", "classic"

QUATERNION_FAR_FROM_UNIT = 1e-3
"""A Sim(3) quaternion whose norm is off 1 by more than this is refused (g2opy writes 6 digits: ~1e-6)."""
DEFAULT_CAMERA = (1.0, 1.0, 0.0, 0.0)
"""g2o's ``VertexSim3Expmap`` camera numbers (focal lengths 1, principal point 0), written for vertices without any."""

_SIM3_FROM_UPPER = _entry_of_upper(7).reshape(-1)
_UPPER_ROWS, _UPPER_COLS = np.triu_indices(7)
_QUATERNION = ("qx", "qy", "qz", "qw", "x", "y", "z", "scale")
_LOG = ("omega_x", "omega_y", "omega_z", "upsilon_x", "upsilon_y", "upsilon_z", "sigma")
_INFO = _information_fields(7)
_FORMATS = {
    (VERTEX_SIM3_TAG, CURRENT): Record(
        "vertex", np.dtype([("id", np.int64), ("q", np.float64, (4,)), ("t", np.float64, (3,)), ("s", np.float64)]),
        ("id",) + _QUATERNION, 1, "quaternion",
    ),
    (VERTEX_SIM3_TAG, CLASSIC): Record(
        "vertex", np.dtype([("id", np.int64), ("xi", np.float64, (7,)), ("camera", np.float64, (4,))]),
        ("id",) + _LOG + ("fx", "fy", "cx", "cy"), 1, "log",
    ),
    (EDGE_SIM3_TAG, CURRENT): Record(
        "edge", np.dtype([("ids", np.int64, (2,)), ("q", np.float64, (4,)), ("t", np.float64, (3,)),
                          ("s", np.float64), ("info", np.float64, (28,))]),
        ("id_from", "id_to") + _QUATERNION + _INFO, 2, "quaternion", _SIM3_FROM_UPPER,
    ),
    (EDGE_SIM3_TAG, CLASSIC): Record(
        "edge", np.dtype([("ids", np.int64, (2,)), ("xi", np.float64, (7,)), ("info", np.float64, (28,))]),
        ("id_from", "id_to") + _LOG + _INFO, 2, "log", _SIM3_FROM_UPPER,
    ),
}  # fmt: skip
"""How each tag's lines are read in each variant."""


@dataclass(frozen=True, eq=False)
class Sim3Format:
    """How a Sim(3) file was written, to write it back the same way."""

    variant: str
    """``"current"`` or ``"classic"`` (module docstring)."""
    camera_ids: np.ndarray
    """``(c,)`` int64: the vertex ids that carried camera numbers (classic files)."""
    cameras: np.ndarray
    """``(c, 4)``: their ``fx fy cx cy``."""


def is_sim3_file(groups: dict[str, Lines]) -> bool:
    """Whether the file holds Sim(3) lines (then :func:`read_sim3` reads it)."""
    return not SIM3_TAGS.isdisjoint(groups)


def read_sim3(
    groups: dict[str, Lines], first_line: dict[str, int], path: str, source: str | None, *, require_edges: bool,
    repair_information: bool,
) -> PoseGraph:  # fmt: skip
    """The Sim(3) graph of a file's lines grouped by tag (:func:`posegraph.io.g2o_lines.group_lines`).

    Checked in the reader's stages (``docs/g2o.md``): the tags (no SE(3)/SE(2) lines beside Sim(3)
    ones), each line's field count (the variant) and syntax, the values, an empty graph, the graph.
    """
    empty = Lines(np.zeros(0, dtype=np.int64), [])
    _refuse_other_pose_tags(groups, first_line, path)
    variant = _variant(groups, first_line, path)
    lines = {tag: groups.get(tag, empty) for tag in (VERTEX_SIM3_TAG, EDGE_SIM3_TAG)}
    records = _parse(lines, variant, path)
    fix_ids, fix_numbers, fix_error = parse_fix(groups.get(FIX_TAG, empty), path)
    raise_first([fix_error])
    poses, measurements, information, notes = _values(records, lines, variant, path, repair_information)
    vertices, edges = records[VERTEX_SIM3_TAG], records[EDGE_SIM3_TAG]
    _refuse_empty(len(vertices), len(edges), require_edges, path)
    edge_index, fixed = topology(
        vertices["id"], lines[VERTEX_SIM3_TAG].numbers, edges["ids"], lines[EDGE_SIM3_TAG].numbers, fix_ids,
        fix_numbers, path, f"{VERTEX_SIM3_TAG} line",
    )  # fmt: skip
    cameras = vertices["camera"] if variant == CLASSIC else np.zeros((0, 4))
    graph = PoseGraph(
        ids=vertices["id"].copy(), poses=poses, edge_from=edge_index[:, 0].copy(), edge_to=edge_index[:, 1].copy(),
        measurements=measurements, information=information, fixed=fixed, source=source,
        edge_lines=lines[EDGE_SIM3_TAG].numbers.copy(), group=SIM3_G2O,
        file_format=Sim3Format(variant, vertices["id"][: len(cameras)].copy(), np.array(cameras)),
    )  # fmt: skip
    notes = _skipped_note(groups, first_line, path) + notes + (components_note(graph, path) if graph.num_edges else [])
    for note in notes:
        warnings.warn(note, InputWarning, stacklevel=4)
    return graph


def _refuse_other_pose_tags(groups: dict[str, Lines], first_line: dict[str, int], path: str) -> None:
    """A Sim(3) edge naming an SE(3)/SE(2) vertex, or else the first SE(3)/SE(2) line, is an error."""
    others = sorted(RECORDS.keys() & groups.keys(), key=lambda tag: first_line[tag])
    if not others:
        return
    rigid = {}
    for tag in others:
        if RECORDS[tag].kind == "vertex":
            for number, rest in zip(groups[tag].numbers.tolist(), groups[tag].rests):
                rigid.setdefault(rest.split(None, 1)[0] if rest.strip() else "", (tag, number))
    edges = groups.get(EDGE_SIM3_TAG)
    for number, rest in zip(edges.numbers.tolist(), edges.rests) if edges else ():
        for token in rest.split()[:2]:
            if token in rigid:
                tag, line = rigid[token]
                raise GraphError(
                    f"{EDGE_SIM3_TAG} names vertex {excerpt(token, quoted=False)}, a {tag} (line {line}): a Sim(3) edge joins "
                    f"{VERTEX_SIM3_TAG} vertices only", path, number,
                )  # fmt: skip
    first_sim3 = min(first_line[tag] for tag in SIM3_TAGS & groups.keys())
    raise G2oFormatError(
        f"{others[0]} in a file of Sim(3) lines (line {first_sim3}): a pose graph holds one group, and "
        "posegraph reads SE(3), SE(2) or Sim(3) files", path, first_line[others[0]],
    )  # fmt: skip


def _field_count(tag: str, variant: str) -> int:
    return len(_FORMATS[tag, variant].fields)


def _variant(groups: dict[str, Lines], first_line: dict[str, int], path: str) -> str:
    """The variant of the file's first Sim(3) line; every other line must have that variant's field count."""
    present = sorted(SIM3_TAGS & groups.keys(), key=lambda tag: first_line[tag])
    variant = None
    for tag in present:
        counts = np.array([len(rest.split()) for rest in groups[tag].rests])
        if variant is None:
            variant = CURRENT if counts[0] == _field_count(tag, CURRENT) else CLASSIC
        bad = np.flatnonzero(counts != _field_count(tag, variant))
        if bad.size:
            raise G2oFormatError(_count_reason(tag, variant, int(counts[bad[0]])), path, int(groups[tag].numbers[bad[0]]))
    return variant or CURRENT


def _count_reason(tag: str, variant: str, found: int) -> str:
    current, classic = _FORMATS[tag, CURRENT].fields, _FORMATS[tag, CLASSIC].fields
    if found in (len(current), len(classic)) and found != _field_count(tag, variant):
        return (f"{tag} line in the {CLASSIC if variant == CURRENT else CURRENT} variant ({found} fields) in a file "
                f"whose first Sim(3) line is in the {variant} one: a file holds one variant")  # fmt: skip
    return (
        f"{tag} needs {len(current)} fields after the tag (current g2o: {' '.join(current[:10])}…) or "
        f"{len(classic)} (classic: {' '.join(classic[:9])}…), found {found}"
    )


def _parse(lines: dict[str, Lines], variant: str, path: str) -> dict[str, np.ndarray]:
    records, errors = {}, []
    for tag, group in lines.items():
        records[tag], error = parse_records(group, tag, _FORMATS[tag, variant], path)
        errors.append(error)
    raise_first(errors)
    raise_first([check_negative_ids(records[VERTEX_SIM3_TAG]["id"], lines[VERTEX_SIM3_TAG].numbers, VERTEX_SIM3_TAG, path)])
    return records


def _values(records, lines, variant: str, path: str, repair_information: bool):
    """``(poses X_i, measurements Z, information, notes)``, the first bad value raised."""
    errors, quaternions = [], []
    matrices = {}
    for tag in (VERTEX_SIM3_TAG, EDGE_SIM3_TAG):
        record, numbers = _FORMATS[tag, variant], lines[tag].numbers
        errors.append(check_finite(records[tag], numbers, tag, record.fields, path))
        if variant == CURRENT:
            errors += [_check_scales(records[tag]["s"], numbers, tag, path), _check_quaternions(records[tag]["q"], numbers, tag, path)]
            quaternions.append(records[tag]["q"])
        else:
            errors.append(_check_log_scales(records[tag]["xi"][:, 6], numbers, tag, path))
    raise_first(errors)
    for tag in (VERTEX_SIM3_TAG, EDGE_SIM3_TAG):
        matrices[tag] = _camera_to_world(records[tag], variant)
    edges = records[EDGE_SIM3_TAG]
    information = edges["info"][:, _SIM3_FROM_UPPER].reshape(-1, 7, 7)
    tags = np.full(len(edges), EDGE_SIM3_TAG, dtype=object)
    information, info_error, notes = check_information(information, lines[EDGE_SIM3_TAG].numbers, tags, path, repair=repair_information)
    raise_first([info_error])
    if quaternions:
        notes = quaternion_note(quaternions, [lines[tag].numbers for tag in (VERTEX_SIM3_TAG, EDGE_SIM3_TAG)], path) + notes
    return matrices[VERTEX_SIM3_TAG], matrices[EDGE_SIM3_TAG], information, notes


def _check_scales(s: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> G2oFormatError | None:
    bad = np.flatnonzero(~(s > 0.0))
    if bad.size == 0:
        return None
    return G2oFormatError(f"{tag} scale is {float(s[bad[0]])!r}; a similarity's scale must be > 0", path, int(numbers[bad[0]]))


MAX_LOG_SCALE = 700.0
"""A classic line's σ beyond ±this makes ``e^σ`` overflow (or vanish) in double precision: refused."""


def _check_log_scales(sigma: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> G2oFormatError | None:
    bad = np.flatnonzero(np.abs(sigma) > MAX_LOG_SCALE)  # NaN compares False: reported as non-finite
    if bad.size == 0:
        return None
    return G2oFormatError(
        f"{tag} log-scale σ is {float(sigma[bad[0]])!r}: its scale e^σ is not a finite positive number", path,
        int(numbers[bad[0]]),
    )  # fmt: skip


def _check_quaternions(q: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> G2oFormatError | None:
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_FAR_FROM_UNIT))
    if bad.size == 0:
        return None
    k = bad[0]
    return G2oFormatError(
        f"{tag} quaternion (qx qy qz qw) = {tuple(q[k].tolist())} has norm {norm[k]:.9g}: more than "
        f"{QUATERNION_FAR_FROM_UNIT:g} from 1, it is not a rotation", path, int(numbers[k]),
    )  # fmt: skip


def _camera_to_world(records: np.ndarray, variant: str) -> np.ndarray:
    """``(k, 4, 4)``: a vertex's ``X = S⁻¹`` or an edge's ``Z = S_ji⁻¹`` (module docstring)."""
    if variant == CLASSIC:
        return sim3.g2o_exp(records["xi"])  # the file holds the camera-to-world log already
    q = records["q"] / np.linalg.norm(records["q"], axis=1, keepdims=True)
    S = sim3.from_rotation_translation_scale(so3.from_quaternion(q), records["t"], records["s"])
    return sim3.inverse(S)


def _refuse_empty(n: int, m: int, require_edges: bool, path: str) -> None:
    if n == 0:
        raise GraphError(f"the file has no {VERTEX_SIM3_TAG} lines: its Sim(3) edges give no poses to read", path)
    if m == 0 and require_edges:
        raise GraphError(f"the file has no {EDGE_SIM3_TAG} lines: there is nothing to optimise", path)


def _skipped_note(groups: dict[str, Lines], first_line: dict[str, int], path: str) -> list[str]:
    skipped = {tag: len(group.rests) for tag, group in groups.items() if tag not in SIM3_TAGS | {FIX_TAG}}
    if not skipped:
        return []
    listing = ", ".join(f"{excerpt(tag, quoted=False)} ×{count}" for tag, count in sorted(skipped.items()))
    first = min(first_line[tag] for tag in skipped)
    return [f"{path}:{first}: skipped {sum(skipped.values())} line(s) with tags posegraph does not read: {listing}"]


# --- writing -----------------------------------------------------------------------------------


def format_sim3(graph: PoseGraph, poses: np.ndarray) -> str:
    """The g2o text of a Sim(3) ``graph`` at ``poses (n, 4, 4)``, in the variant it was read in (current if
    it was not read from a file), camera numbers kept; floats as ``repr`` (they read back exactly)."""
    form = graph.file_format if isinstance(graph.file_format, Sim3Format) else None
    variant = form.variant if form is not None else CURRENT
    vertex_values = _values_of(poses, variant)
    if variant == CLASSIC:
        vertex_values = np.concatenate([vertex_values, _cameras(graph, form)], axis=1)
    line = VERTEX_SIM3_TAG + " %d" + " %r" * vertex_values.shape[1] + "\n"
    parts = [line % (i, *v) for i, v in zip(graph.ids.tolist(), vertex_values.tolist())]
    parts += [f"{FIX_TAG} {i}\n" for i in graph.ids[graph.fixed].tolist()]
    edge_values = np.concatenate([_values_of(graph.measurements, variant), graph.information[:, _UPPER_ROWS, _UPPER_COLS]], axis=1)
    line = EDGE_SIM3_TAG + " %d %d" + " %r" * edge_values.shape[1] + "\n"
    ends = zip(graph.ids[graph.edge_from].tolist(), graph.ids[graph.edge_to].tolist(), edge_values.tolist())
    parts += [line % (i, j, *v) for i, j, v in ends]
    return "".join(parts)


def _values_of(camera_to_world: np.ndarray, variant: str) -> np.ndarray:
    """Per pose, the numbers a line holds: classic ``[ω, υ, σ]`` that g2o's ``Sim3(Vector7)`` maps to it;
    current ``qx qy qz qw x y z s`` of its inverse (world-to-camera for a vertex, ``S_ji`` for an edge)."""
    if variant == CLASSIC:
        return sim3.g2o_exp_inverse(camera_to_world)
    S = sim3.inverse(camera_to_world)
    s = sim3.scale(S)
    return np.concatenate([so3.to_quaternion(S[:, :3, :3] / s[:, None, None]), S[:, :3, 3], s[:, None]], axis=1)


def _cameras(graph: PoseGraph, form: Sim3Format | None) -> np.ndarray:
    """``(n, 4)`` camera numbers per vertex: as read, g2o's defaults for vertices that had none."""
    cameras = np.broadcast_to(np.array(DEFAULT_CAMERA), (graph.num_vertices, 4)).copy()
    if form is not None and len(form.camera_ids):
        known = np.isin(form.camera_ids, graph.ids)
        cameras[graph.index_of(form.camera_ids[known])] = form.cameras[known]
    return cameras
