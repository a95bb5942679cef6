"""`posegraph batch` end to end on local Dask clusters: the summary, outputs equal to `optimize`'s
byte for byte, a malformed file one failed row, re-runs that skip, --force, --scheduler."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

from tests.cli.conftest import CLI, assert_one_error_line, default_sigint, run_cli
from tests.conftest import SHARED_DATASETS
from tests.optional import import_or_skip

import_or_skip("distributed", "posegraph batch")

GRAPHS = ("tinyGrid3D", "smallGrid3D", "intel", "manhattan", "parking-garage")
"""The smaller shared graphs (the batch's speed is measured in docs/benchmarks.md, not here)."""

MALFORMED = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 1 0 0\n"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The shared graphs present (skips without the folder) and a malformed file, last."""
    if not SHARED_DATASETS.is_dir():
        pytest.skip(f"shared datasets folder {SHARED_DATASETS} is absent (it sits next to the project in CI)")
    paths = [SHARED_DATASETS / f"{name}.g2o" for name in GRAPHS if (SHARED_DATASETS / f"{name}.g2o").is_file()]
    if not paths:
        pytest.skip(f"none of {GRAPHS} is in {SHARED_DATASETS}")
    bad = tmp_path_factory.mktemp("inputs") / "malformed.g2o"
    bad.write_text(MALFORMED)
    return [*paths, bad]


@pytest.fixture(scope="module")
def references(inputs, tmp_path_factory):
    """``{name: (exit status, result bytes or None, stderr)}`` of `posegraph optimize IN -o OUT`, one process each."""
    folder = tmp_path_factory.mktemp("optimize")
    found = {}
    for path in inputs:
        out = folder / (path.stem + ".g2o")
        run = run_cli("optimize", path, "-o", out, "--quiet")
        found[path.stem] = (run.returncode, out.read_bytes() if out.exists() else None, run.stderr)
    return found


@pytest.fixture(scope="module")
def first_run(inputs, tmp_path_factory):
    folder = tmp_path_factory.mktemp("batch")
    out, summary = folder / "out", folder / "summary.json"
    return out, summary, run_cli("batch", *inputs, "-o", out, "--workers", 2, "--report", summary)


def read_summary(path):
    with open(path, encoding="utf-8") as f:
        summary = json.load(f)
    with open(os.path.splitext(path)[0] + ".csv", encoding="utf-8", newline="") as f:
        table = list(csv.DictReader(f))
    return summary, table


def assert_outputs_equal(out, inputs, references):
    for path in inputs[:-1]:
        status, expected, _ = references[path.stem]
        assert status == 0 and expected is not None
        assert (out / (path.stem + ".g2o")).read_bytes() == expected, path.stem


def test_batch_summary_outputs_and_exit_status(first_run, inputs, references):
    import posegraph

    out, summary_path, run = first_run
    assert run.returncode == 1, run.stderr  # the malformed file failed
    summary, table = read_summary(summary_path)
    rows = summary["files"]
    assert [row["file"] for row in rows] == [str(p) for p in inputs]
    assert [row["status"] for row in rows] == ["ok"] * (len(inputs) - 1) + ["failed"]
    assert summary["counts"] == {"ok": len(inputs) - 1, "not converged": 0, "failed": 1, "skipped": 0}
    for path, row in zip(inputs[:-1], rows):
        graph = posegraph.read_g2o(out / (path.stem + ".g2o"))
        assert (row["vertices"], row["edges"]) == (graph.num_vertices, graph.num_edges)
        assert row["final_cost"] == pytest.approx(float(posegraph.cost(graph)), rel=1e-9)
        report = json.loads((out / (path.stem + ".report.json")).read_text())
        assert row["chi2_per_dof"] == report["chi2_per_dof"] and row["iterations"] == report["iterations"] > 0
        assert row["seconds"] > 0 and row["outliers"] is None and row["reason"] == ""
    # CSV and JSON hold the same rows
    assert [r["file"] for r in table] == [row["file"] for row in rows]
    assert [float(r["final_cost"]) for r in table[:-1]] == [row["final_cost"] for row in rows[:-1]]
    assert table[-1]["status"] == "failed" and table[-1]["final_cost"] == ""


def test_batch_outputs_are_optimizes_byte_for_byte(first_run, inputs, references):
    out, _, run = first_run
    assert_outputs_equal(out, inputs, references)


def test_a_malformed_file_is_one_failed_row_with_optimizes_message(first_run, inputs, references, tmp_path):
    out, summary_path, run = first_run
    row = read_summary(summary_path)[0]["files"][-1]
    status, result, stderr = references["malformed"]
    assert status == 2 and result is None
    message = stderr.strip().removeprefix("posegraph: error: ")
    assert row["reason"] == message and ":3: EDGE_SE3:QUAT needs 30 fields" in message
    assert not (out / "malformed.g2o").exists() and not (out / "malformed.report.json").exists()
    log = (out / "malformed.log").read_text().splitlines()
    assert log[0].startswith("$ posegraph optimize ") and log[-1] == "exit status 2"
    assert "malformed.g2o" in run.stderr and "1 of" in run.stderr
    # stderr is no terminal: one progress line per file as it ends, in the order they end
    progress = [line for line in run.stderr_lines if line.startswith("[")]
    assert [line.split("]")[0] for line in progress] == [f"[{k}/{len(inputs)}" for k in range(1, len(inputs) + 1)]
    assert f"] failed {inputs[-1]}: {message}" in run.stderr
    assert sum("] ok " in line for line in progress) == len(inputs) - 1


def test_each_log_holds_the_command_and_what_optimize_printed(first_run, inputs):
    out, _, _ = first_run
    for path in inputs[:-1]:
        log = (out / (path.stem + ".log")).read_text().splitlines()
        assert log[0] == (f"$ posegraph optimize {path} -o {out / (path.stem + '.g2o')} "
                          f"--report {out / (path.stem + '.report.json')}")
        assert any(line.startswith("final cost:") for line in log) and log[-1] == "exit status 0"


def test_rerun_skips_complete_files_and_force_redoes_them(first_run, inputs, references):
    out, summary_path, _ = first_run
    before = {p.stem: os.stat(out / (p.stem + ".g2o")).st_mtime_ns for p in inputs[:-1]}
    again = run_cli("batch", *inputs, "-o", out, "--workers", 2, "--report", summary_path)
    assert again.returncode == 1, again.stderr
    rows = read_summary(summary_path)[0]["files"]
    assert [row["status"] for row in rows] == ["skipped"] * (len(inputs) - 1) + ["failed"]
    assert all(row["final_cost"] is not None for row in rows[:-1])
    assert {p.stem: os.stat(out / (p.stem + ".g2o")).st_mtime_ns for p in inputs[:-1]} == before
    forced = run_cli("batch", *inputs, "-o", out, "--workers", 2, "--report", summary_path, "--force")
    assert forced.returncode == 1, forced.stderr
    rows = read_summary(summary_path)[0]["files"]
    assert [row["status"] for row in rows] == ["ok"] * (len(inputs) - 1) + ["failed"]
    assert all(os.stat(out / (p.stem + ".g2o")).st_mtime_ns > before[p.stem] for p in inputs[:-1])
    assert_outputs_equal(out, inputs, references)


def test_a_changed_input_or_other_options_are_redone(inputs, tmp_path):
    source = tmp_path / "grid.g2o"
    shutil.copyfile(inputs[0], source)
    out = tmp_path / "out"

    def statuses(*options):
        run = run_cli("batch", source, "-o", out, "--workers", 1, *options)
        assert run.returncode == 0, run.stderr
        return [row["status"] for row in json.loads((out / "summary.json").read_text())["files"]]

    assert statuses() == ["ok"]
    assert statuses() == ["skipped"]
    later = os.stat(out / "grid.g2o").st_mtime_ns + 10**9
    os.utime(source, ns=(later, later))  # the input changed after the outputs were made
    assert statuses() == ["ok"]
    assert statuses("--max-iterations", "50") == ["ok"]  # another command line
    assert statuses("--max-iterations", "50") == ["skipped"]


def test_batch_runs_on_the_cluster_scheduler_names(inputs, references, tmp_path):
    from posegraph.batch.cluster import LOCAL_CLUSTER_OPTIONS, kept_environment

    distributed = import_or_skip("distributed", "--scheduler")
    with kept_environment(), distributed.LocalCluster(n_workers=2, **LOCAL_CLUSTER_OPTIONS) as cluster:
        run = run_cli("batch", *inputs, "-o", tmp_path, "--scheduler", cluster.scheduler_address)
        ran = cluster.scheduler.task_prefixes.get("optimize_file")
        assert ran is not None and sum(ran.state_counts.values()) >= len(inputs)
    assert run.returncode == 1, run.stderr
    rows = json.loads((tmp_path / "summary.json").read_text())["files"]
    assert [row["status"] for row in rows] == ["ok"] * (len(inputs) - 1) + ["failed"]
    assert_outputs_equal(tmp_path, inputs, references)


def test_optimize_options_reach_each_file(inputs, tmp_path):
    out = tmp_path / "out"
    run = run_cli("batch", inputs[0], "-o", out, "--workers", 1, "--robust", "cauchy", "-i", 7, "--quiet")
    assert run.returncode in (0, 1), run.stderr
    assert run.stdout == ""  # --quiet: no table
    row = json.loads((out / "summary.json").read_text())["files"][0]
    direct = run_cli("optimize", inputs[0], "-o", tmp_path / "direct.g2o", "--robust", "cauchy", "-i", 7, "--quiet")
    assert (out / (inputs[0].stem + ".g2o")).read_bytes() == (tmp_path / "direct.g2o").read_bytes()
    assert row["outliers"] is not None and row["iterations"] <= 7
    assert run.returncode == direct.returncode
    command = (out / (inputs[0].stem + ".log")).read_text().splitlines()[0]
    assert command.endswith("--max-iterations 7 --robust cauchy --quiet"), command


@pytest.mark.parametrize("arguments, fragment", [
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with"),
    (["--drop-outliers"], "--drop-outliers needs a robust loss"),
    (["--workers", "0"], "must be >= 1"),
    (["--fix", "1000000000000000000000"], "argument --fix: too large"),  # not an OverflowError in each log
])
def test_usage_errors_are_one_line_and_run_nothing(inputs, tmp_path, arguments, fragment):
    run = run_cli("batch", inputs[0], "-o", tmp_path / "out", *arguments)
    assert_one_error_line(run, fragment)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_two_inputs_with_one_name_or_standard_input_are_refused(inputs, tmp_path):
    twin = tmp_path / "twin"
    twin.mkdir()
    shutil.copyfile(inputs[0], twin / inputs[0].name)
    assert_one_error_line(run_cli("batch", inputs[0], twin / inputs[0].name, "-o", tmp_path / "o"),
                          "would write the same outputs")
    assert_one_error_line(run_cli("batch", "-", "-o", tmp_path / "o"), "standard input")
    assert_one_error_line(run_cli("batch", twin / inputs[0].name, "-o", twin), "would overwrite an input")
    assert_one_error_line(run_cli("batch", inputs[0], "-o", tmp_path / "o", "--report", tmp_path / "o" / f"{inputs[0].stem}.log"),
                          "the summary", "would be an input or a file's output")
    assert_one_error_line(run_cli("batch", inputs[0], "-o", tmp_path / "o", "--report", tmp_path / "none" / "s.json"),
                          "folder", "does not exist")


def test_without_distributed_batch_says_how_to_install_it(inputs, tmp_path):
    import subprocess
    import sys

    from tests.cli.conftest import CLI

    code = ("import sys; sys.modules['distributed'] = None; sys.argv[0] = 'posegraph'; "
            f"sys.path.insert(0, {str(CLI.parent)!r}); from posegraph.cli import main; "
            f"sys.exit(main(['batch', {str(inputs[0])!r}, '-o', {str(tmp_path / 'o')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        'posegraph: error: posegraph batch needs Dask\'s distributed scheduler (dask.distributed), which is not '
        'installed: pip install "posegraph[batch]"']


def test_plot_and_covariances_are_each_files_and_count_for_completeness(inputs, tmp_path):
    import numpy as np

    import_or_skip("matplotlib", "--plot")
    out = tmp_path / "out"
    run = run_cli("batch", inputs[0], "-o", out, "--workers", 1, "--plot", "--covariances")
    assert run.returncode == 0, run.stderr
    stem = inputs[0].stem
    direct = run_cli("optimize", inputs[0], "-o", tmp_path / "d.g2o", "--covariances", tmp_path / "d.npz", "-q")
    assert direct.returncode == 0, direct.stderr
    with np.load(out / f"{stem}.cov.npz") as batch, np.load(tmp_path / "d.npz") as alone:
        assert np.array_equal(batch["ids"], alone["ids"]) and np.array_equal(batch["covariances"], alone["covariances"])
    assert (out / f"{stem}.png").stat().st_size > 10_000
    (out / f"{stem}.png").unlink()  # an output missing: the file is done again
    again = run_cli("batch", inputs[0], "-o", out, "--workers", 1, "--plot", "--covariances")
    assert json.loads((out / "summary.json").read_text())["files"][0]["status"] == "ok", again.stderr
    assert (out / f"{stem}.png").is_file()


def test_ctrl_c_stops_the_batch_keeping_the_files_finished(inputs, tmp_path):
    """SIGINT to the whole process group, as Ctrl-C in a terminal: exit 130, one line, no traceback
    from this process or its workers; the files finished are complete and a re-run skips them."""
    out = tmp_path / "out"
    many = [inputs[0]] + [tmp_path / f"copy{k}.g2o" for k in range(12)]
    biggest = max(inputs[:-1], key=lambda p: p.stat().st_size)  # parking-garage: 12 copies take seconds
    for path in many[1:]:
        shutil.copyfile(biggest, path)
    proc = subprocess.Popen([sys.executable, str(CLI), "batch", *many, "-o", out, "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=default_sigint)
    try:
        assert proc.stderr.readline().startswith("[1/13] ok ")  # a file has finished
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and stderr.strip().splitlines()[-1].startswith("posegraph: interrupted; ")
    finished = [p for p in many if (out / f"{p.stem}.log").exists()]
    assert finished and all((out / f"{p.stem}.g2o").exists() for p in finished)
    rerun = run_cli("batch", *finished, "-o", out, "--workers", 1)
    assert rerun.returncode == 0 and {r["status"] for r in json.loads((out / "summary.json").read_text())["files"]} == {"skipped"}
