"""posegraph.optimize_many and its parts: options to command lines, output names, the skip test, rows."""

from __future__ import annotations

import json
import os

import pytest

from posegraph.batch import BatchError
from posegraph.batch.files import outputs_complete, output_stem, plan_jobs
from posegraph.batch.options import check_options, file_option_defaults, option_argv
from posegraph.batch.rows import file_row, write_summary
from tests.cli.conftest import run_cli
from tests.optional import import_or_skip

MALFORMED = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 1 0 0\n"


# --------------------------------------------------------------------------------------------
# options: optimize's per-file options as keywords, and back to a command line


def test_options_at_their_defaults_give_an_empty_command_line():
    defaults = file_option_defaults()
    assert defaults["max_iterations"] == 100 and defaults["robust"] == "none" and defaults["fix"] == []
    assert {"method", "init", "repair_information", "strict_known_inliers", "stats", "quiet"} <= set(defaults)
    assert option_argv({}) == [] and option_argv(defaults) == []


def test_option_argv_is_parsed_back_by_optimize_to_the_same_options():
    from posegraph.cli.parser import build_parser

    options = dict(method="gn", init="odometry", max_iterations=20, relative_tolerance=1e-9, robust="gnc",
                   robust_scale=3.5, known_inliers="none", reanalyse_fraction=0.98, fix=[0, 7],
                   repair_information=True, stats=True, quiet=True, linear_solver="scipy")
    argv = option_argv(options)
    assert argv[:2] == ["--repair-information", "--method"] and "-i" not in argv
    args = build_parser(only="optimize").parse_args(["optimize", "in.g2o", "-o", "out.g2o", *argv])
    assert {name: getattr(args, name) for name in options} == options


def test_unknown_or_refused_options_raise_before_any_work(tmp_path):
    with pytest.raises(TypeError, match="unknown optimize option max_iteration"):
        option_argv({"max_iteration": 3})
    with pytest.raises(BatchError, match="--drop-outliers needs a robust loss"):
        check_options(option_argv({"drop_outliers": True}), "a.g2o", "b.g2o")
    with pytest.raises(BatchError, match="invalid choice"):
        check_options(option_argv({"method": "newton"}), "a.g2o", "b.g2o")


@pytest.mark.parametrize("vertex_id", [10**21, 2**63])
def test_a_fix_id_beyond_int64_is_refused_with_the_options(tmp_path, vertex_id):
    """Not an OverflowError in each file's log: ``optimize``'s usage error, before anything is made."""
    import posegraph

    (tmp_path / "in.g2o").write_text(MALFORMED)
    with pytest.raises(BatchError, match=r"argument --fix: too large: .* \(at most 2\^63 - 1 = 9223372036854775807\)"):
        posegraph.optimize_many([tmp_path / "in.g2o"], tmp_path / "out", fix=[vertex_id])
    assert sorted(os.listdir(tmp_path)) == ["in.g2o"]


def test_a_scheduler_that_does_not_answer_leaves_nothing_behind(tmp_path, monkeypatch):
    """Nothing is made until the cluster answers; the message says how long it waited."""
    import socket

    import posegraph
    import posegraph.batch.cluster as cluster

    import_or_skip("distributed", "--scheduler")
    monkeypatch.setattr(cluster, "CONNECT_SECONDS", 1)
    with socket.socket() as probe:  # a port nothing listens on: bound, then freed
        probe.bind(("127.0.0.1", 0))
        address = "tcp://127.0.0.1:%d" % probe.getsockname()[1]
    (tmp_path / "in.g2o").write_text(MALFORMED)
    with pytest.raises(BatchError) as info:
        posegraph.optimize_many([tmp_path / "in.g2o"], tmp_path / "out" / "deeper", scheduler=address)
    message = str(info.value)
    assert message.startswith(f"cannot reach the Dask scheduler at {address} (waited ") and " s): " in message
    assert message.endswith("; nothing was written")
    assert sorted(os.listdir(tmp_path)) == ["in.g2o"]


