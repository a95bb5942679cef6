"""The ``posegraph`` command: optimise, compare with gtsam, verify Jacobians, inspect, evaluate, plot, export.

The installed ``posegraph …`` (``posegraph = "posegraph.cli:main"``), ``python -m posegraph …`` and
``python cli.py …`` from a checkout are the same program. Only the standard library is imported at
start-up; numpy, scipy and the project's modules are imported by the subcommand that needs them,
and gtsam, Open3D and matplotlib only by the subcommands and options that use them, so
``posegraph --help`` answers at once.

Modules: :mod:`~posegraph.cli.program` (``main``: exit statuses and one-line errors),
:mod:`~posegraph.cli.parser` (the parser, built from the subcommand modules),
:mod:`~posegraph.cli.common` (messages, progress, output checks, reading, option types),
:mod:`~posegraph.cli.solving` (solver options shared by ``optimize`` and ``compare``),
:mod:`~posegraph.cli.startup` (process tuning for fast runs), and one module per subcommand:
``optimize``, ``batch`` (many files on Dask: :mod:`posegraph.batch`), ``compare``, ``verify_jacobians``,
``info``, ``eval``, ``plot``, ``export``.

Exit status: 0 success (optimiser converged; compare agreed; every Jacobian check within
tolerance); 1 the run finished but did not meet that bar (iteration cap hit or figure not drawn —
the result is still written, with a warning —, costs disagree, a check over tolerance); 2 bad
input or usage (one line ``posegraph: error: file:line: reason`` on stderr, nothing written); 3 an
internal error (one line; ``--debug`` shows the traceback); 130 interrupted by Ctrl-C (nothing
written). No exception reaches the user as a traceback without ``--debug``.
"""

from posegraph.cli.program import main

__all__ = ["main"]


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
