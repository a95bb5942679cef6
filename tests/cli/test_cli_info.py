"""`posegraph info` and the top-level command: figures checked against gtsam and the graph model."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from tests.cli.conftest import assert_one_error_line, run_cli


def test_help_lists_every_command_with_examples():
    run = run_cli("--help")
    assert run.returncode == 0
    for command in ("optimize", "compare", "verify-jacobians", "info", "eval", "plot", "export"):
        assert command in run.stdout
    assert "examples:" in run.stdout and "exit status" in run.stdout


@pytest.mark.parametrize("command", ["optimize", "compare", "verify-jacobians", "info", "eval", "plot", "export"])
def test_every_subcommand_help_has_examples(command):
    # In-process: the parser is the program's, and a subprocess per command would only add time.
    import contextlib
    import io

    from posegraph import cli

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = cli.main([command, "--help"])
    assert status == 0
    text = out.getvalue()
    examples = text.split("examples:\n", 1)[1]
    assert f"posegraph {command}" in examples


def test_installed_script_is_the_same_program():
    script = shutil.which("posegraph")
    if script is None:
        pytest.skip("the posegraph console script is not installed (pip install -e .)")
    installed = subprocess.run([script, "--version"], capture_output=True, text=True, timeout=60)
    assert installed.returncode == 0
    assert installed.stdout == run_cli("--version").stdout


def test_python_dash_m_is_the_same_program():
    """``python -m posegraph`` and ``python cli.py`` (the checkout's shim) print the same help and version."""
    import os
    import sys

    from tests.cli.conftest import PROJECT_ROOT

    env = dict(os.environ, PYTHONPATH=str(PROJECT_ROOT))
    for flag in ("--help", "--version"):
        module = subprocess.run([sys.executable, "-m", "posegraph", flag], capture_output=True, text=True,
                                timeout=60, env=env)
        assert module.returncode == 0, module.stderr
        assert module.stdout == run_cli(flag).stdout


def test_the_console_script_entry_point_is_the_packaged_program(capsys):
    """pyproject's ``posegraph`` script names ``main`` inside the package, and no top-level module is installed."""
    import importlib
    import tomllib

    from tests.cli.conftest import PROJECT_ROOT

    config = tomllib.loads((PROJECT_ROOT / "pyproject.toml").read_text())
    module_name, function_name = config["project"]["scripts"]["posegraph"].split(":")
    assert module_name.split(".")[0] == "posegraph"
    assert "py-modules" not in config.get("tool", {}).get("setuptools", {})
    main = getattr(importlib.import_module(module_name), function_name)
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == run_cli("--version").stdout


def test_info_figures_match_gtsam_and_the_graph(shared_dataset):
    gtsam = pytest.importorskip("gtsam")
    from posegraph.model.graph import connected_components
    from posegraph.io.g2o import read_g2o

    path = shared_dataset("parking-garage")
    info = json.loads(run_cli("info", path, "--json").stdout)
    factors, values = gtsam.readG2o(str(path), True)
    assert info["num_vertices"] == values.size()
    assert info["num_edges"] == factors.size()
    assert info["initial_cost"] == pytest.approx(factors.error(values), rel=1e-9)
    graph = read_g2o(path)
    assert info["num_components"] == connected_components(graph)[0]
    degree = np.bincount(np.r_[graph.edge_from, graph.edge_to], minlength=graph.num_vertices)
    assert (info["degree_min"], info["degree_max"]) == (degree.min(), degree.max())
    assert info["num_odometry_edges"] + info["num_loop_closures"] == graph.num_edges
    diag = np.diagonal(graph.information, axis1=1, axis2=2)
    assert info["information"]["rotation"]["diagonal_max"] == diag[:, :3].max()
    assert info["information"]["translation"]["diagonal_min"] == diag[:, 3:].min()

    text = run_cli("info", path)
    assert text.returncode == 0
    assert re.search(rf"vertices:\s+{info['num_vertices']}\b", text.stdout)
    assert re.search(rf"edges:\s+{info['num_edges']}: {info['num_odometry_edges']} odometry", text.stdout)
    cost = float(re.search(r"initial cost:\s+(\S+)", text.stdout).group(1))
    assert cost == pytest.approx(info["initial_cost"], rel=1e-11)


def test_info_on_a_malformed_file(tmp_path):
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 0 1 0 0 0 0 0 1\n"
                   "EDGE_SE3:QUAT 0 0 1 0 0 0 0 0 1" + " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n")
    assert_one_error_line(run_cli("info", bad), f"{bad}:")


def test_input_warnings_are_one_line_each(tmp_path):
    """Repairs are reported as `posegraph: warning: file:line: …`, one line each, and the command runs."""
    info = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
    text = "\n".join([
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1",
        "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 2",  # quaternion norm 2: normalised
        "VERTEX_SE3:QUAT 2 5 0 0 0 0 0 1",
        "VERTEX_SE3:QUAT 3 6 0 0 0 0 0 1",
        "PARAMS_CAMERACALIB 0 500 320 240 0 0",  # unknown tag: skipped
        f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {info}",
        f"EDGE_SE3:QUAT 2 3 1 0 0 0 0 0 1 {info}",  # a second component
    ]) + "\n"
    path = tmp_path / "repairs.g2o"
    path.write_text(text)
    run = run_cli("info", path)
    assert run.returncode == 0, run.stderr
    warnings = run.stderr_lines
    assert len(warnings) == 3, run.stderr
    assert all(line.startswith(f"posegraph: warning: {path}") for line in warnings)
    assert any(f"{path}:2:" in line and "quaternion" in line for line in warnings)
    assert any(f"{path}:5:" in line and "PARAMS_CAMERACALIB" in line for line in warnings)
    assert any("2 connected components" in line for line in warnings)
    assert re.search(r"components:\s+2", run.stdout)


def test_an_edge_only_file_is_described_with_a_note_as_optimize_reads_it(tmp_path):
    """Edges but no vertex lines (gtsam's sphere2500.txt, victoria_park.txt): ``info`` describes the graph
    whose vertices the edges name, at the identity, and says so; ``optimize`` reads it the same way."""
    path = tmp_path / "edges.g2o"
    path.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\nEDGE_SE2 0 2 2 0 0 1 0 0 1 0 1\n")
    run = run_cli("info", path)
    assert run.returncode == 0, run.stderr
    assert re.search(r"^vertices:\s+3 ", run.stdout, re.M)
    assert re.search(r"^note:\s+the file has no vertex lines: the 3 vertices .* identity", run.stdout, re.M)
    described = json.loads(run_cli("info", path, "--json").stdout)
    assert described["num_vertices"] == 3 and len(described["notes"]) == 1 and described["optimize_refuses"] == []


def test_a_file_with_neither_vertices_nor_edges_is_still_refused(tmp_path):
    path = tmp_path / "empty.g2o"
    path.write_text("# nothing\n")
    run = run_cli("info", path)
    assert_one_error_line(run, "no pose graph to read")
