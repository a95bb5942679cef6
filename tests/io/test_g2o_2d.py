"""2D g2o files (``VERTEX_SE2`` / ``EDGE_SE2``): reading, writing, every reader guarantee, and gtsam's cost."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError, InputWarning, MissingPosesWarning
from posegraph.io.g2o import format_g2o, read_g2o, write_g2o
from posegraph.lie import se2
from posegraph.lie.group import SE2
from posegraph.solve.residuals import cost

from .test_g2o_errors import check, lines

INFO = "100 2 -3 200 5 300"  # upper triangle of [[100, 2, -3], [2, 200, 5], [-3, 5, 300]], [x, y, θ] order


def vertex(i, rest="0 0 0"):
    return f"VERTEX_SE2 {i} {rest}"


def edge(i, j, measurement="1 0 0.1", upper=INFO):
    return f"EDGE_SE2 {i} {j} {measurement} {upper}"


GOOD = [vertex(0), vertex(1, "1 0 0.1"), vertex(2, "2 0.1 0.2"), edge(0, 1), edge(1, 2)]


def read_text(text_file, text):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        return read_g2o(text_file(text))


def test_a_2d_file_gives_an_se2_graph_with_information_in_file_order(text_file):
    graph = read_text(text_file, lines(*GOOD, "FIX 0"))
    assert graph.group is SE2
    assert graph.poses.shape == (3, 3, 3) and graph.measurements.shape == (2, 3, 3)
    np.testing.assert_array_equal(se2.to_xytheta(graph.poses[2]), [2, 0.1, 0.2])
    np.testing.assert_allclose(se2.to_xytheta(graph.measurements[0]), [1, 0, 0.1], atol=1e-16)
    # g2o's [x, y, θ] is se(2)'s tangent order: nothing permuted.
    np.testing.assert_array_equal(graph.information[0], [[100, 2, -3], [2, 200, 5], [-3, 5, 300]])
    assert graph.fixed.tolist() == [True, False, False]


def test_residual_and_cost_by_hand(text_file):
    """One edge: e = Log(Z⁻¹ Xi⁻¹ Xj) with se2's Log, cost ½ eᵀΩe."""
    graph = read_text(text_file, lines(vertex(0), vertex(1, "1 0.2 0.5"), edge(0, 1, "0.9 0 0.4")))
    Z = se2.from_xytheta([0.9, 0, 0.4])
    e = se2.log(se2.inverse(Z) @ se2.from_xytheta([1, 0.2, 0.5]))
    assert cost(graph) == pytest.approx(0.5 * e @ graph.information[0] @ e, rel=1e-14)


