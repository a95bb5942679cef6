"""read_g2o on well-formed input: values, conventions, tolerated layout, warnings."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest

from posegraph.errors import InputWarning
from posegraph.model.graph import connected_components
from posegraph.io.g2o import read_g2o
from tests.conftest import INDEFINITE_INFORMATION

UPPER = [(r, c) for r in range(6) for c in range(r, 6)]


def rotation_from_xyzw(q):
    """Hamilton unit quaternion (x, y, z, w) to a rotation matrix, written out independently of posegraph."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def vertex(i, t=(0, 0, 0), q=(0, 0, 0, 1)):
    return "VERTEX_SE3:QUAT " + " ".join(str(v) for v in (i, *t, *q))


def edge(i, j, t=(1, 0, 0), q=(0, 0, 0, 1), upper=None):
    if upper is None:
        upper = [1.0 if r == c else 0.0 for r, c in UPPER]
    return "EDGE_SE3:QUAT " + " ".join(repr(v) if isinstance(v, float) else str(v) for v in (i, j, *t, *q, *upper))


def read_quietly(path):
    """read_g2o, asserting that it warns about nothing."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return read_g2o(path)


CHAIN = "\n".join(
    [
        vertex(0),
        vertex(1, (1, 0, 0), (0, 0, 0.3826834323650898, 0.9238795325112867)),
        vertex(2, (1, 1, 0.5), (0.1, -0.2, 0.3, 0.9273618495495703)),
        edge(0, 1, (1, 0, 0), (0, 0, 0.3826834323650898, 0.9238795325112867)),
        edge(1, 2, (0.5, 0.5, 0.5), (0.1, 0.2, -0.1, 0.9695359714832659)),
        edge(2, 0, (-1, -1, -0.5)),
    ]
) + "\n"


def test_vertices_and_edges_are_read_with_their_values(text_file):
    graph = read_quietly(text_file(CHAIN))
    assert graph.ids.tolist() == [0, 1, 2]
    assert graph.poses.shape == (3, 4, 4)
    np.testing.assert_allclose(graph.poses[2, :3, 3], [1, 1, 0.5], rtol=0, atol=0)
    np.testing.assert_allclose(
        graph.poses[2, :3, :3], rotation_from_xyzw((0.1, -0.2, 0.3, 0.9273618495495703)), atol=1e-15
    )
    np.testing.assert_array_equal(graph.poses[:, 3], np.tile([0, 0, 0, 1.0], (3, 1)))
    assert graph.edge_from.tolist() == [0, 1, 2]
    assert graph.edge_to.tolist() == [1, 2, 0]
    np.testing.assert_array_equal(graph.measurements[1, :3, 3], [0.5, 0.5, 0.5])
    np.testing.assert_allclose(
        graph.measurements[1, :3, :3], rotation_from_xyzw((0.1, 0.2, -0.1, 0.9695359714832659)), atol=1e-15
    )
    np.testing.assert_array_equal(graph.information, np.tile(np.eye(6), (3, 1, 1)))
    assert not graph.fixed.any()
    assert graph.source == os.path.abspath(text_file(CHAIN))


def test_information_is_permuted_from_g2o_translation_first_to_rotation_first(text_file):
    # A symmetric positive-definite matrix in g2o's [x y z | rotation] order with all entries distinct.
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 6))
    g2o_matrix = a @ a.T + 6 * np.eye(6)
    upper = [float(g2o_matrix[r, c]) for r, c in UPPER]
    text = "\n".join([vertex(0), vertex(1), edge(0, 1, upper=upper)])
    graph = read_quietly(text_file(text))
    omega = graph.information[0]
    # Written out block by block: rotation first in the model, translation first in the file.
    np.testing.assert_array_equal(omega[:3, :3], g2o_matrix[3:, 3:])
    np.testing.assert_array_equal(omega[3:, 3:], g2o_matrix[:3, :3])
    np.testing.assert_array_equal(omega[:3, 3:], g2o_matrix[3:, :3])
    np.testing.assert_array_equal(omega[3:, :3], g2o_matrix[:3, 3:])
    np.testing.assert_array_equal(omega, omega.T)


def test_upper_triangle_is_read_row_by_row(text_file):
    # Entry k of the 21 goes to (row, column) UPPER[k] of the g2o-ordered matrix.
    upper = [100.0 if r == c else 0.0 for r, c in UPPER]
    k = UPPER.index((1, 4))  # between y and the second rotation coordinate
    upper[k] = 7.0
    graph = read_quietly(text_file("\n".join([vertex(0), vertex(1), edge(0, 1, upper=upper)])))
    omega = graph.information[0]
    # g2o row 1 (y) is model row 4; g2o row 4 (rotation y) is model row 1.
    assert omega[4, 1] == 7.0 and omega[1, 4] == 7.0
    assert np.count_nonzero(omega - np.diag(np.diag(omega))) == 2


def test_layout_variations_read_the_same_graph(text_file):
    reference = read_quietly(text_file(CHAIN, "clean.g2o"))
    lines = CHAIN.strip().split("\n")
    messy = "\ufeff# a comment line\n\n" + "\r\n".join(
        [
            "  \t" + lines[0].replace(" ", "\t") + "   # trailing comment",
            lines[1].replace(" ", "    "),
            "",
            "   ",
            lines[2] + " \t ",
            "#" + "EDGE_SE3:QUAT 9 9 that is commented out",
            lines[3].replace(" ", " \t "),
            lines[4],
            lines[5],
        ]
    ) + "\r\n"
    graph = read_quietly(text_file(messy, "messy.g2o"))
    for name in ("ids", "poses", "edge_from", "edge_to", "measurements", "information", "fixed"):
        np.testing.assert_array_equal(getattr(graph, name), getattr(reference, name), err_msg=name)


def test_fix_lines_mark_vertices_fixed(text_file):
    text = CHAIN + "FIX 2\nFIX 0 2\n"
    graph = read_quietly(text_file(text))
    assert graph.fixed.tolist() == [True, False, True]


def test_sparse_unordered_ids_map_edges_to_indices(text_file):
    text = "\n".join(
        [
            vertex(40, (4, 0, 0)),
            vertex(7, (7, 0, 0)),
            vertex(1000, (1000, 0, 0)),
            edge(7, 40),
            edge(1000, 7),
            "FIX 1000",
        ]
    )
    graph = read_quietly(text_file(text))
    assert graph.ids.tolist() == [40, 7, 1000]  # file order, not sorted
    assert graph.edge_from.tolist() == [1, 2]
    assert graph.edge_to.tolist() == [0, 1]
    np.testing.assert_array_equal(graph.poses[:, 0, 3], [4, 7, 1000])
    assert graph.fixed.tolist() == [False, False, True]


def test_edges_may_come_before_their_vertices(text_file):
    text = "\n".join([edge(1, 0), vertex(0), vertex(1)])
    graph = read_quietly(text_file(text))
    assert (graph.edge_from.tolist(), graph.edge_to.tolist()) == ([1], [0])


def test_unknown_tags_are_skipped_with_one_warning_counting_each_tag(text_file):
    text = "\n".join(
        [
            "PARAMS_CAMERACALIB 0 500 320 240 0 0",
            *CHAIN.strip().split("\n"),
            "VERTEX_TRACKXYZ 10 1 2 3",
            "VERTEX_TRACKXYZ 11 1 2 3",
            "EDGE_SE3_TRACKXYZ 0 10 0 1 2 3 1 0 0 1 0 1",
        ]
    )
    with pytest.warns(InputWarning) as record:
        graph = read_g2o(text_file(text), poses_only=True)  # 1 landmark line of 4 measurements: asked for
    messages = [str(w.message) for w in record if issubclass(w.category, InputWarning)]
    assert len(messages) == 1
    (message,) = messages
    assert ":1:" in message  # the first skipped line
    assert "skipped 4 line(s)" in message
    for counted in ("PARAMS_CAMERACALIB ×1", "VERTEX_TRACKXYZ ×2", "EDGE_SE3_TRACKXYZ ×1"):
        assert counted in message
    assert graph.num_vertices == 3 and graph.num_edges == 3


def test_unnormalised_quaternions_are_normalised_with_one_warning(text_file):
    text = "\n".join(
        [
            vertex(0),
            vertex(1, q=(0, 0, 0.6, 0.9)),  # norm 1.08: off
            vertex(2, q=(0, 0, 0, 1 + 3e-7)),  # within 1e-6: normalised silently
            edge(0, 1, q=(0, 0, 0, 2)),  # norm 2: off
            edge(1, 2),
        ]
    )
    with pytest.warns(InputWarning, match=r":2: normalised 2 quaternion\(s\)") as record:
        graph = read_g2o(text_file(text))
    assert len(record) == 1
    assert "1.08166538" in str(record[0].message)  # the first one's norm
    np.testing.assert_allclose(graph.poses[1, :3, :3], rotation_from_xyzw((0, 0, 0.6, 0.9)), atol=1e-15)
    for rotation in (graph.poses[:, :3, :3], graph.measurements[:, :3, :3]):
        gram = rotation @ np.swapaxes(rotation, -1, -2)
        np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-15)
    np.testing.assert_allclose(graph.measurements[0, :3, :3], np.eye(3), atol=0)


def test_several_components_are_accepted_with_a_warning(text_file):
    text = "\n".join([vertex(0), vertex(1), vertex(2), vertex(3), vertex(4), edge(0, 1), edge(2, 3)])
    with pytest.warns(InputWarning, match="3 connected components") as record:
        graph = read_g2o(text_file(text))
    assert len(record) == 1
    assert "vertex counts 2, 2, 1" in str(record[0].message)
    assert connected_components(graph)[0] == 3


def test_singular_information_is_kept_exactly_with_a_warning(text_file):
    # Translation-only constraint: the rotation block (g2o rows 3..5) is zero.
    upper = [5.0 if r == c and r < 3 else 0.0 for r, c in UPPER]
    upper[UPPER.index((0, 1))] = 1.0
    text = "\n".join([vertex(0), vertex(1), edge(0, 1), edge(0, 1, upper=upper)])
    with pytest.warns(InputWarning, match=r":4: 1 EDGE_SE3:QUAT information matrices are singular") as record:
        graph = read_g2o(text_file(text))
    assert len(record) == 1
    expected = np.zeros((6, 6))
    expected[3:, 3:] = [[5, 1, 0], [1, 5, 0], [0, 0, 5]]
    np.testing.assert_array_equal(graph.information[1], expected)


def test_indefinite_within_rounding_is_accepted_as_singular(text_file):
    # A rank-one matrix whose printed digits make λ_min ≈ −7e-8·λ_max: rounding, not a sign error.
    v = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    rank_one = 1000 * np.outer(v, v)
    rank_one[0, 0] -= 1e-3
    assert np.linalg.eigvalsh(rank_one)[0] < 0
    upper = [float(rank_one[r, c]) for r, c in UPPER]
    text = "\n".join([vertex(0), vertex(1), edge(0, 1), edge(1, 0, upper=upper)])
    with pytest.warns(InputWarning, match=r":4: 1 EDGE_SE3:QUAT information matrices are singular"):
        graph = read_g2o(text_file(text))
    assert graph.num_edges == 2


def test_trajectory_without_edges_when_edges_are_not_required(text_file):
    text = "\n".join([vertex(5, (1, 2, 3)), vertex(3), "FIX 3"])
    graph = read_quietly_without_edges(text_file(text))
    assert graph.ids.tolist() == [5, 3] and graph.fixed.tolist() == [False, True]
    np.testing.assert_array_equal(graph.poses[0, :3, 3], [1, 2, 3])
    assert graph.num_edges == 0
    assert graph.edge_from.shape == graph.edge_to.shape == (0,)
    assert graph.measurements.shape == (0, 4, 4) and graph.information.shape == (0, 6, 6)


def read_quietly_without_edges(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # in particular no "n connected components" for a trajectory
        return read_g2o(path, require_edges=False)


def test_a_clean_file_raises_no_warning(text_file):
    read_quietly(text_file(CHAIN + "FIX 0\n"))


def test_shared_dataset_reads_with_consistent_arrays(shared_g2o_file):
    counts = {}
    with open(shared_g2o_file) as handle:
        for line in handle:
            tag = line.split(None, 1)[0] if line.strip() else None
            counts[tag] = counts.get(tag, 0) + 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        graph = read_g2o(shared_g2o_file, repair_information=shared_g2o_file.name in INDEFINITE_INFORMATION)
    n, m = graph.num_vertices, graph.num_edges
    assert (n, m) == (counts["VERTEX_SE3:QUAT"], counts["EDGE_SE3:QUAT"])
    assert graph.poses.shape == (n, 4, 4) and graph.measurements.shape == (m, 4, 4)
    assert graph.information.shape == (m, 6, 6)
    assert len(np.unique(graph.ids)) == n
    assert graph.edge_from.min() >= 0 and graph.edge_to.max() < n
    for rotation in (graph.poses[:, :3, :3], graph.measurements[:, :3, :3]):
        np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-12)
    np.testing.assert_array_equal(graph.information, np.swapaxes(graph.information, 1, 2))
    assert np.linalg.eigvalsh(graph.information).min() > -1e-9 * np.abs(graph.information).max()


def test_warning_names_the_file(text_file):
    path = text_file("\n".join([vertex(0), vertex(1, q=(0, 0, 0, 3)), edge(0, 1)]), "named.g2o")
    with pytest.warns(InputWarning) as record:
        read_g2o(path)
    assert re.match(re.escape(str(path)) + r":2: ", str(record[0].message))
