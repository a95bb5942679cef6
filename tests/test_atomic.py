"""posegraph.atomic: new files beside the destination, and all-or-nothing writes."""

from __future__ import annotations

import os
import stat
import sys

import pytest

from posegraph import atomic


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
