"""posegraph.io.atomic: new files beside the destination, and all-or-nothing writes."""

from __future__ import annotations

import os
import stat
import sys

import pytest

from posegraph.io import atomic


def test_a_new_file_gets_the_mode_open_gives_and_the_name_asked_for(tmp_path):
    created = atomic.create_new_file(str(tmp_path), ".out.g2o.", ".g2o")
    name = os.path.basename(created)
    assert os.path.dirname(created) == str(tmp_path)
    assert name.startswith(".out.g2o.") and name.endswith(".g2o") and len(name) == len(".out.g2o.") + 8 + 4
    assert os.path.getsize(created) == 0
    with open(tmp_path / "plain", "w"):
        pass
    assert stat.S_IMODE(os.stat(created).st_mode) == stat.S_IMODE(os.stat(tmp_path / "plain").st_mode)


def test_an_existing_name_or_link_is_never_used(tmp_path, monkeypatch):
    draws = iter([b"\x00" * 4, b"\x00" * 4, b"\x01" * 4])
    monkeypatch.setattr(atomic.os, "urandom", lambda n: next(draws))
    taken = tmp_path / "p00000000"
    taken.write_text("keep")
    created = atomic.create_new_file(str(tmp_path), "p")
    assert os.path.basename(created) == "p01010101"
    assert taken.read_text() == "keep"


@pytest.mark.skipif(sys.platform == "win32", reason="symbolic links need privileges on Windows")
def test_a_symbolic_link_at_the_name_is_not_followed(tmp_path, monkeypatch):
    draws = iter([b"\x00" * 4, b"\x02" * 4])
    monkeypatch.setattr(atomic.os, "urandom", lambda n: next(draws))
    target = tmp_path / "elsewhere"
    os.symlink(target, tmp_path / "p00000000")  # dangling: O_CREAT alone would create `elsewhere`
    created = atomic.create_new_file(str(tmp_path), "p")
    assert os.path.basename(created) == "p02020202"
    assert not target.exists()


def test_an_unwritable_folder_raises_os_error(tmp_path):
    with pytest.raises(OSError):
        atomic.create_new_file(str(tmp_path / "missing"), "p")


def test_atomic_path_leaves_the_destination_untouched_on_error_and_no_temporary(tmp_path):
    destination = tmp_path / "result.txt"
    destination.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(destination) as temporary:
            assert temporary.endswith(".txt") and os.path.dirname(temporary) == str(tmp_path)
            with open(temporary, "w") as f:
                f.write("partial")
            raise RuntimeError("interrupted")
    assert destination.read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["result.txt"]
    atomic.write_text_atomic(destination, "new")
    assert destination.read_text() == "new" and sorted(os.listdir(tmp_path)) == ["result.txt"]


@pytest.mark.parametrize("name, suffix", [("a.g2o", ".g2o"), ("a.tar.gz", ".gz"), (".bashrc", ""), ("a.", ""),
                                          ("a", ""), ("..x", ".x"), ("x.y.", "")])
def test_the_suffix_kept_is_pathlibs(name, suffix):
    from pathlib import PurePath

    assert atomic._suffix(name) == PurePath(name).suffix == suffix


# --------------------------------------------------------------------------------------------
# what the name is: devices, FIFOs, links, folders (issue 33)

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, device nodes and modes are POSIX")


def _device_twin(tmp_path, minor: int, name: str):
    """A character device made under ``tmp_path``: (1, 3) is /dev/null's twin, (1, 7) /dev/full's."""
    if os.geteuid() != 0:
        pytest.skip("making a device node (mknod) needs root")
    node = tmp_path / name
    os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    return node


def _read_fifo_in_thread(fifo):
    """Start a thread reading ``fifo`` to its end; returns the list its bytes land in, and the thread."""
    import threading

    received = []

    def read():
        with open(fifo, "rb") as f:
            received.append(f.read())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return received, reader


