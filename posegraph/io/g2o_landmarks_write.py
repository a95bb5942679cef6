"""Writing a graph's landmarks (:class:`~posegraph.model.landmarks.Landmarks`) as g2o lines.

After the pose graph's lines and the priors, in a fixed order: one landmark vertex line per landmark
(``VERTEX_XY l x y`` / ``VERTEX_TRACKXYZ l x y z``, the current ``positions``), one ``FIX l`` per held
landmark, the ``PARAMS_SE3OFFSET`` lines the measurements need that the priors did not write, then each
measurement family in the order read. A family's lines are copied as read (``Observations.text``, trailing
blanks dropped) while that text still reads back to exactly its arrays (ids, measurements, information
and parameter ids, compared bit for bit by parsing it again); otherwise they are formatted with ``repr``
floats, as the pose lines are. Output tags are g2o's (``EDGE_SE2_XY``, ``EDGE_BEARING_SE2_XY``,
``EDGE_PRIOR_XY``, ``EDGE_POINTXYZ_PRIOR``, ``EDGE_SE3_TRACKXYZ``): iSAM's ``LANDMARK``/``POINT3`` and
``LANDMARK2`` lines come out as ``EDGE_SE2_XY``/``EDGE_SE3_TRACKXYZ`` with information (``Ω``, not its
square root), and landmark vertex lines. gtsam's ``BR`` has no g2o tag and stays ``BR`` (standard
deviations ``1/√Ω`` of a diagonal Ω).
"""

from __future__ import annotations

import numpy as np

from posegraph.io.g2o_format import pose_values
from posegraph.io.g2o_isam import information_of, upper_from_symmetric
from posegraph.io.g2o_landmarks import LANDMARK_VERTEX_TAG, MEASUREMENT_TAGS
from posegraph.io.g2o_lines import Lines, parse_records
from posegraph.model.landmarks import Landmarks, Observations

PARAMS_TAG = "PARAMS_SE3OFFSET"
OUTPUT_TAG = {("position", 2): "EDGE_SE2_XY", ("position", 3): "EDGE_SE3_TRACKXYZ", ("bearing", 2): "EDGE_BEARING_SE2_XY",
              ("prior", 2): "EDGE_PRIOR_XY", ("prior", 3): "EDGE_POINTXYZ_PRIOR", ("bearing_range", 2): "BR"}
"""The tag each kind of measurement is written as, per space dimension."""


def format_landmarks(graph) -> list[str]:
    """The landmark lines of ``graph`` (``"TAG fields"``, no newline; none for a graph without landmarks)."""
    landmarks: Landmarks | None = graph.landmarks
    if landmarks is None:
        return []
    s = landmarks.space_dim
    vertex_tag = LANDMARK_VERTEX_TAG[s]
    lines = [f"{vertex_tag} {i} " + " ".join(map(repr, p)) for i, p in zip(landmarks.ids.tolist(), landmarks.positions.tolist())]
    lines += [f"FIX {i}" for i in landmarks.ids[landmarks.fixed].tolist()]
    written = dict(graph.priors.offsets) if graph.priors is not None and len(graph.priors) else {}
    parameters, new = _parameter_ids(landmarks.observations, written)
    lines += [f"{PARAMS_TAG} {i} " + " ".join(map(repr, pose_values(m[None], False)[0].tolist()))
              for i, m in sorted(new.items())]
    for family, parameter_ids in zip(landmarks.observations, parameters):
        tag = OUTPUT_TAG[(family.kind, s)]
        if tag == family.tag and _text_states(family, graph.ids, landmarks.ids):
            lines += [f"{tag} {rest.rstrip()}" for rest in family.text]
        else:
            lines += _formatted(family, tag, graph.ids, landmarks.ids, parameter_ids)
    return lines


def _parameter_ids(families, written: dict) -> tuple[list, dict]:
    """``(per family its parameter ids or None, {id: offset} to write)``: the ids read where there are, else the id
    of an equal offset already defined, else a new one (the identity for a family without offsets)."""
    known = dict(written)
    for family in families:
        if family.offset_ids is not None and family.offsets is not None:
            for i, m in zip(family.offset_ids.tolist(), family.offsets):
                known.setdefault(i, m)
    out = []
    for family in families:
        if family.kind != "position" or family.measurements.shape[1] != 3:
            out.append(None)
        elif family.offset_ids is not None:
            out.append(family.offset_ids)
        else:
            offsets = family.offsets if family.offsets is not None else np.broadcast_to(np.eye(4), (family.count, 4, 4))
            out.append(np.array([_id_of(m, known) for m in offsets], dtype=np.int64))
    return out, {i: m for i, m in known.items() if i not in written}


def _id_of(matrix: np.ndarray, known: dict) -> int:
    """The id of an offset equal to ``matrix`` in ``known``, or a new one added to it."""
    for i, m in known.items():
        if np.array_equal(m, matrix):
            return i
    new = max(known, default=-1) + 1
    known[new] = np.array(matrix)
    return new


def _text_states(family: Observations, pose_ids: np.ndarray, landmark_ids: np.ndarray) -> bool:
    """Whether the family's lines as read still state its arrays exactly (parsed again and compared)."""
    spec = MEASUREMENT_TAGS.get(family.tag)
    if family.text is None or spec is None or spec.entries == "isam" or len(family.text) != family.count:
        return False
    records, error = parse_records(Lines(np.arange(1, family.count + 1), family.text), family.tag, spec.record, "")
    if error is not None:
        return False
    size = family.measurements.shape[1]
    try:
        with np.errstate(all="ignore"):
            omega = information_of(records["info"], size, spec.entries, np.arange(family.count), family.tag, "")
    except ValueError:  # a standard deviation ≤ 0: not what was read
        return False
    ids = [landmark_ids[family.landmark]] if family.unary else [pose_ids[family.pose], landmark_ids[family.landmark]]
    if family.offset_ids is not None:
        ids.append(family.offset_ids)
    return (np.array_equal(records["ids"], np.stack(ids, axis=1)) and np.array_equal(records["z"], family.measurements)
            and np.array_equal(omega, family.information))


def _formatted(family: Observations, tag: str, pose_ids, landmark_ids, parameter_ids) -> list[str]:
    """The family's lines formatted from its arrays (``repr`` floats)."""
    heads = [str(i) for i in landmark_ids[family.landmark].tolist()]
    if not family.unary:
        heads = [f"{p} {h}" for p, h in zip(pose_ids[family.pose].tolist(), heads)]
    if parameter_ids is not None:
        heads = [f"{h} {p}" for h, p in zip(heads, parameter_ids.tolist())]
    if family.kind == "bearing_range":
        off_diagonal = family.information[:, 0, 1]
        if np.any(off_diagonal != 0):
            raise ValueError(f"{tag} lines hold standard deviations: a bearing-range information with a "
                             "correlation cannot be written")
        noise = 1.0 / np.sqrt(np.diagonal(family.information, axis1=1, axis2=2))
    else:
        noise = upper_from_symmetric(family.information)
    return [f"{tag} {h} " + " ".join(map(repr, z + n)) for h, z, n in
            zip(heads, family.measurements.tolist(), noise.tolist())]
