"""Landmark graphs are refused (file:line) unless the poses alone are asked for (poses_only / --poses-only)."""

from __future__ import annotations

import pytest

from posegraph.errors import GraphError
from posegraph.io.g2o import read_g2o
from posegraph.io.g2o_landmarks import LANDMARK_SHARE
from tests.io.helpers import read_with_warnings
from tests.io.test_g2o_read import CHAIN  # 3 vertices, 3 edges


def with_landmarks(count):
    lines = [f"EDGE_SE3_TRACKXYZ 0 {10 + k} 0 1 2 3 1 0 0 1 0 1" for k in range(count)]
    return CHAIN + "\n" + "\n".join([f"VERTEX_TRACKXYZ {10 + k} 1 2 3" for k in range(count)] + lines) + "\n"


def test_a_file_mostly_of_landmark_measurements_is_refused_at_its_first_landmark_line(text_file):
    path = text_file(with_landmarks(2))  # 2 of 5 measurement lines
    assert 2 >= LANDMARK_SHARE * 5
    with pytest.raises(GraphError) as caught:
        read_g2o(path)
    lines = path.read_text().splitlines()
    assert caught.value.line == 1 + next(k for k, line in enumerate(lines) if line.startswith("EDGE_SE3_TRACKXYZ"))
    assert "2 of the file's 5 measurement lines" in str(caught.value) and "--poses-only" in str(caught.value)
    graph, messages = read_with_warnings(path, poses_only=True)
    assert graph.num_edges == 3 and any("EDGE_SE3_TRACKXYZ ×2" in m for m in messages)


def test_a_few_landmark_lines_are_skipped_with_a_warning(text_file):
    text = CHAIN + "\n" + "\n".join(f"EDGE_SE3:QUAT 0 {j} 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
                                    for j in (1, 2) * 3) + "\nEDGE_SE3_TRACKXYZ 0 10 0 1 2 3 1 0 0 1 0 1\n"
    graph, messages = read_with_warnings(text_file(text))  # 1 of 10 measurement lines
    assert graph.num_edges == 9 and any("EDGE_SE3_TRACKXYZ ×1" in m for m in messages)


@pytest.mark.parametrize("name", ["victoriaPark_reduced_1k.g2o", "example.graph", "known_landmark_localization_20.g2o"])
def test_gtsam_landmark_files_are_refused(gtsam_example_file, name):
    with pytest.raises(GraphError, match="--poses-only"):
        read_g2o(gtsam_example_file(name))


def test_reading_a_landmark_graph_as_a_trajectory_warns_instead(text_file):
    """info, eval, plot and export read poses (require_edges=False): the same text, as a warning."""
    graph, messages = read_with_warnings(text_file(with_landmarks(2)), require_edges=False)
    assert graph.num_vertices == 3 and any("observe landmarks" in m and "--poses-only" in m for m in messages)
