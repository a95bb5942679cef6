"""Landmark graphs in and out: every landmark tag read (values, information, offsets), written back, the errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o import format_g2o, read_g2o, write_g2o
from tests.io.helpers import read_with_warnings

POSES_2D = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.5\nEDGE_SE2 0 1 1 0 0.5 10 0 0 10 0 100\n"
POSES_3D = ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n"
            "EDGE_SE3:QUAT 0 1 1 2 3 0 0 0.7071067811865476 0.7071067811865476 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n")
LANDMARKS_2D = POSES_2D + (
    "VERTEX_XY 10 2 3\nVERTEX_XY 11 -1 4\n"
    "EDGE_SE2_XY 0 10 2 3 5 1 7\nEDGE_SE2_XY 1 11 -2 4.5 3 0 3\n"
    "EDGE_BEARING_SE2_XY 1 10 0.25 40\n"
    "EDGE_PRIOR_XY 11 -1 4 9 0.5 8\n"
    "FIX 11\n"
)
ISAM = Path("/work/data-landmarks")


def read(text_file, text, **options):
    graph, messages = read_with_warnings(text_file(text), **options)
    return graph, messages


def family(graph, tag):
    (found,) = [f for f in graph.landmarks.observations if f.tag == tag]
    return found


def test_2d_tags_values_and_information(text_file):
    graph, messages = read(text_file, LANDMARKS_2D)
    lm = graph.landmarks
    assert not messages and lm.vertex_tag == "VERTEX_XY" and lm.ids.tolist() == [10, 11]
    np.testing.assert_array_equal(lm.positions, [[2, 3], [-1, 4]])
    assert lm.fixed.tolist() == [False, True] and not graph.fixed.any()
    xy = family(graph, "EDGE_SE2_XY")
    assert xy.kind == "position" and xy.pose.tolist() == [0, 1] and xy.landmark.tolist() == [0, 1]
    np.testing.assert_array_equal(xy.measurements, [[2, 3], [-2, 4.5]])
    np.testing.assert_array_equal(xy.information[0], [[5, 1], [1, 7]])
    assert xy.lines.tolist() == [6, 7] and xy.offsets is None
    bearing = family(graph, "EDGE_BEARING_SE2_XY")
    assert bearing.kind == "bearing" and bearing.measurements.tolist() == [[0.25]] and bearing.information.tolist() == [[[40]]]
    prior = family(graph, "EDGE_PRIOR_XY")
    assert prior.kind == "prior" and prior.pose.tolist() == [-1] and prior.landmark.tolist() == [1]
    np.testing.assert_array_equal(prior.information[0], [[9, 0.5], [0.5, 8]])


def test_3d_trackxyz_information_order_and_any_offset(text_file):
    text = POSES_3D + ("PARAMS_SE3OFFSET 4 0.1 0.2 0.3 0 0 0.7071067811865476 0.7071067811865476\n"
                       "VERTEX_TRACKXYZ 7 1 2 3\nEDGE_SE3_TRACKXYZ 1 7 4 0.5 0.25 2 11 12 13 22 23 33\n"
                       "EDGE_POINTXYZ_PRIOR 7 1 2 3 1 0 0 1 0 1\n")
    graph, _ = read(text_file, text)
    xyz = family(graph, "EDGE_SE3_TRACKXYZ")
    assert xyz.pose.tolist() == [1] and graph.landmarks.ids.tolist() == [7] and xyz.offset_ids.tolist() == [4]
    np.testing.assert_array_equal(xyz.information[0], [[11, 12, 13], [12, 22, 23], [13, 23, 33]])  # x y z, unpermuted
    np.testing.assert_allclose(xyz.offsets[0], [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.3], [0, 0, 0, 1]], atol=1e-15)
    assert family(graph, "EDGE_POINTXYZ_PRIOR").kind == "prior"
    again = read_g2o(text_file(format_g2o(graph), "out.g2o"))
    np.testing.assert_array_equal(family(again, "EDGE_SE3_TRACKXYZ").offsets, xyz.offsets)


def test_gtsam_br_lines_bearing_range_with_diagonal_information(text_file):
    graph, _ = read(text_file, POSES_2D + "BR 0 7 0.5 3 0.1 0.2\nBR 1 7 -0.5 2 0.1 0.2\n")
    br = family(graph, "BR")
    assert br.kind == "bearing_range" and graph.landmarks.ids.tolist() == [7]  # created: BR files have no vertex lines
    np.testing.assert_allclose(br.information[0], np.diag([100, 25]))
    np.testing.assert_allclose(graph.landmarks.positions[0], [3 * np.cos(0.5), 3 * np.sin(0.5)])  # its first sighting
    with pytest.raises(G2oFormatError, match="BR needs 6 fields") as caught:  # gtsam reads garbage without the stds
        read_g2o(text_file(POSES_2D + "BR 0 7 0.5 3\n"))
    assert caught.value.line == 4


def test_isam_lines_are_square_root_information_with_their_own_landmark_ids(text_file):
    text = "ODOMETRY 0 1 1 0 0 2 1 0 3 0 4\nLANDMARK 0 1 2 3 2 1 3\nLANDMARK 1 1 1 3 2 1 3\n"
    graph, messages = read(text_file, text)
    assert graph.num_vertices == 2 and graph.landmarks.ids.tolist() == [11]  # landmark 1 met pose 1: shifted by 10
    assert any("10 + their file id" in m for m in messages)
    r = np.array([[2, 1], [0, 3]])
    np.testing.assert_allclose(family(graph, "LANDMARK").information[0], r.T @ r)
    r3 = np.array([[2, 1, 0], [0, 3, 0], [0, 0, 4]])
    np.testing.assert_allclose(graph.information[0], r3.T @ r3)
    as_information = read_g2o(text_file(text), isam_information="information")
    np.testing.assert_array_equal(as_information.information[0], [[2, 1, 0], [1, 3, 0], [0, 0, 4]])
    written = read_g2o(text_file(format_g2o(graph), "out.g2o"))  # g2o tags out: EDGE_SE2 / VERTEX_XY / EDGE_SE2_XY
    assert family(written, "EDGE_SE2_XY").count == 2 and written.landmarks.ids.tolist() == [11]
    np.testing.assert_allclose(family(written, "EDGE_SE2_XY").information, family(graph, "LANDMARK").information)


def test_point3_lines_with_and_without_entries(text_file):
    text = POSES_3D + "POINT3 0 5 1 2 3 2 0 0 2 0 2\nPOINT3 1 5 1 2 3\n"
    graph, _ = read(text_file, text)
    point3 = family(graph, "POINT3")
    np.testing.assert_allclose(point3.information, [4 * np.eye(3), np.eye(3)])
    assert graph.landmarks.ids.tolist() == [5] and point3.offsets is None


def test_unchanged_lines_copied_as_read_changed_ones_formatted(text_file):
    graph, _ = read(text_file, LANDMARKS_2D.replace("EDGE_SE2_XY 0 10 2 3 5 1 7", "EDGE_SE2_XY 0 10 2.000 3 5 1 7   "))
    text = format_g2o(graph)
    assert "EDGE_SE2_XY 0 10 2.000 3 5 1 7\n" in text and "VERTEX_XY 10 2.0 3.0\n" in text and "FIX 11\n" in text
    again = format_g2o(read_g2o(text_file(text, "out.g2o")))
    assert again == text  # a file posegraph wrote comes back byte for byte
    xy = family(graph, "EDGE_SE2_XY")
    changed = replace(xy, measurements=xy.measurements + 0.5)
    graph2 = replace(graph, landmarks=replace(graph.landmarks, observations=(changed,) + graph.landmarks.observations[1:],
                                              positions=graph.landmarks.positions * 2))
    text2 = format_g2o(graph2)
    assert "EDGE_SE2_XY 0 10 2.5 3.5 5.0 1.0 7.0\n" in text2 and "VERTEX_XY 10 4.0 6.0\n" in text2
    back = read_g2o(text_file(text2, "out2.g2o"))
    np.testing.assert_array_equal(family(back, "EDGE_SE2_XY").measurements, changed.measurements)
    np.testing.assert_array_equal(back.landmarks.positions, graph2.landmarks.positions)


def test_interleaved_file_reads_back_to_the_same_graph(text_file):
    lines = LANDMARKS_2D.splitlines()
    interleaved = "\n".join([lines[5], lines[0], lines[3], lines[1], lines[6], lines[2], lines[4], *lines[7:]]) + "\n"
    graph, _ = read(text_file, interleaved)
    back = read_g2o(text_file(format_g2o(graph), "out.g2o"))
    for a, b in zip(graph.landmarks.observations, back.landmarks.observations):
        assert a.tag == b.tag and np.array_equal(a.pose, b.pose) and np.array_equal(a.landmark, b.landmark)
        assert np.array_equal(a.measurements, b.measurements) and np.array_equal(a.information, b.information)
    assert back.landmarks.ids.tolist() == graph.landmarks.ids.tolist() and back.landmarks.fixed.tolist() == [False, True]


@pytest.mark.parametrize("text, error, line, reason", [
    (POSES_2D + "VERTEX_XY 10 0 0\nEDGE_SE2_XY 0 12 1 1 1 0 1\n", GraphError, 5, "landmark 12, which has no VERTEX_XY"),
    (POSES_2D + "VERTEX_XY 10 0 0\nEDGE_SE2_XY 5 10 1 1 1 0 1\n", GraphError, 5, "pose 5, which has no VERTEX_SE2"),
    (POSES_2D + "VERTEX_XY 10 0 0\nEDGE_SE2_XY 0 10 1 1 1 2 1\n", G2oFormatError, 5, "not positive semi-definite"),
    (POSES_2D + "VERTEX_XY 10 0 0\nEDGE_SE2_XY 0 10 1 1 0 0 0\n", G2oFormatError, 5, "all zero"),
    (POSES_3D + "VERTEX_XY 10 0 0\n", G2oFormatError, 4, "VERTEX_XY in a 3D file"),
    (POSES_3D + "VERTEX_TRACKXYZ 10 0 0 0\nEDGE_SE3_TRACKXYZ 0 10 3 1 1 1 1 0 0 1 0 1\n", G2oFormatError, 5,
     "parameter 3, which no PARAMS_SE3OFFSET"),
    (POSES_2D + "VERTEX_XY 10 0 0\nEDGE_SE2_XY 0 10 1 nan 1 0 1\n", G2oFormatError, 5, "finite"),
])  # fmt: skip
def test_errors_name_file_and_line(text_file, text, error, line, reason):
    path = text_file(text)
    with pytest.raises(error) as caught:
        read_g2o(path)
    assert caught.value.path == str(path) and caught.value.line == line and reason in str(caught.value)


def test_landmark_ids_that_are_pose_ids_are_their_own_id_space(text_file):
    """gtsam's reading (``L(l)``): every landmark id shifted by a power of ten, FIX naming a pose where ids meet."""
    text = POSES_2D + ("VERTEX_XY 1 2 3\nVERTEX_XY 7 -1 4\nEDGE_SE2_XY 0 1 2 3 5 1 7\nEDGE_SE2_XY 1 7 -2 4.5 3 0 3\n"
                       "EDGE_SE2_XY 1 1 1 2 3 0 3\nFIX 1\nFIX 7\n")
    graph, messages = read(text_file, text)
    assert graph.landmarks.ids.tolist() == [11, 17] and graph.fixed.tolist() == [False, True]
    assert graph.landmarks.fixed.tolist() == [False, True]  # FIX 1 is the pose's; 7 is only a landmark's
    assert len(messages) == 1 and "VERTEX_XY id 1 is also a pose's id" in messages[0] and "10 + its file id" in messages[0]
    xy = family(graph, "EDGE_SE2_XY")
    assert xy.pose.tolist() == [0, 1, 1] and xy.landmark.tolist() == [0, 1, 0]
    np.testing.assert_array_equal(graph.landmarks.positions, [[2, 3], [-1, 4]])
    written = format_g2o(graph)
    assert "VERTEX_XY 11 2.0 3.0\n" in written and "EDGE_SE2_XY 0 11 2.0 3.0 5.0 1.0 7.0\n" in written
    back, again = read(text_file, written)
    assert not again and back.landmarks.ids.tolist() == [11, 17]
    np.testing.assert_array_equal(family(back, "EDGE_SE2_XY").landmark, xy.landmark)


