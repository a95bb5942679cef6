"""Messages for missing optional packages and interruptions, checked in-process (posegraph.cli.main) for speed."""

from __future__ import annotations

import pytest

from posegraph import cli


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("posegraph: error: "), err
    return lines[0]


def missing(name, hint):
    def raise_import_error(*args, **kwargs):
        raise ImportError(f"this command needs {name}, which is not installed; install it: {hint}")

    return raise_import_error


def test_missing_gtsam_says_how_to_install(monkeypatch, capsys, shared_dataset):
    import posegraph.crosscheck.gtsam_bridge as bridge

    monkeypatch.setattr(bridge, "require_gtsam", missing("gtsam", bridge.INSTALL_HINT))
    assert cli.main(["compare", str(shared_dataset("tinyGrid3D"))]) == 2
    assert 'pip install "posegraph[gtsam]"' in one_error_line(capsys)
    assert cli.main(["verify-jacobians"]) == 2
    assert "--no-gtsam" in one_error_line(capsys)


def test_missing_open3d_says_how_to_install(monkeypatch, capsys, tmp_path, shared_dataset):
    import posegraph.io.export_open3d as export

    monkeypatch.setattr(export, "require_open3d", missing("Open3D", export.INSTALL_HINT))
    status = cli.main(["export", str(shared_dataset("tinyGrid3D")), "--open3d", str(tmp_path / "g.json")])
    assert status == 2
    line = one_error_line(capsys)
    assert "pip install open3d" in line and "libusb-1.0-0" in line
    assert list(tmp_path.iterdir()) == []


def test_missing_matplotlib_is_found_before_any_work(monkeypatch, capsys, tmp_path, shared_dataset):
    import posegraph.analysis.plot as plot

    monkeypatch.setattr(plot, "require_matplotlib", missing("matplotlib", 'pip install "posegraph[plot]"'))
    out = tmp_path / "out.g2o"
    status = cli.main(["optimize", str(shared_dataset("tinyGrid3D")), "-o", str(out), "--plot", str(tmp_path / "f.png")])
    assert status == 2
    assert "posegraph[plot]" in one_error_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_a_bug_is_one_line_with_a_hint_and_its_traceback_under_debug(monkeypatch, capsys, shared_dataset, tmp_path):
    """A bug (here an ImportError of our own module) is neither a usage error nor a traceback: exit
    status 3 and one line pointing at --debug, which shows the traceback."""
    import posegraph.solve as solve

    def broken(*args, **kwargs):
        raise ImportError("No module named 'posegraph.nonexistent'", name="posegraph.nonexistent")

    monkeypatch.setattr(solve, "optimize", broken)
    argv = ["optimize", str(shared_dataset("tinyGrid3D")), "-o", str(tmp_path / "out.g2o"), "--quiet"]
    assert cli.main(argv) == 3
    line = one_error_line(capsys)
    assert "internal error" in line and "posegraph.nonexistent" in line and "--debug" in line
    with pytest.raises(ImportError):
        cli.main([*argv, "--debug"])
    assert list(tmp_path.iterdir()) == []


def test_interrupt_while_writing_leaves_nothing(monkeypatch, capsys, tmp_path, shared_dataset):
    """Ctrl-C after the result is staged but while the report is written: no output at all."""
    import posegraph.analysis.report as report

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "optimize_report", interrupted)
    status = cli.main(["optimize", str(shared_dataset("tinyGrid3D")), "-o", str(tmp_path / "out.g2o"),
                       "--report", str(tmp_path / "r.json"), "--quiet"])
    assert status == 130
    assert "interrupted" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_open3d_that_cannot_load_says_why_and_what_to_install(monkeypatch, capsys, tmp_path, shared_dataset):
    """Installed but unloadable (Debian without libusb): one line with the loader's reason and the apt package."""
    import importlib.abc
    import sys

    class BrokenOpen3D(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "open3d":
                raise ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
            return None

    monkeypatch.delitem(sys.modules, "open3d", raising=False)
    monkeypatch.setattr(sys, "meta_path", [BrokenOpen3D(), *sys.meta_path])
    status = cli.main(["export", str(shared_dataset("tinyGrid3D")), "--ply", str(tmp_path / "t.ply")])
    assert status == 2
    line = one_error_line(capsys)
    assert "installed but cannot load" in line and "libusb-1.0.so.0" in line and "apt install libusb-1.0-0" in line
    assert list(tmp_path.iterdir()) == []


WARNING_SCRIPT = """
import sys, warnings
import posegraph.cli.info as info
from posegraph.errors import InputWarning

real = info.run

def run(args):
    warnings.warn_explicit("a library's deprecation", DeprecationWarning, "somelib.py", 1, module="somelib")
    for _ in range(2):
        warnings.warn("our note", InputWarning)
    return real(args)

info.run = run
from posegraph.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("debug", [False, True])
def test_only_posegraph_warnings_show_unless_debug(tmp_path, debug):
    """posegraph's own warnings show every time; another package's deprecation follows Python's
    default filters (hidden outside __main__), and --debug shows everything."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "datasets" / "example_sphere.g2o"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    argv = [sys.executable, "-c", WARNING_SCRIPT, "info", str(example)] + (["--debug"] if debug else [])
    run = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=Path(__file__).resolve().parents[2], timeout=120)
    assert run.returncode == 0, run.stderr
    lines = run.stderr.splitlines()
    assert lines.count("posegraph: warning: our note") == 2, run.stderr
    deprecations = [line for line in lines if "a library's deprecation" in line]
    assert deprecations == (["posegraph: warning: DeprecationWarning: a library's deprecation"] if debug else []), run.stderr
