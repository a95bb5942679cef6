"""TORO's 2D files: VERTEX2 / EDGE2 with the information order told apart, EQUIV merges, gtsam's files."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o import format_g2o, read_g2o
from tests.io.helpers import read_with_warnings

VERTICES = ["VERTEX2 0 0 0 0", "VERTEX2 1 1 0 0.1", "VERTEX2 2 2 0.1 0.2", "VERTEX2 3 1.1 0.1 0.1"]
TORO_ENTRIES = "4 0.5 3 2 0.2 0.1"  # xx xy yy θθ xθ yθ
TORO_MATRIX = [[4, 0.5, 0.2], [0.5, 3, 0.1], [0.2, 0.1, 2]]
G2O_ENTRIES = "4 0.5 0.2 3 0.1 2"  # xx xy xθ yy yθ θθ: the same matrix


def toro_file(entries, *extra):
    edges = [f"EDGE2 0 1 1 0 0.1 {entries}", f"EDGE2 1 2 1 0.1 0.1 {entries}", f"EDGE2 2 3 -0.9 0 -0.1 {entries}"]
    return "\n".join(VERTICES + edges + list(extra)) + "\n"


@pytest.mark.parametrize("entries", [TORO_ENTRIES, G2O_ENTRIES], ids=["TORO order", "g2o order"])
def test_edge2_information_order_is_told_per_file(text_file, entries):
    graph, messages = read_with_warnings(text_file(toro_file(entries)))
    assert messages == [] and graph.group.name == "SE2"
    np.testing.assert_array_equal(graph.information, np.broadcast_to(TORO_MATRIX, (3, 3, 3)))
    np.testing.assert_allclose(graph.poses[1], [[np.cos(0.1), -np.sin(0.1), 1], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]])


def test_ambiguous_order_is_refused_and_can_be_named(text_file):
    path = text_file(toro_file("2 0 1 2 0 1"))  # positive definite read either way, different matrices
    with pytest.raises(G2oFormatError) as caught:
        read_g2o(path)
    assert caught.value.line == 5 and "--edge2-information" in str(caught.value)
    toro = read_g2o(path, edge2_information="toro").information[0]
    g2o = read_g2o(path, edge2_information="g2o").information[0]
    np.testing.assert_array_equal(toro, [[2, 0, 0], [0, 1, 1], [0, 1, 2]])
    np.testing.assert_array_equal(g2o, [[2, 0, 1], [0, 2, 0], [1, 0, 1]])


def test_an_order_that_fits_no_line_is_refused_at_the_first_bad_line(text_file):
    path = text_file(toro_file(TORO_ENTRIES).replace(TORO_ENTRIES, "1 0 1 -1 0 0", 1))
    with pytest.raises(G2oFormatError) as caught:
        read_g2o(path)
    assert caught.value.line == 5 and "positive semi-definite" in str(caught.value)


def test_equiv_merges_the_second_vertex_into_the_first(text_file):
    text = toro_file(TORO_ENTRIES, "EDGE2 3 1 0.1 0 0 1 0 1 1 0 0", "EQUIV 3 1")
    graph, messages = read_with_warnings(text_file(text))
    assert graph.ids.tolist() == [0, 2, 3]  # 1 merged into 3
    pairs = [(int(graph.ids[i]), int(graph.ids[j])) for i, j in zip(graph.edge_from, graph.edge_to)]
    assert pairs == [(0, 3), (3, 2), (2, 3)]  # the 3-1 edge became a loop on 3: dropped
    assert graph.edge_lines.tolist() == [5, 6, 7]
    assert len(messages) == 1 and "merged 1 vertices" in messages[0] and "dropped the 1 edge" in messages[0]
    assert ":9:" in messages[0]
    written = format_g2o(graph)
    for line in ("EQUIV 3 1", VERTICES[1], "EDGE2 3 1 0.1 0 0 1 0 1 1 0 0"):
        assert line in written.splitlines()  # kept as it came
    again, again_messages = read_with_warnings(text_file(written, name="again.g2o"))
    assert len(again_messages) == 1 and "merged 1 vertices" in again_messages[0]
    assert again.ids.tolist() == graph.ids.tolist()
    np.testing.assert_array_equal(again.edge_from, graph.edge_from)
    np.testing.assert_allclose(again.measurements, graph.measurements, atol=1e-15)
    np.testing.assert_array_equal(again.information, graph.information)


@pytest.mark.parametrize("line, error, reason", [
    ("EQUIV 3 9", GraphError, "names vertex 9"),
    ("EQUIV 3", G2oFormatError, "two integer vertex ids"),
])
def test_bad_equiv_lines(text_file, line, error, reason):
    with pytest.raises(error) as caught:
        read_g2o(text_file(toro_file(TORO_ENTRIES, line)))
    assert caught.value.line == 8 and reason in str(caught.value)


def test_w100_30_is_read_as_gtsam_reads_it(gtsam_example_file):
    """g2o's order (gtsam's reading): the same cost as gtsam's factors at the file's poses."""
    import gtsam

    from posegraph.solve.residuals import cost

    path = gtsam_example_file("w100_30.g2o")
    graph = read_g2o(path)
    factors, values = gtsam.readG2o(str(path), False)
    assert graph.num_edges == factors.size() and graph.num_vertices == values.size()
    assert cost(graph) == pytest.approx(factors.error(values), rel=1e-12)


@pytest.mark.slow
def test_w10000_reaches_gtsam_best_cost(gtsam_example_file):
    """TORO's order and 5,875 EQUIV merges: gtsam's best cost on the converted graph, 124.061546."""
    from posegraph.solve.optimizer import optimize

    graph = read_with_warnings(gtsam_example_file("w10000.graph"))[0]
    assert graph.num_vertices == 10000 - 5875
    assert optimize(graph, "chordal").final_cost == pytest.approx(124.061546, abs=5e-7)
