"""`posegraph plot` (checked as an image) and `posegraph export` (read back by Open3D)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.optional import import_or_skip

from tests.cli.conftest import assert_one_error_line, run_cli
from tests.cli.test_cli_optimize import assert_image


def test_plot_overlays_two_files(tmp_path, shared_dataset):
    pytest.importorskip("matplotlib")
    figure = tmp_path / "both.png"
    run = run_cli("plot", shared_dataset("parking-garage"), shared_dataset("smallGrid3D"), "-o", figure,
                  "--labels", "garage", "grid", "--title", "two graphs")
    assert run.returncode == 0, run.stderr
    assert_image(figure, min_width=600, min_height=500)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["both.png"]


def test_plot_refuses_bad_input_and_writes_nothing(tmp_path, shared_dataset):
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nFIX 9\nEDGE_SE3:QUAT 0 0\n")
    figure = tmp_path / "fig.png"
    assert_one_error_line(run_cli("plot", shared_dataset("tinyGrid3D"), bad, "-o", figure), f"{bad}:3:")
    assert_one_error_line(run_cli("plot", shared_dataset("tinyGrid3D"), "-o", figure, "--labels", "a", "b"),
                          "--labels")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.g2o"]


def test_export_reads_back_in_open3d(tmp_path, shared_dataset):
    o3d = import_or_skip("open3d", "export --open3d")
    from posegraph.io.g2o import read_g2o

    source = shared_dataset("parking-garage")
    graph_json, lines_ply = tmp_path / "graph.json", tmp_path / "lines.ply"
    run = run_cli("export", source, "--open3d", graph_json, "--ply", lines_ply, "--loop-closures")
    assert run.returncode == 0, run.stderr
    graph = read_g2o(source)
    pose_graph = o3d.io.read_pose_graph(str(graph_json))
    assert len(pose_graph.nodes) == graph.num_vertices and len(pose_graph.edges) == graph.num_edges
    np.testing.assert_allclose(np.array([n.pose for n in pose_graph.nodes]), graph.poses, atol=1e-12)
    edge = pose_graph.edges[graph.num_edges // 2]
    k = graph.num_edges // 2
    assert (edge.source_node_id, edge.target_node_id) == (graph.edge_to[k], graph.edge_from[k])
    np.testing.assert_allclose(edge.transformation, graph.measurements[k], atol=1e-12)
    line_set = o3d.io.read_line_set(str(lines_ply))
    order = np.argsort(graph.ids)
    np.testing.assert_allclose(np.asarray(line_set.points), graph.poses[order, :3, 3], atol=1e-6)
    assert len(line_set.lines) == (graph.num_vertices - 1) + np.count_nonzero(~graph.odometry_mask())


def test_export_needs_a_target(tmp_path, shared_dataset):
    assert_one_error_line(run_cli("export", shared_dataset("tinyGrid3D")), "--open3d")
    assert list(tmp_path.iterdir()) == []
