"""Write output files all at once or not at all, whatever the name given for them is.

An output is first written whole to a temporary file, then delivered (:class:`StagedOutputs`),
according to what its name is when it is staged (:func:`output_target`):

* a regular file, or no file yet: the temporary file is made in the destination's folder and
  renamed onto it with :func:`os.replace` (atomic on POSIX and Windows within one file system);
  an existing file keeps its permission bits, and its owner and group where the process may set
  them, a new file gets the mode a plain ``open()`` gives (0o666 less the umask);
* a symbolic link to a regular file: the same at the link's final target, so the link stays a
  link and points at the new content;
* a character device or a FIFO (``/dev/null``, ``/dev/stdout``, a named pipe): the temporary
  file is made in the system's temporary folder and its bytes are written into the node, which is
  opened, never replaced;
* a folder, a dangling link, a block device or a socket: refused with
  :class:`~posegraph.errors.OutputError` before anything is written.

An exception — ``KeyboardInterrupt`` and a signal raised as one included — before the delivery
deletes the temporary files, so a destination is either the old file or the complete new one,
never a truncated one; every error names the destination the caller gave, never a temporary file.
"""

from __future__ import annotations

import collections
import contextlib
import os
import stat

__all__ = ["atomic_path", "write_text_atomic", "write_json_atomic", "json_text", "StagedOutputs", "create_new_file",
           "OutputTarget", "output_target", "committed_outputs", "forget_committed_outputs"]


class OutputTarget(collections.namedtuple("OutputTarget", "kind path")):  # not typing's NamedTuple: ~2 ms to import
    """Where an output goes: ``kind`` ``"file"`` (replaced by a rename at ``path``, which is the
    real file a link leads to; it may not exist yet) or ``"node"`` (a character device or FIFO,
    written into through ``path`` as given)."""

    __slots__ = ()


def output_target(path) -> OutputTarget:
    """How an output named ``path`` is delivered (see the module's docstring).

    Raises :class:`~posegraph.errors.OutputError` naming ``path`` (``reason``: why) for a folder,
    a dangling symbolic link (or a loop of links), a block device or a socket.
    """
    path = os.fspath(path)
    try:
        st = os.stat(path)  # follows links: what a write through the name would reach
    except FileNotFoundError:
        if os.path.lexists(path):
            raise _refused(path, f"it is a symbolic link to {os.path.realpath(path)}, which does not exist") from None
        return OutputTarget("file", path)
    except OSError as exc:  # ELOOP, ENOTDIR, EACCES…
        raise _output_error(path, exc) from exc
    if stat.S_ISDIR(st.st_mode):
        raise _refused(path, "it is a folder")
    if stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode):
        return OutputTarget("node", path)
    if not stat.S_ISREG(st.st_mode):
        kind = "block device" if stat.S_ISBLK(st.st_mode) else "socket" if stat.S_ISSOCK(st.st_mode) else "special file"
        raise _refused(path, f"it is a {kind}: outputs go to regular files, character devices (/dev/null) and FIFOs")
    if not os.path.islink(path):
        return OutputTarget("file", path)
    real = os.path.realpath(path)
    with contextlib.suppress(OSError):
        if os.path.samestat(os.stat(real), st):
            return OutputTarget("file", real)
    # A link whose text does not name the file (/proc/self/fd/N of a deleted file): written
    # into through the name, as a device is, since no rename can reach that file.
    return OutputTarget("node", path)


def _refused(path: str, reason: str):
    from posegraph.errors import OutputError

    return OutputError(f"cannot write the file: {reason}", path=path)


_STAGED_NOW: set = set()
"""The temporary files staged and not yet delivered or discarded, as absolute paths (:func:`atomic_path`)."""

_COMMITTED: list = []
"""The destinations delivered in this process since :func:`forget_committed_outputs`, in order."""


def committed_outputs() -> list:
    """The destinations (as the callers named them) that :class:`StagedOutputs` delivered in this
    process since :func:`forget_committed_outputs`: what a program interrupted after its renames
    has put on disk (its message must say so, not "nothing written")."""
    return list(_COMMITTED)