def test_an_output_folder_that_cannot_be_made_is_refused_before_the_cluster(tmp_path):
    import posegraph

    (tmp_path / "in.g2o").write_text(MALFORMED)
    (tmp_path / "file").write_text("")
    with pytest.raises(BatchError, match=f"cannot make the output folder {tmp_path}/file/out: {tmp_path}/file is a file"):
        posegraph.optimize_many([tmp_path / "in.g2o"], tmp_path / "file" / "out", scheduler="tcp://127.0.0.1:1")
    assert sorted(os.listdir(tmp_path)) == ["file", "in.g2o"]


# --------------------------------------------------------------------------------------------
# files: names in OUT_DIR and the skip test


@pytest.mark.parametrize("name, stem", [("a/sphere.g2o", "sphere"), ("b/city.g2o.gz", "city"),
                                        ("c/sphere2500.txt", "sphere2500"), ("d/noext", "noext"),
                                        ("e/x.y.g2o.xz", "x.y")])
def test_output_stem_drops_the_compression_suffix_and_the_extension(name, stem):
    assert output_stem(name) == stem


def test_plan_jobs_names_every_output_and_the_command(tmp_path):
    [job] = plan_jobs(["in/a.g2o.bz2"], str(tmp_path), ["--method", "gn"], plot=True, covariances=True)
    base = str(tmp_path / "a")
    assert job.given == "in/a.g2o.bz2" and job.input == os.path.abspath("in/a.g2o.bz2")
    assert job.outputs == (base + ".g2o", base + ".report.json", base + ".png", base + ".cov.npz", base + ".log")
    assert job.argv == ["optimize", job.input, "-o", base + ".g2o", "--report", base + ".report.json",
                        "--method", "gn", "--plot", base + ".png", "--covariances", base + ".cov.npz"]


def test_plan_jobs_refuses_shared_outputs_and_overwriting_an_input(tmp_path):
    with pytest.raises(BatchError, match="would write the same outputs"):
        plan_jobs(["x/a.g2o", "y/a.g2o.gz"], str(tmp_path), [])
    with pytest.raises(BatchError, match="would overwrite an input"):
        plan_jobs([str(tmp_path / "a.g2o")], str(tmp_path), [])


def test_outputs_are_complete_only_with_the_same_command_success_and_newer_than_the_input(tmp_path):
    source = tmp_path / "a.g2o"
    source.write_text("x")
    [job] = plan_jobs([str(source)], str(tmp_path / "out"), [])
    os.mkdir(tmp_path / "out")
    for path in (job.output, job.report):
        open(path, "w").close()
    assert not outputs_complete(job)  # no log
    with open(job.log, "w") as f:
        f.write(f"{job.command}\nfinal cost: 1\nexit status 0\n")
    assert outputs_complete(job)
    [other] = plan_jobs([str(source)], str(tmp_path / "out"), ["--method", "gn"])
    assert not outputs_complete(other)
    later = os.stat(job.log).st_mtime_ns + 10**9
    os.utime(source, ns=(later, later))
    assert not outputs_complete(job)
    for path in job.outputs:
        os.utime(path, ns=(later, later))
    assert outputs_complete(job)
    with open(job.log, "w") as f:
        f.write(f"{job.command}\nexit status 1\n")
    assert not outputs_complete(job)


# --------------------------------------------------------------------------------------------
# rows and the summary


def test_a_failed_file_row_carries_optimizes_last_error_line(tmp_path):
    [job] = plan_jobs(["bad.g2o"], str(tmp_path), [])
    printed = "read …\nposegraph: warning: something\nposegraph: error: bad.g2o:3: EDGE_SE3:QUAT needs 30 fields\n"
    row = file_row(job, 2, printed, 0.25)
    assert row["status"] == "failed" and row["reason"] == "bad.g2o:3: EDGE_SE3:QUAT needs 30 fields"
    assert row["final_cost"] is None and row["output"] is None and row["seconds"] == 0.25