def test_xyz_prior_with_parameter_minus_one_is_accepted_and_written_back(text_file):
    line = "EDGE_SE3_XYZ_PRIOR 1 -1 1 2 3 1 0 0 1 0 1"
    graph, _ = read(text_file, POSES_3D + line + "\n")
    assert graph.priors.num_position == 1 and graph.priors.position_offset_ids.tolist() == [-1]
    assert line in format_g2o(graph)


def test_landmarks_alone_join_the_poses_and_nothing_to_optimise_names_what_it_found(text_file):
    text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_XY 5 1 1\nEDGE_SE2_XY 0 5 1 1 1 0 1\nEDGE_SE2_XY 1 5 0 1 1 0 1\n"
    graph, messages = read(text_file, text)
    assert graph.num_edges == 0 and graph.landmarks.num_measurements == 2 and not messages  # one component
    with pytest.raises(GraphError, match="nothing to optimise .*EDGE_SE2_XY ×2"):
        read_g2o(text_file(text), poses_only=True)


def test_fix_of_a_landmark_skipped_with_poses_only_is_no_error(text_file):
    graph, messages = read(text_file, LANDMARKS_2D, poses_only=True)
    assert graph.landmarks is None and graph.num_edges == 1 and any("EDGE_SE2_XY ×2" in m for m in messages)


