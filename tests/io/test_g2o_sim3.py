"""g2o's Sim(3) files: χ² equal to g2opy's, both variants read and written back, bad input refused with file:line."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posegraph.errors import G2oFormatError, GraphError
from posegraph.io.g2o import read_g2o, write_g2o
from posegraph.io.g2o_sim3 import CLASSIC, CURRENT, Sim3Format
from posegraph.lie import sim3
from posegraph.lie.group import SIM3_G2O
from posegraph.solve.residuals import cost


def g2o_chi2(path) -> float:
    from datasets.g2opy_sim3 import g2o_chi2 as chi2

    return chi2(path)

INFO_UPPER = " ".join("100" if r == c else "0" for r in range(7) for c in range(r, 7))


def _random_graph(rng, n=40, extra=30, noise=0.02):
    """Ground-truth poses and noisy measurements of a chain with random loop closures (camera-to-world)."""
    steps = np.concatenate([rng.normal(size=(n - 1, 3)) * 0.2, rng.normal(size=(n - 1, 3)) + [1, 0, 0],
                            rng.normal(size=(n - 1, 1)) * 0.05], axis=1)  # fmt: skip
    X = _chain(sim3.exp(steps))
    i = np.r_[np.arange(n - 1), rng.integers(0, n, extra)]
    j = np.r_[np.arange(1, n), rng.integers(0, n, extra)]
    keep = i != j
    i, j = i[keep], j[keep]
    Z = sim3.between(X[i], X[j]) @ sim3.exp(rng.normal(size=(len(i), 7)) * noise)
    start = X @ sim3.exp(rng.normal(size=(n, 7)) * 0.05)
    return start, i, j, Z


def _chain(steps):
    poses = [np.eye(4)]
    for step in steps:
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _g2opy_file(path, rng, optimize_iterations=0, noise=0.02):
    """A Sim(3) graph built in g2opy and written by g2opy's ``save`` (the current variant), after ``optimize_iterations`` of g2o's LM."""
    g2o = pytest.importorskip("g2opy", reason="the g2opy wheel is not installed: no g2o to compare with")
    X, i, j, Z = _random_graph(rng, noise=noise)
    optimizer = g2o.SparseOptimizer()
    optimizer.set_algorithm(g2o.OptimizationAlgorithmLevenberg(g2o.BlockSolverSim3(g2o.LinearSolverEigenSim3())))

    def similarity(M):
        s = float(sim3.scale(M))
        return g2o.Sim3(M[:3, :3] / s, M[:3, 3].copy(), s)

    for k, pose in enumerate(X):
        vertex = g2o.VertexSim3Expmap()
        vertex.set_id(k)
        vertex.set_estimate(similarity(sim3.inverse(pose)))  # g2o's estimate is world-to-camera
        vertex.set_fixed(k == 0)
        optimizer.add_vertex(vertex)
    for a, b, z in zip(i, j, Z):
        edge = g2o.EdgeSim3()
        edge.set_vertex(0, optimizer.vertex(int(a)))
        edge.set_vertex(1, optimizer.vertex(int(b)))
        edge.set_measurement(similarity(sim3.inverse(z)))
        edge.set_information(np.diag(rng.uniform(50, 200, 7)))
        optimizer.add_edge(edge)
    if optimize_iterations:
        optimizer.initialize_optimization()
        optimizer.optimize(optimize_iterations)
    optimizer.save(str(path))
    return g2o


@pytest.mark.parametrize("iterations", [0, 20])
def test_chi2_equals_g2os_own(tmp_path, iterations):
    """Far from the optimum and at g2o's own, where residual angles ~1e-3 fall in g2o's first-order branch."""
    path = tmp_path / "g.g2o"
    g2o = _g2opy_file(path, np.random.default_rng(iterations), iterations, noise=0.02 if iterations == 0 else 1e-3)
    graph = read_g2o(path)
    assert graph.group is SIM3_G2O and graph.file_format.variant == CURRENT
    reference = g2o_chi2(path)
    assert abs(2.0 * cost(graph) - reference) <= 1e-9 * reference
    exact = replace(graph, group=replace(SIM3_G2O, residual_log=None))
    if iterations:  # the exact log's χ² differs: g2o's branches matter at the optimum
        assert abs(2.0 * cost(exact) - reference) > 1e-9 * reference


def test_write_read_keeps_poses_and_g2o_reads_the_same_chi2(tmp_path):
    path = tmp_path / "g.g2o"
    g2o = _g2opy_file(path, np.random.default_rng(5))
    graph = read_g2o(path)
    out = tmp_path / "out.g2o"
    write_g2o(out, graph)
    again = read_g2o(out)
    assert again.file_format.variant == CURRENT
    np.testing.assert_allclose(again.poses, graph.poses, rtol=0, atol=1e-13)
    np.testing.assert_allclose(again.measurements, graph.measurements, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(again.information, graph.information)
    np.testing.assert_array_equal(again.fixed, graph.fixed)
    assert abs(g2o_chi2(out) - 2.0 * cost(graph)) <= 1e-9 * g2o_chi2(out)


def _classic_text():
    """A classic file: logs of camera-to-world, cameras after each vertex, σ below g2o's 1e-5 branch in one."""
    return "\n".join([
        "VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 500 501 320 240",
        "VERTEX_SIM3:EXPMAP 1 0.1 -0.2 0.05 1.0 0.1 -0.3 4e-6 400 400 300 200",
        "VERTEX_SIM3:EXPMAP 2 0.2 -0.1 0.1 2.0 0.3 -0.2 0.2 400 400 300 200",
        "FIX 0",
        "EDGE_SIM3:EXPMAP 0 1 0.1 -0.2 0.05 1.0 0.1 -0.3 0.0 " + INFO_UPPER,
        "EDGE_SIM3:EXPMAP 1 2 0.1 0.1 0.05 1.0 0.2 0.1 0.2 " + INFO_UPPER,
        "EDGE_SIM3:EXPMAP 0 2 0.2 -0.1 0.1 2.0 0.3 -0.2 0.19 " + INFO_UPPER,
    ]) + "\n"  # fmt: skip


