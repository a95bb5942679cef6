"""Helpers for the end-to-end tests: run the command line as a user would, in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CLI = PROJECT_ROOT / "cli.py"


def default_sigint() -> None:
    """``preexec_fn`` for a child that a test interrupts: Ctrl-C's default handling, which a child
    started from a background job (SIGINT ignored, as ``nohup cmd &`` leaves it) would otherwise
    inherit as ignored, so that Python never raises KeyboardInterrupt in it."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


@dataclass
class Run:
    args: list
    returncode: int
    stdout: str
    stderr: str

    @property
    def stderr_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


def run_cli(*args, cwd=None, timeout=300) -> Run:
    """``python cli.py ARGS…`` in a subprocess; returns its exit status and output."""
    argv = [sys.executable, str(CLI), *map(str, args)]
    env = dict(os.environ, PYTHONWARNINGS="default")
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, timeout=timeout, env=env)
    return Run(argv, proc.returncode, proc.stdout, proc.stderr)


@pytest.fixture
def cli():
    return run_cli


def assert_one_error_line(run: Run, *fragments: str) -> str:
    """Exit status 2 and exactly one line ``posegraph: error: …`` on stderr holding every fragment."""
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert len(run.stderr_lines) == 1, run.stderr
    line = run.stderr_lines[0]
    assert line.startswith("posegraph: error: "), line
    assert "Traceback" not in run.stderr
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    return line
