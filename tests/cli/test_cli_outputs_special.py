"""Outputs named by a device, a FIFO, a link, a folder; modes kept; a full disk; signals (issue 33).

Every special file is made by the test under its own temporary folder (``os.mkfifo``; ``os.mknod``
of /dev/null's and /dev/full's twins, as root only), never a system path; signals go to a child
process at a point it announces (a marker file), so nothing depends on timing.
"""

from __future__ import annotations

import errno
import os
import signal
import stat
import subprocess
import sys
import textwrap
import threading

import pytest

from posegraph import cli
from tests.cli.conftest import PROJECT_ROOT, assert_one_error_line, run_cli

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, device nodes, modes and signals are POSIX")


@pytest.fixture
def graph(shared_dataset):
    return shared_dataset("tinyGrid3D")


def device_twin(path, minor: int = 3):
    """A character device at ``path``: (1, 3) is /dev/null's twin, (1, 7) /dev/full's."""
    if os.geteuid() != 0:
        pytest.skip("making a device node (mknod) needs root")
    os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    return path


class FifoReader:
    """A FIFO at ``path`` with a thread reading it to its end (the writer's open blocks until a reader)."""

    def __init__(self, path):
        self.path, self.data = path, None
        os.mkfifo(path)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        with open(self.path, "rb") as f:
            self.data = f.read()

    def received(self) -> bytes:
        self.thread.join(120)
        return self.data


def assert_node(path, kind) -> None:
    mode = os.lstat(path).st_mode
    assert (stat.S_ISFIFO(mode) if kind == "fifo" else stat.S_ISCHR(mode)), (path, oct(mode))


def make_nodes(tmp_path, kind: str, names):
    """One node of ``kind`` per name: FifoReader for "fifo", the path of a /dev/null twin for "device"."""
    if kind == "fifo":
        return {name: FifoReader(tmp_path / name) for name in names}
    return {name: device_twin(tmp_path / name) for name in names}


# --------------------------------------------------------------------------------------------
# devices and FIFOs: written into, left as they were


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_optimize_writes_every_output_into_devices_and_fifos(tmp_path, graph, kind):
    pytest.importorskip("matplotlib")
    names = ["out.g2o", "report.json", "cov.npz", "fig.png"]
    nodes = make_nodes(tmp_path, kind, names)
    run = run_cli("optimize", graph, "-o", tmp_path / "out.g2o", "--report", tmp_path / "report.json",
                  "--covariances", tmp_path / "cov.npz", "--plot", tmp_path / "fig.png", "-q")
    assert run.returncode == 0, run.stderr
    for name in names:
        assert_node(tmp_path / name, kind)
    if kind == "fifo":
        got = {name: nodes[name].received() for name in names}
        assert got["out.g2o"].startswith(b"VERTEX_SE3:QUAT ") and b"EDGE_SE3:QUAT " in got["out.g2o"]
        assert got["report.json"].startswith(b"{") and b'"final_cost"' in got["report.json"]
        assert got["cov.npz"].startswith(b"PK") and got["fig.png"].startswith(b"\x89PNG")
    assert sorted(os.listdir(tmp_path)) == sorted(names)  # no regular file beside, no temporary file


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_certify_writes_into_devices_and_fifos(tmp_path, graph, kind):
    nodes = make_nodes(tmp_path, kind, ["out.g2o", "cert.json"])
    run = run_cli("certify", graph, "-o", tmp_path / "out.g2o", "--report", tmp_path / "cert.json", "-q")
    assert run.returncode in (0, 1), run.stderr
    assert_node(tmp_path / "out.g2o", kind)
    assert_node(tmp_path / "cert.json", kind)
    if kind == "fifo":
        assert nodes["out.g2o"].received().startswith(b"VERTEX_SE3:QUAT ")
        assert b'"certified"' in nodes["cert.json"].received()
    assert sorted(os.listdir(tmp_path)) == ["cert.json", "out.g2o"]


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs Linux's /proc/self/fd")
def test_a_link_to_the_processs_stdout_gets_the_result_as_dev_stdout_would(tmp_path, graph):
    """``-o /dev/stdout`` without naming the system's /dev/stdout (which the bug replaced): a link
    made here to /proc/self/fd/1, as /dev/stdout is, leads to the child's stdout, a pipe; it gets
    the bytes a file gets, and the link stays a link."""
    os.symlink("/proc/self/fd/1", tmp_path / "stdout")
    as_file = run_cli("optimize", graph, "-o", tmp_path / "out.g2o", "-q")
    as_stdout = run_cli("optimize", graph, "-o", tmp_path / "stdout", "-q")
    assert as_file.returncode == 0 and as_stdout.returncode == 0, as_stdout.stderr
    assert as_stdout.stdout == (tmp_path / "out.g2o").read_text()
    assert os.readlink(tmp_path / "stdout") == "/proc/self/fd/1"
    assert sorted(os.listdir(tmp_path)) == ["out.g2o", "stdout"]


