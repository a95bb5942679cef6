"""Files that are landmark graphs rather than pose graphs: refused unless the poses alone are asked for.

posegraph optimises poses; landmark vertices and the measurements of them (g2o's
``VERTEX_TRACKXYZ`` / ``EDGE_SE3_TRACKXYZ``, ``VERTEX_XY`` / ``EDGE_SE2_XY``, TORO's ``LANDMARK2``
and ``BR`` (bearing-range) lines, …) are skipped like any tag it does not read. When such lines are
a large share of a file's measurements, skipping them answers another problem: gtsam's
``victoriaPark_reduced_1k.g2o`` is 999 odometry edges and 606 ``LANDMARK2`` lines — without the
landmarks its poses form a chain, which "converges" at once to cost 0. So a file whose landmark
measurement lines are at least :data:`LANDMARK_SHARE` of its measurement lines (pose edges, priors
and landmark measurements) is refused at its first landmark line, unless the caller asks to
optimise the poses alone (``poses_only=True``, ``--poses-only``): then they are skipped with the
usual warning. Reading a trajectory (``require_edges=False``: ``info``, ``eval``, ``plot``,
``export``) only warns, with the same text.
"""

from __future__ import annotations

from posegraph.errors import GraphError

LANDMARK_VERTEX_TAGS = frozenset({"VERTEX_TRACKXYZ", "VERTEX_XY", "VERTEX_POINTXYZ"})
"""Landmark vertices (not counted as measurements)."""
LANDMARK_MEASUREMENT_TAGS = frozenset({
    "EDGE_SE3_TRACKXYZ", "EDGE_SE3_POINTXYZ", "EDGE_SE2_XY", "EDGE_SE2_POINTXY", "EDGE_BEARING_SE2_XY",
    "EDGE_SE2_XY_CALIB", "LANDMARK2", "BR",
})  # fmt: skip
"""Measurements of landmarks, by g2o (types_slam2d/3d) and TORO-era files (gtsam's ``load2D``)."""
LANDMARK_SHARE = 0.25
"""A file whose landmark measurement lines are at least this share of its measurement lines is refused
(victoriaPark_reduced_1k: 606 of 1,605, 38 %; cityTrees_reduced_1k: 406 of 1,405, 29 %)."""


def landmark_refusal(groups: dict, measurement_tags, poses_only: bool, path: str) -> GraphError | None:
    """The :class:`GraphError` for a landmark graph (module docstring), or None; ``measurement_tags``:
    the tags of the pose edges and priors that posegraph reads."""
    landmark = {tag: len(groups[tag].rests) for tag in LANDMARK_MEASUREMENT_TAGS & groups.keys()}
    if poses_only or not landmark:
        return None
    count = sum(landmark.values())
    total = count + sum(len(groups[tag].rests) for tag in set(measurement_tags) & groups.keys())
    if count < LANDMARK_SHARE * total or count == total:  # (no pose measurement at all: the reader says so)
        return None
    first_tag = min(landmark, key=lambda tag: groups[tag].numbers[0])
    listing = ", ".join(f"{tag} ×{n}" for tag, n in sorted(landmark.items()))
    return GraphError(
        f"{count} of the file's {total} measurement lines observe landmarks ({listing}), which posegraph does not "
        "read: without them the poses answer another problem; pass --poses-only (read_g2o(..., poses_only=True)) "
        "to optimise the poses alone",
        path, int(groups[first_tag].numbers[0]),
    )  # fmt: skip