def test_classic_variant_reads_g2os_exp_and_writes_back_classic(tmp_path):
    path = tmp_path / "classic.g2o"
    path.write_text(_classic_text())
    graph = read_g2o(path)
    assert graph.file_format.variant == CLASSIC
    xi = np.array([0.1, -0.2, 0.05, 1.0, 0.1, -0.3, 4e-6])
    # g2o's Sim3(Vector7) takes C = 1 below |σ| = 1e-5: the translation is W υ with that C, not exact Exp's.
    np.testing.assert_allclose(graph.poses[1], sim3.g2o_exp(xi), rtol=0, atol=1e-15)
    assert np.abs(graph.poses[1] - sim3.exp(xi)).max() > 1e-7
    out = tmp_path / "out.g2o"
    write_g2o(out, graph)
    lines = out.read_text().splitlines()
    assert lines[0].split()[-4:] == ["500.0", "501.0", "320.0", "240.0"] and len(lines[0].split()) == 13
    assert len(lines[-1].split()) == 1 + 2 + 7 + 28
    again = read_g2o(out)
    assert again.file_format.variant == CLASSIC
    np.testing.assert_allclose(again.poses, graph.poses, rtol=0, atol=1e-14)
    np.testing.assert_allclose(again.measurements, graph.measurements, rtol=0, atol=1e-14)
    assert cost(again) == pytest.approx(cost(graph), rel=1e-12)


def test_classic_and_current_of_the_same_graph_agree(tmp_path):
    path = tmp_path / "g.g2o"
    _g2opy_file(path, np.random.default_rng(9))
    graph = read_g2o(path)
    classic_path = tmp_path / "classic.g2o"
    write_g2o(classic_path, replace(graph, file_format=Sim3Format(CLASSIC, np.zeros(0, np.int64), np.zeros((0, 4)))))
    classic = read_g2o(classic_path)
    assert classic.file_format.variant == CLASSIC
    np.testing.assert_allclose(classic.poses, graph.poses, rtol=0, atol=1e-13)
    assert cost(classic) == pytest.approx(cost(graph), rel=1e-12)
    assert classic_path.read_text().splitlines()[0].endswith(" 1.0 1.0 0.0 0.0")  # g2o's default camera


VERTEX_0 = "VERTEX_SIM3:EXPMAP 0 0 0 0 1 0 0 0 1"
VERTEX_1 = "VERTEX_SIM3:EXPMAP 1 0 0 0 1 1 0 0 1.5"
EDGE_01 = "EDGE_SIM3:EXPMAP 0 1 0 0 0 1 -1 0 0 0.6667 " + INFO_UPPER


@pytest.mark.parametrize(
    "lines, line, reason",
    [
        ([VERTEX_0, "VERTEX_SIM3:EXPMAP 1 0 0 0 1 1 0 0 0", EDGE_01], 2, "scale is 0.0; a similarity's scale must be > 0"),
        ([VERTEX_0, "VERTEX_SIM3:EXPMAP 1 0 0 0 1 1 0 0 -2", EDGE_01], 2, "scale must be > 0"),
        ([VERTEX_0, VERTEX_1, EDGE_01.replace(" 0.6667 ", " nan ")], 3, "(scale) is nan; values must be finite"),
        ([VERTEX_0, "VERTEX_SIM3:EXPMAP 1 0 0 0 1.1 1 0 0 1", EDGE_01], 2, "has norm 1.1: more than 0.001 from 1"),
        ([VERTEX_0, "VERTEX_SIM3:EXPMAP 1 0 0 0 1 1 0 0", EDGE_01], 2, "needs 9 fields after the tag (current g2o"),
        ([VERTEX_0, VERTEX_1, EDGE_01 + " 3"], 3, "needs 38 fields after the tag (current g2o"),
        ([VERTEX_0, "VERTEX_SIM3:EXPMAP 1 0 0 0 0 0 0 0 1 1 0 0", EDGE_01], 2, "line in the classic variant (12 fields)"),
        ([VERTEX_0, VERTEX_1, EDGE_01, "VERTEX_SE3:QUAT 7 0 0 0 0 0 0 1"], 4, "VERTEX_SE3:QUAT in a file of Sim(3) lines"),
        (["VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 1 1 0 0", "VERTEX_SIM3:EXPMAP 1 0 0 0 1 0 0 800 1 1 0 0"], 2,
         "log-scale σ is 800.0: its scale e^σ is not a finite positive number"),
    ],
)
def test_bad_input_names_file_line_and_reason(tmp_path, lines, line, reason):
    path = tmp_path / "bad.g2o"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(G2oFormatError) as caught:
        read_g2o(path)
    assert str(caught.value).startswith(f"{path}:{line}: ")
    assert reason in str(caught.value)


def test_a_sim3_edge_between_se3_vertices_is_refused(tmp_path):
    path = tmp_path / "mixed.g2o"
    path.write_text("\n".join([
        VERTEX_0, "VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1", "VERTEX_SIM3:EXPMAP 2 0 0 0 1 2 0 0 1", EDGE_01,
        EDGE_01.replace(" 0 1 ", " 0 2 ", 1),
    ]) + "\n")  # fmt: skip
    with pytest.raises(GraphError, match=rf"^{path}:4: EDGE_SIM3:EXPMAP names vertex 1, a VERTEX_SE3:QUAT \(line 2\)"):
        read_g2o(path)