def test_a_full_device_is_one_line_naming_it_and_nothing_else_is_written(tmp_path, graph):
    full = device_twin(tmp_path / "full", minor=7)
    run = run_cli("optimize", graph, "-o", tmp_path / "out.g2o", "--report", full, "-q")  # found when written
    assert_one_error_line(run, f"{full}: cannot write the file: No space left on device")
    assert_node(full, "device")
    assert sorted(os.listdir(tmp_path)) == ["full"]  # devices are written before any rename: no out.g2o


# --------------------------------------------------------------------------------------------
# links: written through, at their target


def test_links_stay_links_and_their_targets_get_the_outputs(tmp_path, graph):
    pytest.importorskip("matplotlib")
    real = tmp_path / "real"
    real.mkdir()
    names = ["out.g2o", "report.json", "cov.npz", "fig.png"]
    for name in names:
        (real / name).write_text("old")
        os.symlink(real / name, tmp_path / f"link-{name}")
    run = run_cli("optimize", graph, "-o", tmp_path / "link-out.g2o", "--report", tmp_path / "link-report.json",
                  "--covariances", tmp_path / "link-cov.npz", "--plot", tmp_path / "link-fig.png", "-q")
    assert run.returncode == 0, run.stderr
    for name in names:
        assert os.readlink(tmp_path / f"link-{name}") == str(real / name)
    assert (real / "out.g2o").read_text().startswith("VERTEX_SE3:QUAT ")
    assert '"final_cost"' in (real / "report.json").read_text()
    assert (real / "cov.npz").read_bytes()[:2] == b"PK" and (real / "fig.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(os.listdir(real)) == sorted(names)  # no temporary file left beside the targets


def test_certify_writes_through_a_link(tmp_path, graph):
    (tmp_path / "real.g2o").write_text("old")
    os.symlink("real.g2o", tmp_path / "link.g2o")
    run = run_cli("certify", graph, "-o", tmp_path / "link.g2o", "-q")
    assert run.returncode in (0, 1), run.stderr
    assert os.readlink(tmp_path / "link.g2o") == "real.g2o"
    assert (tmp_path / "real.g2o").read_text().startswith("VERTEX_SE3:QUAT ")


def test_batch_summary_through_links(tmp_path, graph):
    pytest.importorskip("distributed")
    (tmp_path / "s.json").write_text("old")
    (tmp_path / "s.csv").write_text("old")
    os.symlink("s.json", tmp_path / "link.json")
    os.symlink("s.csv", tmp_path / "link.csv")
    run = run_cli("batch", graph, "-o", tmp_path / "out", "--report", tmp_path / "link.json", "--workers", 1, "-q")
    assert run.returncode == 0, run.stderr
    assert os.path.islink(tmp_path / "link.json") and os.path.islink(tmp_path / "link.csv")
    assert '"counts"' in (tmp_path / "s.json").read_text()
    assert (tmp_path / "s.csv").read_text().startswith("file,vertices,")
    assert sorted(os.listdir(tmp_path)) == ["link.csv", "link.json", "out", "s.csv", "s.json"]


def test_batch_summary_into_a_device_writes_no_csv_beside_it(tmp_path, graph):
    """``--report`` a device (``/dev/null``'s twin): the summary goes into it, and no ``.csv`` is made beside
    it (as root, ``--report /dev/null`` would otherwise leave a regular ``/dev/null.csv``)."""
    pytest.importorskip("distributed")
    device_twin(tmp_path / "null")
    run = run_cli("batch", graph, "-o", tmp_path / "out", "--report", tmp_path / "null", "--workers", 1)
    assert run.returncode == 0, run.stderr
    assert_node(tmp_path / "null", "device")
    assert sorted(os.listdir(tmp_path)) == ["null", "out"]
    assert f"summary: {tmp_path / 'null'}\n" in run.stdout


def test_batch_summary_csv_into_a_fifo(tmp_path, graph):
    """``--report S.json`` a file, its ``S.csv`` a FIFO: the CSV is written into the FIFO, left a FIFO."""
    pytest.importorskip("distributed")
    csv = FifoReader(tmp_path / "s.csv")
    run = run_cli("batch", graph, "-o", tmp_path / "out", "--report", tmp_path / "s.json", "--workers", 1, "-q")
    assert run.returncode == 0, run.stderr
    assert csv.received().startswith(b"file,vertices,")
    assert_node(tmp_path / "s.csv", "fifo")
    assert (tmp_path / "s.json").read_text().startswith("{")
    assert sorted(os.listdir(tmp_path)) == ["out", "s.csv", "s.json"]


# --------------------------------------------------------------------------------------------
# refused before any solving: a dangling link, a folder


OUTPUTS = [
    ("optimize", "-o", "what.g2o"), ("optimize", "--report", "what.json"), ("optimize", "--covariances", "what.npz"),
    ("optimize", "--plot", "what.png"), ("certify", "-o", "what.g2o"), ("certify", "--report", "what.json"),
    ("batch", "--report", "what.json"),
]


@pytest.mark.parametrize("bad", ["dangling", "folder"])
@pytest.mark.parametrize("command, option, name", OUTPUTS)
def test_a_dangling_link_or_a_folder_is_one_line_before_any_work(tmp_path, graph, command, option, name, bad):
    if option == "--plot":
        pytest.importorskip("matplotlib")
    target = tmp_path / name
    if bad == "dangling":
        os.symlink(tmp_path / "nowhere", target)
        reason = f"is a symbolic link to {tmp_path / 'nowhere'}, which does not exist"
    else:
        target.mkdir()
        reason = "it is a folder"
    argv = [command, graph]
    if command == "batch":
        argv += ["-o", tmp_path / "batch-out"]
    elif option != "-o":
        argv += ["-o", tmp_path / "result.g2o"]
    run = run_cli(*argv, option, target)  # not --quiet: any phase line (reading, solving) would show
    assert_one_error_line(run, str(target), reason)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # nothing written, nothing made
    assert not (tmp_path / "nowhere").exists()


# --------------------------------------------------------------------------------------------
# modes kept


def test_overwritten_outputs_keep_their_mode_and_new_ones_get_the_umasks(tmp_path, graph):
    for name in ("out.g2o", "report.json"):
        (tmp_path / name).write_text("old")
        os.chmod(tmp_path / name, 0o600)
    run = run_cli("optimize", graph, "-o", tmp_path / "out.g2o", "--report", tmp_path / "report.json",
                  "--covariances", tmp_path / "new.npz", "-q")
    assert run.returncode == 0, run.stderr
    for name in ("out.g2o", "report.json"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o600
        assert (tmp_path / name).read_text() != "old"
    with open(tmp_path / "plain", "w"):
        pass
    assert stat.S_IMODE(os.stat(tmp_path / "new.npz").st_mode) == stat.S_IMODE(os.stat(tmp_path / "plain").st_mode)


# --------------------------------------------------------------------------------------------
# a full disk names the output asked for


def _enospc():
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_while_writing_the_result_names_it(tmp_path, graph, monkeypatch, capsys):
    import posegraph.io.g2o_write as g2o_write

    def no_space(fd):  # where a full disk shows on file systems that allocate late (ext4, NFS, XFS)
        raise _enospc()

    monkeypatch.setattr(g2o_write.os, "fsync", no_space)
    status = cli.main(["optimize", str(graph), "-o", str(tmp_path / "out.g2o"), "--report", str(tmp_path / "r.json"),
                       "-q"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert status == 2 and err == [f"posegraph: error: {tmp_path / 'out.g2o'}: cannot write the file: "
                                   f"{os.strerror(errno.ENOSPC)}"]
    assert os.listdir(tmp_path) == []


def test_a_full_disk_while_writing_the_report_names_it(tmp_path, graph, monkeypatch, capsys):
    import builtins

    import posegraph.io.atomic as atomic

    class Full:
        """A text file whose writes fail as on a full disk."""

        def __init__(self, f):
            self.f = f

        def write(self, text):
            raise _enospc()

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    def opened(path, mode="r", *args, **kwargs):
        f = builtins.open(path, mode, *args, **kwargs)
        return Full(f) if "w" in mode else f

    monkeypatch.setattr(atomic, "open", opened, raising=False)  # atomic's own writes only
    (tmp_path / "out.g2o").write_text("old")
    status = cli.main(["optimize", str(graph), "-o", str(tmp_path / "out.g2o"), "--report", str(tmp_path / "r.json"),
                       "-q"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert status == 2 and err == [f"posegraph: error: {tmp_path / 'r.json'}: cannot write the file: "
                                   f"{os.strerror(errno.ENOSPC)}"]
    assert os.listdir(tmp_path) == ["out.g2o"] and (tmp_path / "out.g2o").read_text() == "old"


# --------------------------------------------------------------------------------------------
# signals: handled as Ctrl-C is


CHILD = """
import os, sys, time
import posegraph.io.atomic as atomic

hook, argv = sys.argv[1], sys.argv[2:]
if hook == "mid-write":  # the result's temporary file is complete, the report is being made
    json_text = atomic.json_text

    def waiting(*args, **kwargs):
        open("writing", "w").close()
        while not os.path.exists("go"):
            time.sleep(0.01)
        return json_text(*args, **kwargs)

    atomic.json_text = waiting
else:  # "after-rename:N": signal N to itself right after the first rename onto a user's file
    number, replace = int(hook.split(":")[1]), os.replace

    def replace_then_signal(source, destination):
        replace(source, destination)
        if not os.path.basename(destination).startswith("."):  # not write_g2o's rename onto its staged file
            os.kill(os.getpid(), number)

    os.replace = replace_then_signal
from posegraph.cli import main
sys.exit(main(argv))
"""


def _child(tmp_path, hook: str, argv, ignore=()):
    """``posegraph ARGV`` in a child with ``hook`` (above), its signals at their defaults but ``ignore``."""
    (tmp_path / "child.py").write_text(textwrap.dedent(CHILD))

    def dispositions():
        for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(number, signal.SIG_IGN if number in ignore else signal.SIG_DFL)

    env = dict(os.environ, PYTHONPATH=str(PROJECT_ROOT))
    return subprocess.Popen([sys.executable, str(tmp_path / "child.py"), hook, *map(str, argv)], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=dispositions)


def _wait_for(proc, marker) -> None:
    """Until the child has made ``marker`` (it then waits for the test); fails if it ended first."""
    while not marker.exists():
        assert proc.poll() is None, proc.communicate()
        try:
            proc.wait(0.01)
        except subprocess.TimeoutExpired:
            pass


def _outputs(tmp_path, graph):
    """A folder with an old result and report, and the ``optimize`` command line that replaces them."""
    out = tmp_path / "out"
    out.mkdir()
    for name in ("out.g2o", "r.json"):
        (out / name).write_text("old")
    return out, ["optimize", graph, "-o", out / "out.g2o", "--report", out / "r.json"]


@pytest.mark.parametrize("number", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_while_writing_leaves_the_old_outputs_and_no_temporary_file(tmp_path, graph, number):
    out, argv = _outputs(tmp_path, graph)
    proc = _child(tmp_path, "mid-write", argv)
    try:
        _wait_for(proc, tmp_path / "writing")
        assert any(name.startswith(".out.g2o.") for name in os.listdir(out))  # the result's temporary file
        proc.send_signal(number)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + number, stderr
    name = signal.Signals(number).name
    assert stderr.strip().splitlines()[-1] == f"posegraph: interrupted by {name}; nothing written"
    assert "Traceback" not in stderr
    assert sorted(os.listdir(out)) == ["out.g2o", "r.json"]  # no temporary file survives
    assert (out / "out.g2o").read_text() == "old" and (out / "r.json").read_text() == "old"  # neither new


def test_an_ignored_sighup_stays_ignored(tmp_path, graph):
    """``nohup``: SIGHUP ignored before the run is still ignored, and the run completes."""
    out, argv = _outputs(tmp_path, graph)
    proc = _child(tmp_path, "mid-write", argv + ["-q"], ignore=(signal.SIGHUP,))
    try:
        _wait_for(proc, tmp_path / "writing")
        proc.send_signal(signal.SIGHUP)
        (tmp_path / "go").touch()
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert (out / "out.g2o").read_text().startswith("VERTEX_SE3:QUAT ")
    assert '"final_cost"' in (out / "r.json").read_text()


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_between_the_renames_comes_after_both_and_the_message_says_so(tmp_path, graph, number):
    out, argv = _outputs(tmp_path, graph)
    proc = _child(tmp_path, f"after-rename:{int(number)}", argv + ["-q"])
    try:
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + number, stderr
    said = "interrupted" if number == signal.SIGINT else f"interrupted by {signal.Signals(number).name}"
    assert stderr.strip().splitlines()[-1] == (f"posegraph: {said}; written, complete: {out / 'out.g2o'}, "
                                               f"{out / 'r.json'}; nothing else written")
    assert (out / "out.g2o").read_text().startswith("VERTEX_SE3:QUAT ")  # both new: the renames were not split
    assert '"final_cost"' in (out / "r.json").read_text()
    assert sorted(os.listdir(out)) == ["out.g2o", "r.json"]
