"""g2o's prior lines (EDGE_SE3_PRIOR with PARAMS_SE3OFFSET, EDGE_SE3_XYZ_PRIOR, EDGE_PRIOR_SE2,
EDGE_PRIOR_SE2_XY): values as read, round trips through the writer, bad lines (file:line)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o import format_g2o, read_g2o
from tests.io.helpers import read_with_warnings
from tests.io.test_g2o_read import CHAIN, rotation_from_xyzw

INFO6 = [float(v) for v in np.diag([10.0, 20, 30, 40, 50, 60])[np.triu_indices(6)]]
INFO6[1] = 0.5  # (t_x, t_y): a coupling that the permutation must carry to [ω; v] rows 3, 4
OFFSET = (0.1, -0.2, 0.3, 0.1, 0.2, 0.3, 0.9)
PRIORS_3D = "\n".join([
    "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1",
    "PARAMS_SE3OFFSET 7 " + " ".join(map(str, OFFSET)),
    "EDGE_SE3_PRIOR 1 7 1 2 3 0.1 0.1 0.1 0.98 " + " ".join(map(repr, INFO6)),
    "EDGE_SE3_XYZ_PRIOR 2 0 4 5 6 2 0.1 0 3 0.2 4",
    "EDGE_SE3_XYZ_PRIOR 0 0 -1 0 0.5 1 0 0 1 0 1",
])
CHAIN_2D = "\n".join([
    "VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0.5", "VERTEX_SE2 2 1 1 1",
    "EDGE_SE2 0 1 1 0 0.5 1 0 0 1 0 1", "EDGE_SE2 1 2 0.5 0.5 0.5 1 0 0 1 0 1",
])
PRIORS_2D = "\n".join([
    "EDGE_PRIOR_SE2 1 1.1 0.1 0.4 10 1 0 10 0 5",
    "EDGE_PRIOR_SE2_XY 2 1 1.2 3 0.5 4",
    "EDGE_PRIOR_SE2_XY 0 0.1 -0.1 1 0 1",
])


def test_3d_priors_read_with_offsets_and_permuted_information(text_file):
    graph, messages = read_with_warnings(text_file(CHAIN + "\n" + PRIORS_3D + "\n"))
    assert messages == []
    priors = graph.priors
    assert priors.pose_vertex.tolist() == [1] and priors.position_vertex.tolist() == [2, 0]
    np.testing.assert_allclose(priors.pose_measurements[0, :3, :3], rotation_from_xyzw((0.1, 0.1, 0.1, 0.98)))
    np.testing.assert_array_equal(priors.pose_measurements[0, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(priors.pose_offsets[0, :3, :3], rotation_from_xyzw(OFFSET[3:]))
    np.testing.assert_array_equal(priors.pose_offsets[0, :3, 3], OFFSET[:3])
    # g2o's [t; R] diag(10..60) with t_x t_y = 0.5 becomes [ω; v] diag(40, 50, 60, 10, 20, 30)
    information = priors.pose_information[0]
    np.testing.assert_array_equal(np.diag(information), [40, 50, 60, 10, 20, 30])
    assert information[3, 4] == information[4, 3] == 0.5
    np.testing.assert_array_equal(priors.position_measurements, [[4, 5, 6], [-1, 0, 0.5]])
    np.testing.assert_array_equal(priors.position_information[0], [[2, 0.1, 0], [0.1, 3, 0.2], [0, 0.2, 4]])
    assert priors.pose_lines.tolist() == [10] and priors.position_lines.tolist() == [11, 12]


def test_2d_priors_read(text_file):
    graph, messages = read_with_warnings(text_file(CHAIN_2D + "\n" + PRIORS_2D + "\n"))
    assert messages == []
    priors = graph.priors
    assert priors.pose_vertex.tolist() == [1] and priors.position_vertex.tolist() == [2, 0]
    np.testing.assert_allclose(priors.pose_measurements[0], [[np.cos(0.4), -np.sin(0.4), 1.1],
                                                             [np.sin(0.4), np.cos(0.4), 0.1], [0, 0, 1]])
    np.testing.assert_array_equal(priors.pose_information[0], [[10, 1, 0], [1, 10, 0], [0, 0, 5]])
    np.testing.assert_array_equal(priors.position_information[0], [[3, 0.5], [0.5, 4]])


@pytest.mark.parametrize("text", [CHAIN + "\n" + PRIORS_3D, CHAIN_2D + "\n" + PRIORS_2D], ids=["3D", "2D"])
def test_writer_writes_the_prior_lines_back_unchanged(text_file, text):
    graph = read_g2o(text_file(text + "\n"))
    written = format_g2o(graph).splitlines()
    prior_lines = [line for line in text.splitlines() if "PRIOR" in line or "PARAMS" in line]
    assert written[-len(prior_lines):] == prior_lines  # parameters first, then the priors in file order
    again = read_g2o(text_file(format_g2o(graph), name="again.g2o"))
    assert again.priors.checksum(again.ids) == graph.priors.checksum(graph.ids)


@pytest.mark.parametrize("text", [CHAIN + "\n" + PRIORS_3D, CHAIN_2D + "\n" + PRIORS_2D], ids=["3D", "2D"])
def test_changed_priors_are_formatted_and_read_back(text_file, text):
    graph = read_g2o(text_file(text + "\n"))
    moved = graph.priors.position_measurements + 0.25
    changed = replace(graph, priors=replace(graph.priors, position_measurements=moved))
    written = format_g2o(changed)
    assert written != format_g2o(graph)
    back = read_g2o(text_file(written, name="back.g2o")).priors
    np.testing.assert_array_equal(back.position_measurements, moved)
    np.testing.assert_allclose(back.pose_measurements, graph.priors.pose_measurements, atol=1e-15)
    np.testing.assert_allclose(back.pose_offsets, graph.priors.pose_offsets, atol=1e-15)
    np.testing.assert_array_equal(back.pose_information, graph.priors.pose_information)
    np.testing.assert_array_equal(back.position_information, graph.priors.position_information)


BAD_3D = [
    ("EDGE_SE3_XYZ_PRIOR 2 0 4 5 6 2 0.1 0 3 0.2", G2oFormatError, "needs 11 fields"),
    ("EDGE_SE3_XYZ_PRIOR 9 0 4 5 6 2 0.1 0 3 0.2 4", GraphError, "names vertex 9"),
    ("EDGE_SE3_XYZ_PRIOR 2 3 4 5 6 2 0.1 0 3 0.2 4", G2oFormatError, "names parameter 3"),
    ("EDGE_SE3_XYZ_PRIOR 2 0 4 5 nan 2 0.1 0 3 0.2 4", G2oFormatError, "field 5 (z)"),
    ("EDGE_SE3_XYZ_PRIOR 2 0 4 5 6 -2 0 0 3 0 4", G2oFormatError, "not positive semi-definite"),
    ("EDGE_SE3_PRIOR 1 0 1 2 3 0 0 0 0 " + " ".join(map(repr, INFO6)), G2oFormatError, "zero norm"),
    ("PARAMS_SE3OFFSET 0 1 1 1 0 0 0 1", G2oFormatError, "defined twice"),
    ("EDGE_PRIOR_SE2_XY 2 1 1.2 3 0.5 4", G2oFormatError, "in a 3D file"),
]


@pytest.mark.parametrize("line, error, reason", BAD_3D, ids=[reason for _, _, reason in BAD_3D])
def test_bad_prior_lines_are_refused_with_file_and_line(text_file, line, error, reason):
    text = CHAIN + "\nPARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n" + line + "\nEDGE_SE3_XYZ_PRIOR 0 0 -1 0 0.5 1 0 0 1 0 1\n"
    path = text_file(text)
    with pytest.raises(error) as caught:
        read_g2o(path)
    assert caught.value.line == len(text.splitlines()) - 1
    assert reason in str(caught.value) and str(path) in str(caught.value)


def test_a_single_position_prior_is_accepted_with_a_warning_that_a_rotation_stays_free(text_file):
    from posegraph.model.graph import held_vertices
    from posegraph.solve.optimizer import optimize

    text = CHAIN + "\nPARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\nEDGE_SE3_XYZ_PRIOR 2 0 4 5 6 1 0 0 1 0 1\n"
    graph, messages = read_with_warnings(text_file(text))
    assert len(messages) == 1 and "leave a rotation free" in messages[0] and ":9:" in messages[0]
    assert not held_vertices(graph).any()
    result = optimize(graph, "chordal")  # LM's damping copes; the prior is met exactly
    assert result.converged
    np.testing.assert_allclose(result.poses[2, :3, 3], [4, 5, 6], atol=1e-6)


def test_three_position_priors_not_on_a_line_fix_the_gauge_silently(text_file):
    _, messages = read_with_warnings(text_file(CHAIN + "\n" + PRIORS_3D + "\nEDGE_SE3_XYZ_PRIOR 1 0 0 9 0 1 0 0 1 0 1\n"))
    assert messages == []


def test_offsets_without_priors_are_skipped_with_the_other_unread_tags(text_file):
    graph, messages = read_with_warnings(text_file(CHAIN + "\nPARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n"))
    assert graph.priors is None and len(messages) == 1 and "PARAMS_SE3OFFSET ×1" in messages[0]