def test_round_trip_is_exact_and_unchanged_edges_are_copied(text_file, tmp_path):
    text = lines(*GOOD[:3], "EDGE_SE2 0 1   1.0 0 0.1 " + INFO + "   # comment", edge(1, 2), "FIX 0")
    graph = read_text(text_file, text)
    assert graph.edge_source is not None and graph.edge_source.format == "EDGE_SE2"
    written = format_g2o(graph)
    assert "EDGE_SE2 0 1   1.0 0 0.1 " + INFO + "\n" in written  # copied as read, comment dropped
    rewritten = format_g2o(replace(graph, edge_source=None))
    fields = [line.split() for line in rewritten.splitlines() if line.startswith("EDGE_SE2 0 1 ")][0]
    # θ goes through cos/sin and back by atan2 (as in gtsam's Rot2): equal to the last bit or one ulp.
    np.testing.assert_allclose([float(x) for x in fields[3:]], [1, 0, 0.1, 100, 2, -3, 200, 5, 300], rtol=1e-15)
    for out in (written, rewritten):
        path = tmp_path / "out.g2o"
        path.write_text(out)
        again = read_g2o(path)
        assert again.group is SE2
        np.testing.assert_array_equal(again.information, graph.information)
        np.testing.assert_allclose(again.measurements, graph.measurements, rtol=0, atol=1e-15)
        np.testing.assert_allclose(again.poses, graph.poses, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(again.fixed, graph.fixed)


@pytest.mark.parametrize("angle", [np.pi, -np.pi + 1e-12, 3.0, 4.0, -4.0, 7.5])
def test_written_angles_are_wrapped_to_minus_pi_pi(angle, text_file, tmp_path):
    graph = read_text(text_file, lines(*GOOD))
    poses = graph.poses.copy()
    poses[1] = se2.from_xytheta([1.0, 2.0, angle])
    write_g2o(tmp_path / "out.g2o", graph, poses)
    theta = float((tmp_path / "out.g2o").read_text().splitlines()[1].split()[4])
    assert -np.pi <= theta <= np.pi
    assert np.cos(theta) == pytest.approx(np.cos(angle), abs=1e-15)
    assert np.sin(theta) == pytest.approx(np.sin(angle), abs=1e-15)


def test_writer_refuses_3d_poses_for_a_2d_graph(text_file, tmp_path):
    graph = read_text(text_file, lines(*GOOD))
    with pytest.raises(ValueError, match=r"\(3, 3, 3\)"):
        write_g2o(tmp_path / "out.g2o", graph, np.broadcast_to(np.eye(4), (3, 4, 4)))
    assert not (tmp_path / "out.g2o").exists()


def test_an_edge_only_file_gets_its_vertices_at_the_identity_with_a_warning(text_file):
    with pytest.warns(MissingPosesWarning, match="no vertex lines"):
        graph = read_g2o(text_file(lines(edge(3, 5), edge(5, 9), edge(9, 3))))
    assert graph.group is SE2 and graph.ids.tolist() == [3, 5, 9]
    np.testing.assert_array_equal(graph.poses, np.broadcast_to(np.eye(3), (3, 3, 3)))


# ---------------------------------------------------------------- the reader's guarantees, in 2D


@pytest.mark.parametrize("token", ["nan", "inf", "1e400"])
def test_non_finite_numbers(text_file, token):
    check(text_file, lines(*GOOD, vertex(3, f"0 {token} 0")), G2oFormatError, 6, "field 3 (y)")


def test_a_word_where_a_number_belongs(text_file):
    check(text_file, lines(*GOOD, edge(1, 2, "1 zero 0")), G2oFormatError, 6, "field 4 (dy)", "not a number")


def test_a_missing_information_entry(text_file):
    check(text_file, lines(*GOOD, edge(1, 2, upper="1 0 0 1 0")), G2oFormatError, 6, "needs 11 fields", "found 10")


def test_an_indefinite_information_matrix(text_file):
    check(text_file, lines(*GOOD, edge(0, 2, upper="1 5 0 1 0 1")), G2oFormatError, 6, "not positive semi-definite")


def test_an_indefinite_information_matrix_is_repaired_when_asked(text_file):
    with pytest.warns(InputWarning, match="repaired 1 information"):
        graph = read_g2o(text_file(lines(*GOOD, edge(0, 2, upper="1 5 0 1 0 1"))), repair_information=True)
    assert np.linalg.eigvalsh(graph.information[2]).min() > 0


def test_a_duplicate_vertex(text_file):
    check(text_file, lines(*GOOD, vertex(1)), GraphError, 6, "duplicate vertex id 1", "line 2")


def test_an_edge_to_a_missing_vertex(text_file):
    check(text_file, lines(*GOOD, edge(2, 7)), GraphError, 6, "names vertex 7", "no VERTEX_SE2 line")


def test_a_self_loop(text_file):
    check(text_file, lines(*GOOD, edge(2, 2)), GraphError, 6, "self-loop")


def test_fix_of_a_missing_vertex(text_file):
    check(text_file, lines(*GOOD, "FIX 8"), GraphError, 6, "FIX names vertex 8")


def test_vertices_without_edges(text_file):
    check(text_file, lines(*GOOD[:3]), GraphError, None, "no EDGE_SE2 lines")


# -------------------------------------------------------------------------- against gtsam


@pytest.mark.parametrize("dataset", ["intel", "manhattan"])
def test_cost_equals_gtsam_graph_error(dataset, shared_dataset):
    """Our cost at two sets of poses equals ``graph.error`` of the graph ``gtsam.readG2o(is3D=False)`` builds."""
    gtsam = pytest.importorskip("gtsam")
    from posegraph.crosscheck.gtsam_bridge import poses_to_values
    from posegraph.init import initialize

    path = shared_dataset(dataset)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        graph = read_g2o(path)
    factors, _ = gtsam.readG2o(str(path), False)
    assert factors.size() == graph.num_edges
    rng = np.random.default_rng(0)
    chordal = initialize(graph)
    perturbed = chordal @ se2.exp(rng.normal(scale=[0.05, 0.05, 0.02], size=(graph.num_vertices, 3)))
    for poses in (chordal, perturbed):
        ours = cost(graph, poses)
        theirs = factors.error(poses_to_values(graph.ids, poses))
        assert ours == pytest.approx(theirs, rel=1e-11)