def forget_committed_outputs() -> None:
    """Start a new record for :func:`committed_outputs` (a command line run starts with one)."""
    _COMMITTED.clear()


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Context manager yielding a temporary path to write; delivered to ``path`` on success.

    ``suffix`` (default: ``path``'s own suffix) is kept on the temporary name, for writers that
    pick their format from the file name (Open3D, matplotlib). The folder of ``path`` must exist.
    One :class:`StagedOutputs` of one file: the same rules for links, devices, modes and errors.
    A ``path`` that is itself a staged temporary file (a library writer such as ``write_g2o``
    called on the name :meth:`StagedOutputs.writing` gave) is yielded as it is: nobody sees it
    before its own commit, which is the one that delivers it.
    """
    if os.path.abspath(path) in _STAGED_NOW:
        yield os.fspath(path)
        return
    with StagedOutputs() as outputs:
        with outputs.writing(path, suffix) as tmp:
            yield tmp
        outputs.commit()


_NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def create_new_file(folder: str, prefix: str, suffix: str = "") -> str:
    """Create an empty file ``folder/prefix<8 random hex digits>suffix`` that did not exist; its path.

    ``O_CREAT | O_EXCL`` (and ``O_NOFOLLOW``) as :func:`tempfile.mkstemp` does — never an existing
    file, never through a symbolic link — but with the mode a plain ``open()`` gives (0o666 less
    the umask), which the renamed result must have, instead of mkstemp's private 0o600 (no umask
    to read and restore, which is not thread-safe); and without importing :mod:`tempfile`, which
    with :mod:`shutil` and :mod:`random` costs ~1 ms of every command. Raises :class:`OSError`.
    """
    for _ in range(100):
        path = os.path.join(folder, f"{prefix}{os.urandom(4).hex()}{suffix}")
        try:
            os.close(os.open(path, _NEW_FILE_FLAGS, 0o666))
        except FileExistsError:  # 1 in 4e9 per try: another name
            continue
        return path
    raise FileExistsError(f"no unused file name {prefix}…{suffix} in {folder}")


_Staged = collections.namedtuple("_Staged", "tmp given target new_mode")
"""A staged output: the temporary file the writer fills; the destination as the caller named it
(messages, :func:`committed_outputs`); its :class:`OutputTarget`; the mode a new file gets (the
temporary file's at creation, from the umask)."""


class StagedOutputs:
    """Several output files that appear together, or not at all.

    ``writing(path)`` (or ``stage(path)``) gives a temporary file name for a writer to fill;
    ``commit()`` delivers every staged file to its destination (:func:`output_target`): first the
    devices and FIFOs are written into (a stream cannot be taken back, and a FIFO nobody reads
    blocks, so this part stays interruptible), then the files are renamed into place with SIGINT,
    SIGTERM and SIGHUP held back until the last rename is done and delivered after it. Leaving the
    ``with`` block without committing — an error, Ctrl-C, a signal raised as an exception —
    deletes the temporary files and leaves the destinations untouched. A command that writes a
    result, a report and a figure thus never leaves one of them without the others.
    """

    def __init__(self) -> None:
        self._staged: list[_Staged] = []

    def __enter__(self) -> "StagedOutputs":
        return self

    def __exit__(self, *exc) -> None:
        if self._staged:  # a second signal must not stop the clean-up of the first halfway
            with _signals_held():
                self.discard()

    def stage(self, path, suffix: str | None = None) -> str:
        """A temporary path to write in place of ``path``; an :class:`~posegraph.errors.OutputError`
        naming ``path`` if it cannot be an output (:func:`output_target`) or its folder is missing."""
        given = os.fspath(path)
        target = output_target(given)
        name = os.path.basename(target.path)
        suffix = _suffix(name) if suffix is None else suffix
        if target.kind == "node":  # no file may be made beside a device (/dev): the system's temporary folder
            import tempfile

            folder = tempfile.gettempdir()
        else:
            folder = os.path.dirname(target.path) or "."
        try:
            tmp = create_new_file(folder, f".{name}.", suffix)
            new_mode = stat.S_IMODE(os.stat(tmp).st_mode)
            if target.kind == "node" or os.path.exists(target.path):
                os.chmod(tmp, 0o600)  # private while written: the old file may be, and a stream's copy is
        except OSError as exc:  # named by the user's path, not the temporary one
            raise _output_error(given, exc) from exc
        self._staged.append(_Staged(tmp, given, target, new_mode))
        _STAGED_NOW.add(os.path.abspath(tmp))
        return tmp

    @contextlib.contextmanager
    def writing(self, path, suffix: str | None = None):
        """Stage ``path`` and yield its temporary name; an :class:`OSError` raised while it is
        written (a full disk, a quota) becomes an :class:`~posegraph.errors.OutputError` naming
        ``path``, as does an ``OutputError`` a writer raised naming the temporary file."""
        from posegraph.errors import OutputError

        given = os.fspath(path)
        tmp = self.stage(given, suffix)
        try:
            yield tmp
        except OutputError as exc:
            if exc.path != tmp:
                raise
            raise OutputError(exc.reason, path=given) from exc
        except OSError as exc:
            raise _output_error(given, exc) from exc

    def write_text(self, path, text: str) -> None:
        """Stage ``path`` with ``text`` (UTF-8, newlines as given)."""
        with self.writing(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
            f.write(text)

    def commit(self) -> None:
        """Deliver every staged file (see the class's docstring); :class:`~posegraph.errors.OutputError`
        naming the destination if one cannot be."""
        nodes = [s for s in self._staged if s.target.kind == "node"]
        files = [s for s in self._staged if s.target.kind != "node"]
        for staged in nodes:
            _write_into(staged)
            _COMMITTED.append(staged.given)
        with _signals_held():
            for staged in files:
                _rename_onto(staged)
                _COMMITTED.append(staged.given)
            self._forget()

    def discard(self) -> None:
        """Delete the temporary files not yet delivered."""
        for staged in self._staged:
            with contextlib.suppress(OSError):
                os.unlink(staged.tmp)
        self._forget()

    def _forget(self) -> None:
        for staged in self._staged:
            _STAGED_NOW.discard(os.path.abspath(staged.tmp))
        self._staged = []


def _write_into(staged: _Staged) -> None:
    """Copy the temporary file's bytes into the device or FIFO (opened, not created nor truncated:
    O_APPEND for a regular file reached through /proc/self/fd, as a shell's ``>>`` would), then
    delete the temporary file."""
    flags = os.O_WRONLY | os.O_APPEND | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        with open(staged.tmp, "rb") as source:
            node = os.open(staged.target.path, flags)
            try:
                while chunk := source.read(1 << 20):
                    view = memoryview(chunk)
                    while view:  # a pipe may take less than all of it
                        view = view[os.write(node, view):]
            finally:
                os.close(node)
    except OSError as exc:
        raise _output_error(staged.given, exc) from exc
    with contextlib.suppress(OSError):
        os.unlink(staged.tmp)


def _rename_onto(staged: _Staged) -> None:
    """Give the temporary file the mode (and owner and group, where allowed) of the file it
    replaces, or a new file's mode, and rename it onto the target."""
    target = staged.target.path
    try:
        try:
            old = os.stat(target)
        except FileNotFoundError:
            os.chmod(staged.tmp, staged.new_mode)
        else:
            if stat.S_ISREG(old.st_mode):
                with contextlib.suppress(OSError):  # only root may give a file away; a group needs membership
                    os.chown(staged.tmp, old.st_uid, old.st_gid)
                os.chmod(staged.tmp, stat.S_IMODE(old.st_mode))  # after chown, which may clear set-id bits
        os.replace(staged.tmp, target)
    except OSError as exc:
        raise _output_error(staged.given, exc) from exc


_HELD_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


@contextlib.contextmanager
def _signals_held():
    """Run the block with SIGINT, SIGTERM and SIGHUP held back, then deliver (:func:`signal.raise_signal`)
    each that came, to the handler that was in place: a Python handler raises its exception after
    the block, a default action (the process ends) happens after it. Signals ignored stay ignored.
    Outside the main thread, where no handler can be set, nothing is held."""
    import signal
    import threading

    received: list = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for name in _HELD_SIGNALS:
            number = getattr(signal, name, None)
            handler = signal.getsignal(number) if number is not None else None
            if handler is not None and handler != signal.SIG_IGN:  # None: set outside Python, left alone
                previous[number] = signal.signal(number, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    for number in dict.fromkeys(received):
        signal.raise_signal(number)


def _suffix(name: str) -> str:
    """The suffix ``pathlib`` gives ``name``: from its last dot, unless that dot starts or ends the name."""
    dot = name.rfind(".")
    return name[dot:] if 0 < dot < len(name) - 1 else ""


def _output_error(path: str, exc: OSError):
    """An :class:`~posegraph.errors.OutputError` naming ``path`` (the destination) for ``exc``."""
    from posegraph.errors import OutputError

    return OutputError(f"cannot write the file: {exc.strerror or exc}", path=path)


def write_text_atomic(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:class:`StagedOutputs`' rules)."""
    with StagedOutputs() as outputs:
        outputs.write_text(path, text)
        outputs.commit()


def write_json_atomic(path, data, indent: int = 2) -> None:
    """Write ``data`` as JSON to ``path`` atomically (NaN and infinities written as ``null``)."""
    write_text_atomic(path, json_text(data, indent))


def json_text(data, indent: int = 2) -> str:
    """``data`` as strict JSON text with a final newline (NaN and infinities as ``null``)."""
    import json

    return json.dumps(_finite(data), indent=indent) + "\n"


def _finite(value):
    """Replace non-finite floats by None: strict JSON has no NaN or Infinity."""
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value
