"""``--rerun OUT.rrd``, ``--rerun-spawn``, ``--rerun-connect ADDR`` of ``optimize`` and ``replay``: a Rerun
recording of the run (``docs/rerun.md``; ``pip install "posegraph[rerun]"``, imported only when asked).

The ``.rrd`` file is written as the run goes to a temporary file beside it, and renamed into place
with the command's other outputs (:class:`posegraph.io.atomic.StagedOutputs`); a failure or Ctrl-C
leaves no partial recording. Its path is checked, and Rerun found, before any solving.
"""

from __future__ import annotations

import contextlib
import os

from posegraph.cli.common import UsageError, check_output, warn

DEFAULT_VIEWER = "rerun+http://127.0.0.1:9876/proxy"
"""Where a Rerun viewer listens by default (``rerun`` started on its own, or ``--rerun-spawn``)."""


def rerun_options(p) -> None:
    g = p.add_argument_group("Rerun recording (pip install 'posegraph[rerun]'; docs/rerun.md)")
    g.add_argument("--rerun", metavar="OUT.rrd", help="record the run to a Rerun file (open it with `rerun OUT.rrd`)")
    g.add_argument("--rerun-spawn", action="store_true", help="start a Rerun viewer and stream the recording to it")
    g.add_argument("--rerun-connect", metavar="ADDR", help="stream the recording to a running Rerun viewer: "
                   f"HOST:PORT or a URL (default viewer: {DEFAULT_VIEWER})")


def wants_rerun(args) -> bool:
    return bool(getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False) or getattr(args, "rerun_connect", None))


def check_rerun_options(args) -> None:
    """The recording's path writable and not an input, and rerun-sdk installed: before any work."""
    if not wants_rerun(args):
        return
    if args.rerun:
        check_output(args.rerun, inputs=[args.input], what="recording")
    import importlib.util

    if importlib.util.find_spec("rerun") is None:
        raise UsageError("--rerun, --rerun-spawn and --rerun-connect need the rerun-sdk package: "
                         "pip install 'posegraph[rerun]'")
    if args.rerun_connect:
        check_viewer(viewer_url(args.rerun_connect))


def check_viewer(url: str, seconds: float = 3.0) -> None:
    """A usage error unless something listens at ``url``'s host and port (a TCP connection), so that a
    wrong address fails before the run rather than after it."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    try:
        port = parts.port or (443 if parts.scheme.endswith("https") else 80)
        with socket.create_connection((parts.hostname or "127.0.0.1", port), timeout=seconds):
            pass
    except (OSError, ValueError) as exc:
        raise UsageError(f"--rerun-connect: no Rerun viewer at {url} ({getattr(exc, 'strerror', None) or exc})") from None


def viewer_url(address: str) -> str:
    """A gRPC URL for ``address``: a ``rerun://``, ``rerun+http(s)://`` URL as given, ``HOST:PORT``
    as ``rerun+http://HOST:PORT/proxy``."""
    if "://" in address:
        return address
    return f"rerun+http://{address}/proxy"


