"""Errors and warnings raised on a user's input.

Every error caused by a user's file derives from :class:`InputError` (a
``ValueError``), carries the file, the 1-based line number (``None`` when the
problem is not tied to one line) and the reason, and prints as
``file:line: reason`` so the command line can show it as one line.
"""

from __future__ import annotations

__all__ = ["excerpt", "QUOTED_CHARS", "InputError", "G2oFormatError", "GraphError", "OutputError", "PosegraphWarning", "InputWarning",
           "Interrupted"]


QUOTED_CHARS = 60
"""The most characters a message quotes from a user's file: a line or a field of any length gives a
message one can read (a 100 MB field once gave a 105 MB error line)."""


def excerpt(text: str, *, quoted: bool = True) -> str:
    """``text`` as a message shows it: cut to :data:`QUOTED_CHARS` characters with an ellipsis when
    longer, and ``repr``'d when ``quoted`` (so that blanks and control characters show)."""
    if len(text) > QUOTED_CHARS:
        text = text[: QUOTED_CHARS - 1] + "…"
    return repr(text) if quoted else text


class InputError(ValueError):
    """A user's input cannot be used. ``str(err)`` is ``"path:line: reason"``."""

    def __init__(self, reason: str, path: str | None = None, line: int | None = None):
        self.reason = reason
        self.path = path
        self.line = line
        super().__init__(self._format())

    def _format(self) -> str:
        where = self.path if self.path is not None else "<input>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {self.reason}"


class G2oFormatError(InputError):
    """A line of a g2o file is malformed (field count, number syntax, NaN, bad quaternion or information)."""


class GraphError(InputError):
    """The file parses but does not describe a usable pose graph (duplicate id, missing vertex, self-loop, empty)."""


class OutputError(InputError):
    """An output cannot be written as asked (it would overwrite the input, or its folder does not exist)."""


class Interrupted(KeyboardInterrupt):
    """A signal that asks the process to stop (SIGTERM, SIGHUP), raised as Ctrl-C raises
    ``KeyboardInterrupt`` — by the command line's handlers — so that every ``except
    KeyboardInterrupt`` and ``finally`` cleans up after it the same way. ``signum``: the signal."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signum)


class PosegraphWarning(UserWarning):
    """posegraph's own warnings: the command line shows every one of these, and leaves other
    packages' warnings (numpy's, scipy's, Python's deprecations) to Python's filters."""


class InputWarning(PosegraphWarning):
    """Something in the input was repaired or skipped (normalised quaternion, unknown tags, several components)."""


class MissingPosesWarning(InputWarning):
    """The file has edges but no vertex lines: its vertices were created at the identity pose, which
    matters only to what starts from the file's poses (the command line says it for ``--init file`` only)."""
