"""Write an output file all at once or not at all.

Every output (reports, figures, exports) is first written to a temporary file in the destination's
folder and moved onto the destination with :func:`os.replace`, which is atomic on POSIX and
Windows when both paths are on one file system. An exception — ``KeyboardInterrupt`` included —
before the move deletes the temporary file, so the destination is either the old file or
the complete new one, never a truncated one.
"""

from __future__ import annotations

import contextlib
import os

__all__ = ["atomic_path", "write_text_atomic", "write_json_atomic", "json_text", "StagedOutputs", "create_new_file"]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Context manager yielding a temporary path to write; moved onto ``path`` on success.

    ``suffix`` (default: ``path``'s own suffix) is kept on the temporary name, for writers that
    pick their format from the file name (Open3D, matplotlib). The folder of ``path`` must exist.
    """
    path = os.fspath(path)
    tmp = _temporary_beside(path, suffix)
    try:
        yield tmp
        try:
            os.replace(tmp, path)
        except OSError as exc:
            raise _output_error(path, exc) from exc
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _temporary_beside(path: str, suffix: str | None) -> str:
    """Create an empty temporary file next to ``path`` and return its name."""
    folder, name = os.path.split(path)
    try:
        return create_new_file(folder or ".", f".{name}.", _suffix(name) if suffix is None else suffix)
    except OSError as exc:  # named by the user's path, not the temporary one
        raise _output_error(path, exc) from exc


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


class StagedOutputs:
    """Several output files that appear together, or not at all.

    ``stage(path)`` returns a temporary file name next to ``path`` for a writer to fill;
    ``commit()`` moves every staged file onto its destination, with Ctrl-C held back until the
    last move is done (a ``KeyboardInterrupt`` is raised after it); leaving the ``with`` block
    without committing — an error, Ctrl-C — deletes the temporary files and leaves the
    destinations untouched. A command that writes a result, a report and a figure thus never
    leaves one of them without the others.
    """

    def __init__(self) -> None:
        self._staged: list[tuple[str, str]] = []

    def __enter__(self) -> "StagedOutputs":
        return self

    def __exit__(self, *exc) -> None:
        self.discard()

    def stage(self, path, suffix: str | None = None) -> str:
        """A temporary path to write in place of ``path`` (whose folder must exist)."""
        path = os.fspath(path)
        tmp = _temporary_beside(path, suffix)
        self._staged.append((tmp, path))
        return tmp

    def commit(self) -> None:
        import signal

        interrupted = []
        try:
            previous = signal.signal(signal.SIGINT, lambda *_: interrupted.append(1))
        except ValueError:  # not the main thread: Ctrl-C does not reach this one anyway
            previous = None
        try:
            for tmp, path in self._staged:
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise _output_error(path, exc) from exc
            self._staged = []
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
        if interrupted:
            raise KeyboardInterrupt

    def discard(self) -> None:
        for tmp, _ in self._staged:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self._staged = []


def _suffix(name: str) -> str:
    """The suffix ``pathlib`` gives ``name``: from its last dot, unless that dot starts or ends the name."""
    dot = name.rfind(".")
    return name[dot:] if 0 < dot < len(name) - 1 else ""


def _output_error(path: str, exc: OSError):
    """An :class:`~posegraph.errors.OutputError` naming ``path`` (the destination) for ``exc``."""
    from posegraph.errors import OutputError

    return OutputError(f"cannot write the file: {exc.strerror or exc}", path=path)


def write_text_atomic(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)


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
