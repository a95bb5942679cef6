"""The command started with standard input, output or error closed, as a daemon or cron may start it
(``posegraph optimize in.g2o -o out.g2o <&- >&- 2>&-``): the work is done and its files written."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli.conftest import CLI, run_cli

EXAMPLE = Path(__file__).resolve().parents[2] / "datasets" / "example_sphere.g2o"
GROUND_TRUTH = EXAMPLE.with_name("example_sphere_groundtruth.g2o")


def run_closed(closed: tuple, *args) -> subprocess.CompletedProcess:
    """``python cli.py ARGS…`` with the descriptors ``closed`` (of 0, 1, 2) closed, as the shell's
    ``<&-``, ``>&-``, ``2>&-`` leave them; stderr is captured when it is open."""

    def close() -> None:  # runs in the child after the pipes are in place, before Python starts
        for fd in closed:
            os.close(fd)

    return subprocess.run([sys.executable, str(CLI), *map(str, args)], preexec_fn=close, timeout=300,
                          stdin=None if 0 in closed else subprocess.DEVNULL,
                          stdout=None if 1 in closed else subprocess.PIPE,
                          stderr=None if 2 in closed else subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def expected(tmp_path_factory) -> str:
    """The result of a run with every stream open."""
    out = tmp_path_factory.mktemp("open") / "out.g2o"
    assert run_cli("optimize", EXAMPLE, "-o", out, "-q").returncode == 0
    return out.read_text()


@pytest.mark.parametrize("closed", [(0,), (1,), (2,), (0, 1), (0, 1, 2)])
def test_optimize_writes_its_outputs_with_streams_closed(closed, expected, tmp_path):
    out, report = tmp_path / "out.g2o", tmp_path / "report.json"
    run = run_closed(closed, "optimize", EXAMPLE, "-o", out, "--report", report)
    assert run.returncode == 0, run.stderr
    assert out.read_text() == expected
    assert report.stat().st_size > 0
    if 2 not in closed:  # progress and summary are discarded, never an error
        assert "error" not in run.stderr, run.stderr
        assert "read " in run.stderr


@pytest.mark.parametrize("argv", [
    ["info", EXAMPLE], ["info", EXAMPLE, "--json"], ["eval", EXAMPLE, GROUND_TRUTH], ["info", "--help"], ["--version"],
])
def test_printing_commands_succeed_with_every_stream_closed(argv):
    assert run_closed((0, 1, 2), *argv).returncode == 0


def test_certify_writes_its_estimate_with_every_stream_closed(tmp_path):
    run = run_closed((0, 1, 2), "certify", EXAMPLE, "-o", tmp_path / "c.g2o", "--report", tmp_path / "c.json")
    assert run.returncode == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.g2o", "c.json"]


def test_result_to_a_closed_standard_output_is_a_usage_error(tmp_path):
    run = run_closed((1,), "optimize", EXAMPLE, "-o", "-", "--report", tmp_path / "r.json")
    assert run.returncode == 2
    assert run.stderr.strip() == ("posegraph: error: the result cannot go to standard output (-): it is closed; "
                                  "give a file name")
    assert list(tmp_path.iterdir()) == []


def test_reading_a_closed_standard_input_is_a_usage_error(tmp_path):
    run = run_closed((0,), "optimize", "-", "-o", tmp_path / "out.g2o")
    assert run.returncode == 2
    assert run.stderr.strip() == "posegraph: error: standard input (-) is closed: give a file name"
    assert list(tmp_path.iterdir()) == []
    run = run_closed((0,), "eval", "-", GROUND_TRUTH)
    assert (run.returncode, run.stderr.strip()) == (2, "posegraph: error: standard input (-) is closed: give a file name")