def test_summary_json_and_csv_hold_the_same_rows(tmp_path):
    import csv

    [job] = plan_jobs(["a.g2o"], str(tmp_path), [])
    with open(job.report, "w") as f:
        json.dump({"num_vertices": 3, "num_edges": 2, "final_cost": 0.1 + 0.2, "chi2_per_dof": 1.5,
                   "iterations": 4, "converged": False, "outlier_edges": [1]}, f)
    rows = [file_row(job, 1, "posegraph: warning: the solver stopped before converging\n", 1.0)]
    write_summary(rows, str(tmp_path / "s.json"))
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["files"] == rows and summary["counts"]["not converged"] == 1
    assert rows[0]["outliers"] == 1 and rows[0]["reason"] == "the solver stopped before converging"
    with open(tmp_path / "s.csv", newline="") as f:
        [line] = list(csv.DictReader(f))
    assert float(line["final_cost"]) == 0.1 + 0.2 and line["status"] == "not converged" and line["outliers"] == "1"


# --------------------------------------------------------------------------------------------
# optimize_many on a client the caller made


@pytest.fixture(scope="module")
def client():
    from posegraph.batch.cluster import LOCAL_CLUSTER_OPTIONS, kept_environment

    distributed = import_or_skip("distributed", "optimize_many")
    with kept_environment(), distributed.LocalCluster(n_workers=2, **LOCAL_CLUSTER_OPTIONS) as cluster:
        with distributed.Client(cluster, set_as_default=False) as connected:
            yield connected


def test_optimize_many_with_a_client(client, shared_dataset, tmp_path):
    import posegraph

    paths = [shared_dataset("tinyGrid3D"), shared_dataset("intel"), tmp_path / "bad.g2o"]
    paths[-1].write_text(MALFORMED)
    seen = []
    rows = posegraph.optimize_many(paths, tmp_path / "out", client=client, robust="huber",
                                   progress=lambda row, counts: seen.append(dict(counts)))
    assert [row["status"] for row in rows] == ["ok", "ok", "failed"]
    assert rows[2]["reason"].startswith(f"{paths[2]}:2: EDGE_SE3:QUAT needs 30 fields")
    assert seen[0]["running"] == 2 and seen[0]["done"] == 0 and seen[-1] == dict(
        done=2, failed=1, running=0, waiting=0, total=3, skipped=0)
    for path, row in zip(paths[:2], rows):
        direct = tmp_path / f"direct-{path.stem}.g2o"
        assert run_cli("optimize", path, "-o", direct, "--robust", "huber", "-q").returncode == 0
        assert (tmp_path / "out" / f"{path.stem}.g2o").read_bytes() == direct.read_bytes()
        assert row["outliers"] is not None
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["files"] == rows
    again = posegraph.optimize_many(paths[:2], tmp_path / "out", client=client, robust="huber")
    assert [row["status"] for row in again] == ["skipped", "skipped"]
    assert [row["final_cost"] for row in again] == [row["final_cost"] for row in rows[:2]]
    assert client.status == "running"  # a client given is not closed
    with pytest.raises(BatchError, match="at most one of client, scheduler and workers"):
        posegraph.optimize_many(paths[:1], tmp_path / "other", client=client, workers=2)
    assert not (tmp_path / "other").exists()


def test_a_local_cluster_leaves_the_callers_environment_as_it_was(shared_dataset, tmp_path, monkeypatch):
    import posegraph

    import_or_skip("distributed", "optimize_many")
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "MALLOC_TRIM_THRESHOLD_"):
        monkeypatch.delenv(name, raising=False)
    before = dict(os.environ)
    [row] = posegraph.optimize_many([shared_dataset("tinyGrid3D")], tmp_path, workers=1)
    assert row["status"] == "ok" and dict(os.environ) == before


def test_a_task_that_fails_on_the_cluster_is_one_failed_row(client, tmp_path):
    from posegraph.batch.many import _row_of

    [job] = plan_jobs(["a.g2o"], str(tmp_path), [])
    future = client.submit(lambda: 1 / 0, pure=False)
    row = _row_of(future, job)
    assert row["status"] == "failed" and row["file"] == "a.g2o"
    assert row["reason"] == "the task failed on the cluster (ZeroDivisionError: division by zero)"
