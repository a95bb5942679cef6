"""Landmark graphs are read (graph.landmarks); --poses-only skips them; landmark kinds posegraph does not read are
refused when they are most of the file (file:line), as before."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.errors import GraphError
from posegraph.io.g2o import read_g2o
from posegraph.io.g2o_landmarks import LANDMARK_SHARE
from tests.io.helpers import read_with_warnings
from tests.io.test_g2o_read import CHAIN  # 3 vertices (ids 0, 1, 2), 3 edges


def with_landmarks(count):
    lines = [f"EDGE_SE3_TRACKXYZ 0 {10 + k} 0 1 2 3 1 0 0 1 0 1" for k in range(count)]
    return (CHAIN + "\nPARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n"
            + "\n".join([f"VERTEX_TRACKXYZ {10 + k} 1 2 3" for k in range(count)] + lines) + "\n")


def test_a_file_mostly_of_landmark_measurements_is_read(text_file):
    graph, messages = read_with_warnings(text_file(with_landmarks(2)))
    assert graph.num_edges == 3 and graph.landmarks.count == 2 and graph.landmarks.num_measurements == 2
    assert not messages


def test_poses_only_skips_the_landmark_lines_with_the_warning(text_file):
    graph, messages = read_with_warnings(text_file(with_landmarks(2)), poses_only=True)
    assert graph.num_edges == 3 and graph.landmarks is None
    assert any("EDGE_SE3_TRACKXYZ ×2" in m and "VERTEX_TRACKXYZ ×2" in m for m in messages)


def test_a_file_mostly_of_landmark_kinds_not_read_is_refused_at_its_first_such_line(text_file):
    text = CHAIN + "\n" + "\n".join(f"EDGE_PROJECT_DISPARITY 0 {10 + k} 0 1 2 3" for k in range(2)) + "\n"
    assert 2 >= LANDMARK_SHARE * 5
    with pytest.raises(GraphError) as caught:
        read_g2o(text_file(text))
    first = 1 + next(k for k, line in enumerate(text.splitlines()) if line.startswith("EDGE_PROJECT_DISPARITY"))
    assert caught.value.line == first and "--poses-only" in str(caught.value)
    graph, messages = read_with_warnings(text_file(text), poses_only=True)
    assert graph.num_edges == 3 and any("EDGE_PROJECT_DISPARITY ×2" in m for m in messages)


@pytest.mark.parametrize("name, poses, landmarks, tag, count", [
    ("victoriaPark_reduced_1k.g2o", 1000, 48, "LANDMARK2", 606),
    ("example.graph", 95, 24, "BR", 422),
])  # fmt: skip
def test_gtsam_landmark_files_are_read(gtsam_example_file, name, poses, landmarks, tag, count):
    graph, _ = read_with_warnings(gtsam_example_file(name))
    assert graph.num_vertices == poses and graph.landmarks.count == landmarks
    assert [(f.tag, f.count) for f in graph.landmarks.observations] == [(tag, count)]


def test_gtsam_file_whose_landmark_ids_are_pose_ids_is_read_as_gtsam_reads_it(gtsam_example_file):
    """gtsam's known_landmark_localization files give landmarks the ids of poses (gtsam keys them L(id)); g2o
    cannot load them. Read in their own id space (ids + 100 here), every measurement on its landmark."""
    path = gtsam_example_file("known_landmark_localization_20.g2o")
    graph, messages = read_with_warnings(path)
    assert graph.num_vertices == 20 and graph.landmarks.ids.tolist() == [100, 101, 102, 103]
    assert len(messages) == 1 and "own id space" in messages[0] and ":21:" in messages[0]
    (track,) = graph.landmarks.observations
    assert track.count == 80 and track.text is None
    lines = [line.split() for line in open(path) if line.startswith("EDGE_SE3_TRACKXYZ")]
    np.testing.assert_array_equal(track.pose, [int(f[1]) for f in lines])
    np.testing.assert_array_equal(graph.landmarks.ids[track.landmark], [100 + int(f[2]) for f in lines])
    np.testing.assert_allclose(track.measurements, [[float(x) for x in f[4:7]] for f in lines])


def test_reading_a_landmark_graph_as_a_trajectory_reads_its_landmarks_too(text_file):
    graph, messages = read_with_warnings(text_file(with_landmarks(2)), require_edges=False)
    assert graph.num_vertices == 3 and graph.landmarks.count == 2 and not messages
