"""What `posegraph optimize` does to start fast: lean imports, one BLAS thread, frozen imports, and
the same results and report with --quiet (where it skips the costs nobody sees)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from tests.cli.conftest import PROJECT_ROOT, run_cli


def run_python(code: str, **env) -> subprocess.CompletedProcess:
    environment = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    environment.update(env)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=PROJECT_ROOT,
        env=environment, timeout=120,
    )


def test_solver_imports_leave_out_what_the_default_path_does_not_use():
    proc = run_python(
        """
        import gc, os, sys
        from posegraph.cli import startup
        startup.single_threaded_blas()  # before numpy loads, as import_solver_modules does first
        from posegraph.linalg import cholmod
        cholmod.load = lambda: None  # the path without cvxopt (SuperLU), which imports scipy.sparse
        startup.import_solver_modules()
        unused = ["numpy.f2py", "numpy.testing", "numpy.ma", "numpy.polynomial", "scipy.sparse.csgraph",
                  "scipy.sparse.linalg", "scipy.linalg"]
        print("loaded", [name for name in unused if name in sys.modules])
        import numpy, scipy.sparse
        # numpy is as it was: its full namespace, and the lazily loaded submodules still load.
        print("all", all(name in numpy.__all__ for name in ("f2py", "testing", "ma")), "testing" in dir(numpy))
        import numpy.testing
        numpy.testing.assert_array_equal(numpy.arange(3), [0, 1, 2])
        matrix = scipy.sparse.csr_matrix(numpy.eye(3))
        print("sparse", (matrix @ numpy.ones(3)).tolist())
        print("threads", os.environ.get("OPENBLAS_NUM_THREADS"), "frozen", gc.get_freeze_count() > 1000,
              "collecting", gc.isenabled())
        """
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "loaded []"
    assert lines[1] == "all True True"
    assert lines[2] == "sparse [1.0, 1.0, 1.0]"
    assert lines[3] == "threads 1 frozen True collecting True"  # the collector is off only during the imports


def test_with_cvxopt_cholmod_a_whole_run_imports_no_scipy(tmp_path, shared_dataset):
    from posegraph.linalg import cholmod

    if cholmod.load() is None:
        pytest.skip(f"CHOLMOD is not available: {cholmod.unavailable_reason()}")
    source, output, report = shared_dataset("smallGrid3D"), tmp_path / "out.g2o", tmp_path / "report.json"
    proc = run_python(
        f"""
        import sys
        from posegraph import cli
        code = cli.main(["optimize", {str(source)!r}, "-o", {str(output)!r}, "--quiet", "--report", {str(report)!r}])
        print(code, sorted(name for name in sys.modules if name.split(".")[0] == "scipy"))
        print(sorted(name for name in ("shutil", "tempfile", "random", "pathlib", "fractions") if name in sys.modules))
        """
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["0", "[]", "[]"]  # nor what argparse, tempfile or so3 might have pulled in
    assert json.loads(report.read_text())["linear_solver"].startswith("cholmod (supernodal, amd")


def test_an_explicit_openblas_thread_count_is_kept():
    proc = run_python(
        """
        import os
        from posegraph.cli import startup
        startup.import_solver_modules()
        print(os.environ["OPENBLAS_NUM_THREADS"])
        """,
        OPENBLAS_NUM_THREADS="2",
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "2"


def test_quiet_runs_report_the_same_costs(tmp_path, shared_dataset):
    """With --quiet the start cost comes from the solver's first evaluation instead of a separate one;
    the report must not notice, and the written result must be the same file."""
    source = shared_dataset("smallGrid3D")
    reports, outputs = {}, {}
    for mode, flags in (("loud", []), ("quiet", ["--quiet"])):
        outputs[mode], reports[mode] = tmp_path / f"{mode}.g2o", tmp_path / f"{mode}.json"
        run = run_cli("optimize", source, "-o", outputs[mode], "--report", reports[mode], *flags)
        assert run.returncode == 0, run.stderr
    loud, quiet = (json.loads(reports[mode].read_text()) for mode in ("loud", "quiet"))
    for key in ("file_cost", "initial_cost", "final_cost", "chi2", "chi2_per_dof", "iterations"):
        assert quiet[key] == loud[key], key
    assert "start_cost" not in quiet  # the same as initial_cost: one field, once
    assert outputs["quiet"].read_text() == outputs["loud"].read_text()


@pytest.mark.parametrize("report", [False, True])
def test_quiet_without_a_report_prints_nothing(tmp_path, shared_dataset, report):
    extra = ["--report", tmp_path / "r.json"] if report else []
    run = run_cli("optimize", shared_dataset("tinyGrid3D"), "-o", tmp_path / "out.g2o", "--quiet", *extra)
    assert run.returncode == 0, run.stderr
    assert run.stdout == "" and run.stderr_lines == []
    if report:
        assert json.loads((tmp_path / "r.json").read_text())["file_cost"] > 0


@pytest.mark.parametrize(
    "argv",
    [
        ["optimize", "in.g2o", "-o", "out.g2o", "--method", "gn", "--quiet"],
        ["compare", "in.g2o", "--gtsam-start", "own"],
        ["verify-jacobians", "--samples", "10"],
        ["info", "in.g2o"],
        ["eval", "a.g2o", "b.g2o", "--no-align"],
        ["plot", "a.g2o", "b.g2o", "-o", "a.png", "--title", "t"],
        ["export", "a.g2o", "--open3d", "a.json", "--loop-closures"],
    ],
)
def test_the_parser_built_for_one_command_parses_it_as_the_full_parser_does(argv):
    import argparse

    from posegraph.cli import parser

    full = parser.build_parser()
    commands = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert tuple(commands) == parser.COMMANDS
    expected = vars(full.parse_args(argv))
    assert expected["func"] is parser.command_module(argv[0]).run
    assert expected["func"].__module__ == "posegraph.cli." + argv[0].replace("-", "_")
    assert vars(parser.build_parser(only=argv[0]).parse_args(argv)) == expected


def test_freed_memory_is_kept_for_reuse_unless_the_user_tunes_malloc():
    import ctypes

    if not sys.platform.startswith("linux") or not hasattr(ctypes.CDLL(None), "gnu_get_libc_version"):
        pytest.skip("glibc's mallopt only")
    code = "from posegraph.cli import startup; print(startup.keep_freed_memory())"
    assert run_python(code).stdout.split() == ["True"]
    for variable in ("MALLOC_TOP_PAD_", "GLIBC_TUNABLES"):
        assert run_python(code, **{variable: "131072" if variable != "GLIBC_TUNABLES" else "glibc.malloc.top_pad=131072"}).stdout.split() == ["False"]


@pytest.mark.parametrize("argv", [["--help"], ["optimize", "--help"], ["batch", "--help"], ["plot", "--help"], ["export", "--help"]])
def test_help_loads_no_numpy(argv):
    """Help texts come from the parser alone: numpy (and with it BLAS, before its thread count is set
    for a solve) is not loaded by any subcommand module at import time."""
    proc = subprocess.run([sys.executable, "-X", "importtime", str(PROJECT_ROOT / "cli.py"), *argv],
                          capture_output=True, text=True, cwd=PROJECT_ROOT, timeout=60)
    assert proc.returncode == 0, proc.stderr
    imported = [line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines() if line.startswith("import time:")]
    assert imported and not [name for name in imported if name.split(".")[0] == "numpy"]


@pytest.mark.parametrize("columns", [None, "100", "abc", "0", "-5", "30"])
def test_help_is_as_wide_as_shutil_says(columns, monkeypatch):
    import shutil

    from posegraph.cli.parser import terminal_columns

    if columns is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", columns)
    assert terminal_columns() == shutil.get_terminal_size().columns


def test_a_large_graph_gets_glibcs_lean_malloc_settings_back():
    proc = run_python(
        """
        from posegraph.cli import startup
        print(startup.return_freed_memory())  # nothing to undo yet
        print(startup.keep_freed_memory(), startup.return_freed_memory(), startup.return_freed_memory())
        """
    )
    assert proc.returncode == 0, proc.stderr
    first, second = proc.stdout.splitlines()
    assert first == "False"
    assert second in ("True True False", "False False False")  # glibc; elsewhere nothing is changed


@pytest.mark.skipif(sys.platform == "win32", reason="SIGTERM and SIGHUP as POSIX delivers them")
def test_stop_signals_raise_as_interrupts_in_the_block_only():
    """In a child: SIGTERM and SIGHUP raise Interrupted(signum) inside the block; after it, the
    handlers are back (default); a SIGHUP ignored before (nohup) is not taken."""
    proc = run_python(
        """
        import os, signal
        from posegraph.cli.startup import stop_signals_interrupt
        from posegraph.errors import Interrupted
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        try:
            with stop_signals_interrupt():
                os.kill(os.getpid(), signal.SIGHUP)  # ignored: nothing happens
                os.kill(os.getpid(), signal.SIGTERM)
                print("not interrupted")
        except Interrupted as exc:
            print("raised", exc.signum, isinstance(exc, KeyboardInterrupt))
        print("after", signal.getsignal(signal.SIGTERM) == signal.SIG_DFL, signal.getsignal(signal.SIGHUP) == signal.SIG_IGN)
        """
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[:2] == [f"raised {int(signal.SIGTERM)} True", "after True True"]