class Recording:
    """The run's Rerun recording stream (``stream``) and where it goes: a staged ``.rrd`` file, a
    viewer. :meth:`stage_into` hands the finished file to the command's outputs."""

    def __init__(self, args, application: str) -> None:
        from posegraph.cli.startup import single_threaded_blas

        single_threaded_blas()  # before numpy loads, with Rerun, as the command's own imports would have it
        os.environ.setdefault("RUST_LOG", "off")  # the SDK's own log lines: posegraph warns in one line itself
        from posegraph.analysis.rerun_log import require_rerun
        from posegraph.io.atomic import StagedOutputs

        rr = require_rerun()
        self.path = args.rerun
        self.stream = rr.RecordingStream(application, recording_id=os.urandom(8).hex())
        self._staged = StagedOutputs()
        self.viewer = viewer_url(args.rerun_connect) if args.rerun_connect else DEFAULT_VIEWER
        sinks = []
        if self.path:
            self._tmp = self._staged.stage(self.path)
            sinks.append(rr.FileSink(self._tmp))
        self.live = bool(args.rerun_spawn or args.rerun_connect)
        if args.rerun_spawn:
            self.stream.spawn(connect=False)
        if self.live:
            sinks.append(rr.GrpcSink(self.viewer))
        self.stream.set_sinks(*sinks)

    def stage_into(self, outputs) -> None:
        """Flush the recording and stage its file among ``outputs`` (renamed with them on their commit).
        A viewer that cannot be reached is a warning: the run's outputs and the file are still written."""
        try:
            self.stream.flush()
        except RuntimeError as exc:  # the gRPC sink: the viewer went away, or never came (--rerun-spawn)
            warn(f"the recording did not reach the Rerun viewer at {self.viewer} ({' '.join(str(exc).split())})")
        self.stream.disconnect()
        if not self.path:
            return
        staged = outputs.stage(self.path)
        try:
            os.replace(self._tmp, staged)
        except OSError:  # another file system (a device's stage is in the system's temporary folder)
            import shutil

            shutil.copyfile(self._tmp, staged)
        self._staged.discard()

    def close(self) -> None:
        """Stop writing; the staged file, if still here, is deleted."""
        with contextlib.suppress(Exception):
            self.stream.disconnect()
        self._staged.discard()


@contextlib.contextmanager
def open_recording(args, application: str):
    """A :class:`Recording` for the run (None without a Rerun option), closed on leaving the block; the
    options checked first by :func:`check_rerun_options` (with the command's other outputs)."""
    if not wants_rerun(args):
        yield None
        return
    recording = Recording(args, application)
    try:
        yield recording
    finally:
        recording.close()


def optimize_recorder(recording, graph, start):
    """The :class:`~posegraph.analysis.rerun_log.IterationRecorder` of an ``optimize`` run (None
    without a recording), the graph's start logged: ``world/initial`` the file's poses, iteration 0 ``start``."""
    if recording is None:
        return None
    from posegraph.analysis.rerun_log import IterationRecorder, log_graph
    from posegraph.analysis.rerun_log import require_rerun

    rec = recording.stream
    rec.log("world", require_rerun().ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_graph(rec, graph)
    recorder = IterationRecorder(rec, graph)
    if start is not None:  # None: GNC's robust start, made inside the optimiser
        recorder.start(start, None if graph.landmarks is None else graph.landmarks.positions)
    return recorder


def with_recorder(params, recorder):
    """``params`` with ``recorder`` as its ``estimate_callback`` (unchanged when None)."""
    if recorder is None:
        return params
    from dataclasses import replace

    return replace(params, estimate_callback=recorder)


def record_optimize_result(recorder, graph, result, *, weights=None, covariances=None, chi2=None, robust=None,
                           title: str = "") -> None:
    """The result, per-edge values, summary and blueprint of an ``optimize`` run (nothing without a recorder)."""
    if recorder is None:
        return
    from posegraph.analysis.rerun_log import log_result, optimize_blueprint

    recorder.finish(result.poses, result.points)
    log_result(recorder.rec, graph, result, weights=weights, covariances=covariances, chi2=chi2,
               history=None if robust is None else robust.history, title=title)
    recorder.rec.send_blueprint(optimize_blueprint(graph, result.poses))


def replay_recorder(recording, graph, batch_size: int):
    """The :class:`~posegraph.incremental.rerun_replay.ReplayRecorder` of a ``replay`` run (None without a recording)."""
    if recording is None:
        return None
    from posegraph.analysis.rerun_log import require_rerun
    from posegraph.incremental.rerun_replay import ReplayRecorder

    rec = recording.stream
    rec.log("world", require_rerun().ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return ReplayRecorder(rec, graph, batch_size)
