"""Putting a batch's landmarks and landmark measurements into the graph.

New landmarks are placed from their measurements given the poses, as a new pose is placed by the edge
that reaches it: :func:`posegraph.init.landmarks.initialize_landmarks` on the new landmarks alone. A new
landmark with exactly one measurement, a position or a bearing-range, lands where it says: zero residual,
so the estimate stays at the optimum with no solve (a landmark seen for the first time). Every other
measurement (a landmark seen again, a second sighting in the same batch, a bearing, a point prior, a
``FIX`` landmark) needs a solve.

Gauge: a landmark joins the poses that see it (each new sighting joins its pose to the landmark's first
observer in :class:`~posegraph.incremental.components.Components`), and a ``FIX`` landmark or a point
prior anchors the component of the poses seeing it, as a prior does.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import GraphError
from posegraph.init.landmarks import initialize_landmarks
from posegraph.model.graph import PoseGraph
from posegraph.model.landmarks import Landmarks, Observations

__all__ = ["check_placeable", "commit_landmarks", "rejoin_through_landmarks"]

EXACT_KINDS = ("position", "bearing_range")
"""Kinds of which one measurement determines a point exactly (a bearing gives a ray)."""


def check_placeable(batch) -> None:
    """``GraphError`` naming the first staged landmark with no position and no measurement in its batch."""
    measured = set()
    for _, _, _, landmarks, *_ in batch.landmark_measurements:
        measured.update(landmarks.tolist())
    for ids, positions, _ in batch.landmarks:
        for landmark, position in zip(ids.tolist(), positions):
            if np.isnan(position).any() and landmark not in measured:
                raise GraphError(f"landmark id {landmark}: no position given and no measurement of it in the batch")


def commit_landmarks(opt, batch) -> tuple[list[int], bool]:
    """Add ``batch``'s landmarks and measurements to ``opt`` (poses committed already).

    Returns ``(released, work)``: the pose indices whose anchor a landmark released, and whether any
    measurement needs a solve (module docstring).
    """
    store = opt._landmarks
    first_new = store.count
    if batch.landmarks:
        ids, positions, fixed = (np.concatenate(x) for x in zip(*batch.landmarks))
        store.add(ids, positions, fixed)
    rows = [_append(opt, *staged) for staged in batch.landmark_measurements]
    exact = _place_new(opt, first_new, rows)
    released = _join(opt, rows)
    return released, any(not _all_exact(landmark, exact, first_new) for _, _, landmark in rows)


def _all_exact(landmark: np.ndarray, exact: np.ndarray, first_new: int) -> bool:
    """Whether every measurement of ``landmark`` ``(q,)`` placed its (new) landmark exactly."""
    return bool(np.all(landmark >= first_new) and np.all(exact[landmark - first_new]))


def _append(opt, kind, tag, pose_ids, landmark_ids, z, w, offsets, keys):
    """One staged family appended; ``(family, new rows (slice), their landmark indices)``."""
    poses = np.full(pose_ids.shape[0], -1, np.int64) if kind == "prior" else opt._store.indices_of(pose_ids, "landmark measurement")
    landmarks = opt._landmarks.indices_of(landmark_ids, "landmark measurement")
    family = opt._landmarks.family(kind, tag)
    start = family.count
    family.extend(poses, landmarks, z, w, offsets, keys)
    opt._landmarks.next_key += keys.shape[0]
    return family, slice(start, family.count), landmarks


def _place_new(opt, first_new: int, rows) -> np.ndarray:
    """Place the landmarks from ``first_new`` on from their new measurements; ``(a,)`` bool: placed exactly."""
    store = opt._landmarks
    count = store.count - first_new
    if count == 0:
        return np.zeros(0, dtype=bool)
    families, sightings = [], np.zeros(count, np.int64)
    exact_kind = np.ones(count, dtype=bool)
    for family, new, landmark in rows:
        mine = landmark >= first_new
        if not mine.any():
            continue
        local = landmark[mine] - first_new
        np.add.at(sightings, local, 1)
        exact_kind[local] &= family.kind in EXACT_KINDS
        offsets = None if family.offsets is None else family.offsets.view[new][mine]
        families.append(Observations(family.kind, family.pose.view[new][mine], local, family.measurements.view[new][mine],
                                     family.information.view[new][mine], offsets))
    given = store.positions.view[first_new:]
    fixed = store.fixed.view[first_new:]
    s = opt._store
    graph = PoseGraph(ids=s.ids.view, poses=s.poses.view, edge_from=np.zeros(0, np.int64), edge_to=np.zeros(0, np.int64),
                      measurements=s.measurements.view[:0], information=s.information.view[:0], group=opt.group,
                      landmarks=Landmarks(store.ids.view[first_new:], np.nan_to_num(given), tuple(families), fixed))
    points, undetermined = initialize_landmarks(graph, s.poses.view)
    keep_given = fixed | (undetermined & ~np.isnan(given).any(axis=1))
    given[:] = np.where(keep_given[:, None], given, points)
    return ~fixed & (sightings == 1) & exact_kind


def _join(opt, rows) -> list[int]:
    """Components joined through the new measurements; the anchors released."""
    store, components = opt._landmarks, opt._components
    ids, fixed = opt._store.ids.view, opt._store.fixed.view
    released: list[int] = []
    for family, new, landmark in rows:
        for p, l in zip(family.pose.view[new].tolist(), landmark.tolist()):
            released += _sighting(store, components, p, l, ids, fixed)
    return released


def _sighting(store, components, pose: int, landmark: int, ids, fixed) -> list[int]:
    """Pose ``pose`` (−1: a point prior) measures ``landmark``: the anchors this releases."""
    first = int(store.first_pose.data[landmark])
    if pose < 0:  # a prior ties the landmark, and through it the poses that see it
        store.tied.data[landmark] = True
        return components.anchor_by_prior(first, fixed) if first >= 0 else []
    if first < 0:
        store.first_pose.data[landmark] = pose
        return components.anchor_by_prior(pose, fixed) if store.tied.data[landmark] else []
    return components.join(pose, first, ids, fixed)


def rejoin_through_landmarks(opt) -> list[int]:
    """After :meth:`Components.rebuild` (edges removed): the joins and anchors the landmarks make; the anchors released."""
    store, components = opt._landmarks, opt._components
    ids, fixed = opt._store.ids.view, opt._store.fixed.view
    released: list[int] = []
    pose, landmark = store.observed_pairs()
    first = store.first_pose.view
    for p, l in zip(pose.tolist(), landmark.tolist()):
        released += components.join(p, int(first[l]), ids, fixed)
    for l in np.flatnonzero(store.tied.view & (first >= 0)).tolist():
        released += components.anchor_by_prior(int(first[l]), fixed)
    return released
