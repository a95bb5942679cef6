"""What a g2o user types: `-i N`, `-` for standard input and output, `--fix ID…`; and the
inspection and comparison commands as such a user reads them (`info` on a refused file, `compare`
phases, `eval` units)."""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys

import numpy as np
import pytest

from posegraph import cli
from tests.cli.conftest import PROJECT_ROOT, assert_one_error_line, run_cli


def test_dash_i_is_the_iteration_cap_as_in_g2o(tmp_path, shared_dataset):
    out, report = tmp_path / "out.g2o", tmp_path / "r.json"
    run = run_cli("optimize", "-i", "20", "-o", out, "--report", report, shared_dataset("tinyGrid3D"), "--quiet")
    assert run.returncode == 0, run.stderr
    assert json.loads(report.read_text())["settings"]["max_iterations"] == 20
    run = run_cli("optimize", "-i", "1", "-o", out, shared_dataset("tinyGrid3D"), "--init", "file", "--quiet")
    assert run.returncode == 1 and "before converging" in run.stderr


def test_dash_reads_standard_input_and_writes_standard_output(tmp_path, shared_dataset):
    from posegraph.io.g2o import read_g2o

    source = shared_dataset("tinyGrid3D")
    proc = subprocess.run([sys.executable, str(PROJECT_ROOT / "cli.py"), "optimize", "-", "-o", "-"],
                          input=source.read_bytes(), capture_output=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert list(tmp_path.iterdir()) == []  # no file named "-"
    (tmp_path / "out.g2o").write_bytes(proc.stdout)  # stdout is the result alone
    result, original = read_g2o(tmp_path / "out.g2o"), read_g2o(source)
    np.testing.assert_array_equal(result.ids, original.ids)
    stderr = proc.stderr.decode()
    assert "read <stdin>: 9 vertices" in stderr and "output:         <stdout>" in stderr  # the summary too
    final = float(re.search(r"^final cost:\s+(\S+)", stderr, re.MULTILINE).group(1))
    from posegraph.solve.residuals import cost

    assert cost(result) == pytest.approx(final, rel=1e-9)


def test_dash_as_input_of_info_and_as_report(monkeypatch, capsys, tmp_path, shared_dataset):
    source = shared_dataset("tinyGrid3D")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(source.read_bytes())))
    assert cli.main(["info", "-", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["num_edges"] == 11
    assert cli.main(["optimize", str(source), "-o", str(tmp_path / "o.g2o"), "--report", "-", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["final_cost"] == pytest.approx(9.3139094, rel=1e-6)
    assert cli.main(["eval", "-", "-"]) == 2
    assert "standard input (-) can be read only once" in capsys.readouterr().err
    assert cli.main(["export", str(source), "--ply", "-"]) == 2
    assert "cannot go to standard output" in capsys.readouterr().err


def test_fix_holds_vertices_by_id_and_leaves_the_file_s_fix_lines(tmp_path, shared_dataset):
    from posegraph.io.g2o import read_g2o

    source = shared_dataset("smallGrid3D")
    out, report = tmp_path / "out.g2o", tmp_path / "r.json"
    run = run_cli("optimize", source, "-o", out, "--report", report, "--fix", "0", "50", "--quiet")
    assert run.returncode == 0, run.stderr
    before, after = read_g2o(source), read_g2o(out)
    held = before.index_of([0, 50])
    np.testing.assert_allclose(after.poses[held], before.poses[held], atol=1e-15)
    assert not after.fixed.any() and "FIX" not in out.read_text()  # the output states the file's FIX lines only
    plain = tmp_path / "plain.g2o"
    assert run_cli("optimize", source, "-o", plain, "--fix", "0", "--quiet").returncode == 0
    # Holding a second vertex removes 6 more degrees of freedom and raises the optimum.
    assert json.loads(report.read_text())["dof"] == 6 * before.num_edges - 6 * (before.num_vertices - 2)
    from posegraph.solve.residuals import cost

    assert cost(after) > cost(read_g2o(plain)) * (1 + 1e-6)
    assert_one_error_line(run_cli("optimize", source, "-o", out, "--fix", "100000", "--quiet"), "--fix", "100000")


def test_info_describes_a_file_optimize_refuses(shared_dataset):
    source = shared_dataset("cubicle")
    run = run_cli("info", source)
    assert run.returncode == 0, run.stderr
    refusal = re.search(r"^optimize refuses:\s+(.*)$", run.stdout, re.MULTILINE).group(1)
    assert refusal.startswith("5021 information matrices are not positive semi-definite (the first at line 5753)")
    assert "--repair-information" in refusal
    assert re.search(r"^edges:\s+16869", run.stdout, re.MULTILINE)
    assert "Traceback" not in run.stderr and "error" not in run.stderr


def test_compare_labels_each_phase_by_what_each_tool_did(tmp_path, shared_dataset):
    pytest.importorskip("gtsam")
    report = tmp_path / "c.json"
    run = run_cli("compare", shared_dataset("tinyGrid3D"), "--quiet", "--report", report)
    assert run.returncode == 0, run.stdout + run.stderr
    # Same start: gtsam converted posegraph's poses, it did not initialise.
    assert re.search(r"^seconds initialise \(chordal\)\s+\d+\.\d{4}\s+–$", run.stdout, re.MULTILINE), run.stdout
    assert re.search(r"^seconds convert start\s+–\s+\d+\.\d{4}$", run.stdout, re.MULTILINE), run.stdout
    data = json.loads(report.read_text())
    assert set(data["gtsam"]["seconds"]) == {"read_file", "convert_start", "optimise", "total"}
    assert set(data["posegraph"]["seconds"]) == {"read_file", "initialise", "optimise", "total"}
    totals = data["gtsam"]["seconds"]
    assert totals["total"] == pytest.approx(totals["read_file"] + totals["convert_start"] + totals["optimise"])

    run = run_cli("compare", shared_dataset("tinyGrid3D"), "--quiet", "--gtsam-start", "own")
    assert re.search(r"^seconds initialise \(chordal\)\s+\d+\.\d{4}\s+\d+\.\d{4}$", run.stdout, re.MULTILINE)
    assert "convert start" not in run.stdout


def test_eval_table_has_units_and_one_number_format(tmp_path, shared_dataset):
    source = shared_dataset("smallGrid3D")
    run = run_cli("eval", source, source)
    assert run.returncode == 0, run.stderr
    rows = [line for line in run.stdout.splitlines() if line.startswith(("ATE", "RPE"))]
    labels = [re.match(r"(.*\))\s", row).group(1) for row in rows]
    assert labels == ["ATE translation (m)", "ATE rotation (deg)", "RPE translation (m)", "RPE rotation (deg)"]
    numbers = [token for row in rows for token in row[len("ATE translation (m)") + 1:].split()]
    assert len(numbers) == 24 and all(re.fullmatch(r"\d+\.\d{6}", token) for token in numbers), numbers
    data = json.loads(run_cli("eval", source, source, "--json").stdout)
    assert data["units"] == {"translation": "m", "rotation": "deg"}