@posix_only
def test_a_fifo_is_written_into_and_stays_a_fifo(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    received, reader = _read_fifo_in_thread(fifo)
    atomic.write_text_atomic(fifo, "through the pipe\n")
    reader.join(60)
    assert received == [b"through the pipe\n"]
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["pipe"]


@posix_only
def test_a_character_device_is_written_into_and_stays_the_same_device(tmp_path):
    node = _device_twin(tmp_path, 3, "null")
    before = os.lstat(node)
    with atomic.StagedOutputs() as outputs:
        outputs.write_text(node, "discarded\n")
        outputs.write_text(tmp_path / "beside.txt", "kept\n")
        outputs.commit()
    after = os.lstat(node)
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev and after.st_ino == before.st_ino
    assert (tmp_path / "beside.txt").read_text() == "kept\n"
    assert sorted(os.listdir(tmp_path)) == ["beside.txt", "null"]


@posix_only
def test_a_full_device_names_the_output_and_no_file_is_renamed(tmp_path):
    """Devices are written before any rename: a full one (/dev/full's twin) leaves the files as they were."""
    from posegraph.errors import OutputError

    full = _device_twin(tmp_path, 7, "full")
    (tmp_path / "result.txt").write_text("old")
    with pytest.raises(OutputError) as caught:
        with atomic.StagedOutputs() as outputs:
            outputs.write_text(tmp_path / "result.txt", "new")
            outputs.write_text(full, "report")
            outputs.commit()
    assert str(caught.value) == f"{full}: cannot write the file: No space left on device"
    assert (tmp_path / "result.txt").read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["full", "result.txt"]


@posix_only
def test_a_link_stays_a_link_and_its_target_is_replaced_beside_itself(tmp_path, monkeypatch):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir(), there.mkdir()
    (there / "real.txt").write_text("old")
    os.symlink(there / "real.txt", here / "link.txt")
    folders = []
    create = atomic.create_new_file
    monkeypatch.setattr(atomic, "create_new_file", lambda folder, *a: folders.append(folder) or create(folder, *a))
    atomic.write_text_atomic(here / "link.txt", "new")
    assert folders == [str(there)]  # the temporary file beside the target, so the rename is within one folder
    assert os.readlink(here / "link.txt") == str(there / "real.txt")
    assert (there / "real.txt").read_text() == "new"
    assert os.listdir(here) == ["link.txt"] and os.listdir(there) == ["real.txt"]


@posix_only
def test_a_chain_of_links_is_followed_to_the_file(tmp_path):
    (tmp_path / "real.txt").write_text("old")
    os.symlink("real.txt", tmp_path / "one")
    os.symlink("one", tmp_path / "two")
    atomic.write_text_atomic(tmp_path / "two", "new")
    assert os.path.islink(tmp_path / "two") and os.path.islink(tmp_path / "one")
    assert (tmp_path / "real.txt").read_text() == "new"
    assert sorted(os.listdir(tmp_path)) == ["one", "real.txt", "two"]


@posix_only
@pytest.mark.parametrize("make, reason", [
    (lambda p: os.symlink(p.parent / "nowhere", p), "it is a symbolic link to {parent}/nowhere, which does not exist"),
    (lambda p: p.mkdir(), "it is a folder"),
    (lambda p: os.symlink(p.parent, p), "it is a folder"),
])
def test_a_dangling_link_or_a_folder_is_refused_and_nothing_is_made(tmp_path, make, reason):
    from posegraph.errors import OutputError

    name = tmp_path / "out"
    make(name)
    before = sorted(os.listdir(tmp_path))
    with pytest.raises(OutputError) as caught:
        atomic.write_text_atomic(name, "x")
    assert str(caught.value) == f"{name}: cannot write the file: " + reason.format(parent=tmp_path)
    assert sorted(os.listdir(tmp_path)) == before
    assert not (tmp_path / "nowhere").exists()


@posix_only
def test_an_overwritten_file_keeps_its_mode_and_a_new_one_gets_the_umasks(tmp_path):
    private = tmp_path / "private.txt"
    private.write_text("old")
    os.chmod(private, 0o600)
    atomic.write_text_atomic(private, "new")
    assert private.read_text() == "new" and stat.S_IMODE(os.stat(private).st_mode) == 0o600
    os.chmod(private, 0o640)
    atomic.write_text_atomic(private, "newer")
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o640
    atomic.write_text_atomic(tmp_path / "fresh.txt", "x")
    with open(tmp_path / "plain", "w"):
        pass
    assert stat.S_IMODE(os.stat(tmp_path / "fresh.txt").st_mode) == stat.S_IMODE(os.stat(tmp_path / "plain").st_mode)


@posix_only
def test_an_overwritten_file_keeps_its_owner_where_root_may_set_it(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("giving a file to another user needs root")
    owned = tmp_path / "owned.txt"
    owned.write_text("old")
    os.chown(owned, 4321, 4322)
    os.chmod(owned, 0o604)
    atomic.write_text_atomic(owned, "new")
    st = os.stat(owned)
    assert (st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)) == (4321, 4322, 0o604) and owned.read_text() == "new"


def test_a_full_disk_names_the_output_asked_for_and_leaves_nothing(tmp_path):
    import errno

    from posegraph.errors import OutputError

    destination = tmp_path / "result.txt"
    destination.write_text("old")
    with pytest.raises(OutputError) as caught:
        with atomic.StagedOutputs() as outputs:
            with outputs.writing(destination) as temporary:
                with open(temporary, "w") as f:
                    f.write("part")  # what a write does when the disk fills: the bytes so far, then ENOSPC
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            outputs.commit()
    assert str(caught.value) == f"{destination}: cannot write the file: {os.strerror(errno.ENOSPC)}"
    assert destination.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["result.txt"]


def test_a_writers_error_naming_the_temporary_file_names_the_output(tmp_path):
    """write_g2o names the path it is given (the staged temporary file): the message must not."""
    from posegraph.errors import OutputError

    with pytest.raises(OutputError) as caught:
        with atomic.StagedOutputs() as outputs:
            with outputs.writing(tmp_path / "out.g2o") as temporary:
                raise OutputError("cannot write the file: Disk quota exceeded", temporary)
    assert str(caught.value) == f"{tmp_path / 'out.g2o'}: cannot write the file: Disk quota exceeded"
    assert os.listdir(tmp_path) == []


@posix_only
def test_signals_during_the_renames_are_delivered_after_the_last(tmp_path, monkeypatch):
    """Ctrl-C between two renames: both files are delivered, then KeyboardInterrupt; the record says so."""
    import signal

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT is not Python's default handler in this process")
    replace = os.replace

    def replace_then_interrupt(source, destination):
        replace(source, destination)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(atomic.os, "replace", replace_then_interrupt)
    atomic.forget_committed_outputs()
    with pytest.raises(KeyboardInterrupt):
        with atomic.StagedOutputs() as outputs:
            outputs.write_text(tmp_path / "a.txt", "a")
            outputs.write_text(tmp_path / "b.txt", "b")
            outputs.commit()
    assert (tmp_path / "a.txt").read_text() == "a" and (tmp_path / "b.txt").read_text() == "b"
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "b.txt"]
    assert atomic.committed_outputs() == [str(tmp_path / "a.txt"), str(tmp_path / "b.txt")]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