def test_g2opy_reads_what_we_write(text_file, tmp_path):
    g2o = pytest.importorskip("g2opy")
    graph, _ = read(text_file, LANDMARKS_2D.replace("FIX 11\n", ""))
    target = tmp_path / "written.g2o"
    write_g2o(target, graph)
    optimizer = g2o.SparseOptimizer()
    assert optimizer.load(str(target))
    assert len(optimizer.vertices()) == 4 and len(optimizer.edges()) == 5


PUBLIC = [  # (file, poses, pose edges, landmarks, {tag: count}); fetched outside the repository
    ("victoriaPark-full.g2o.gz", 6969, 6968, 151, {"EDGE_SE2_XY": 3640}),
    ("world-1000-dense-highnoise_default.g2o.gz", 1000, 999, 589, {"EDGE_SE2_XY": 55084}),
    ("isam_victoriaPark.txt", 6969, 6968, 151, {"LANDMARK": 3640}),
    ("isam_torus2000Points.txt", 1073, 2034, 20, {"POINT3": 1039}),
    ("isam_manhattanOlson3500.txt", 3500, 5598, None, {}),
]


@pytest.mark.parametrize("name, poses, edges, landmarks, tags", PUBLIC)
def test_public_landmark_files(name, poses, edges, landmarks, tags, tmp_path):
    path = ISAM / name
    if not path.exists():
        pytest.skip(f"{path} is absent (fetched from grisetti/g2o_frontend and rickytan/iSAM outside the repository)")
    graph, _ = read_with_warnings(path)
    assert (graph.num_vertices, graph.num_edges) == (poses, edges)
    assert (graph.landmarks.count if graph.landmarks else None) == landmarks
    assert {f.tag: f.count for f in (graph.landmarks.observations if graph.landmarks else ())} == tags
    if graph.landmarks is not None:
        write_g2o(tmp_path / "out.g2o", graph)
        back, _ = read_with_warnings(tmp_path / "out.g2o")
        assert back.landmarks.ids.tolist() == graph.landmarks.ids.tolist()
        for a, b in zip(graph.landmarks.observations, back.landmarks.observations):
            np.testing.assert_array_equal(a.measurements, b.measurements)
            np.testing.assert_allclose(a.information, b.information, rtol=1e-15)


def test_isam_odometry_covariances_read_as_square_roots_are_named(text_file):
    """gtsam's victoria_park.txt holds covariances on iSAM's tags: read as square roots (the default) the
    heading's σ is 1/R_θθ = 2.5e5 rad. Said on the first ODOMETRY line, with the option; iSAM's own
    square roots (R_θθ = 500: σ 0.002 rad) and the covariance reading say nothing."""
    covariances = "".join(f"ODOMETRY {i} {i + 1} 0.1 0 0.01 0.0001 0 0 4e-06 0 4e-06\n" for i in range(4))
    landmark = "LANDMARK 2 1 3 1 0.4 0 0.4\n"
    _, messages = read(text_file, "# gtsam\n" + covariances + landmark)
    (note,) = [m for m in messages if "square-root information" in m]
    assert ":2: ODOMETRY" in note and "2.5e+05 rad" in note and "0.002 rad" in note
    assert "--isam-information covariance" in note
    _, messages = read(text_file, covariances + landmark, isam_information="covariance")
    assert not any("square-root information" in m for m in messages)
    square_roots = "".join(f"ODOMETRY {i} {i + 1} 0.1 0 0.01 100 0 0 500 0 500\n" for i in range(4))
    _, messages = read(text_file, square_roots + landmark)
    assert not any("square-root information" in m for m in messages)


def test_gtsams_victoria_park_read_as_covariances_converges():
    """The reading the note proposes: LM converges well inside the iteration cap (the default reading: the
    cap, 100 iterations, cost 0.041; docs/landmarks.md)."""
    gtsam = pytest.importorskip("gtsam")
    from posegraph.solve import optimize

    path = gtsam.findExampleDataFile("victoria_park.txt")
    _, messages = read_with_warnings(path)
    assert any("They look like covariances" in m for m in messages)
    graph, messages = read_with_warnings(path, isam_information="covariance")
    assert not any("They look like covariances" in m for m in messages)
    result = optimize(graph)
    assert result.converged and result.iterations < 20
