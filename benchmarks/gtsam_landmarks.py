"""gtsam's side of the landmark benchmark as one process: read with gtsam's own reader, LM, write.

    python -m benchmarks.gtsam_landmarks IN -o OUT.g2o --report REPORT.json

The reader is the one gtsam offers for the format: ``gtsam.readG2o(path, is3D)`` for a g2o file
(``VERTEX_*``/``EDGE_*`` tags; 3D when a tag says SE3/TRACKXYZ), ``gtsam.load2D`` for gtsam's and
iSAM's 2D text (``ODOMETRY``, ``LANDMARK``, ``BR``, ``EDGE2``; it takes the noise numbers as
information), ``readG2o(path, True)`` for iSAM's 3D text (``EDGE3``, ``POINT3``). A ``.gz`` file is
decompressed to a temporary file first (timed in ``read``). When the graph gtsam builds has fewer
factors than the file has measurement lines, gtsam did not read the file: the report says so in
``not_read`` and nothing is optimised. Otherwise a tight prior (σ 1e-6) holds the pose with the
smallest key at its start value, ``LevenbergMarquardtOptimizer`` with default parameters runs from the
values gtsam's reader gives (the file's vertices, or, for files without, the odometry composed), and
``writeG2o`` writes the result. Costs are ``graph.error`` of the graph as read, without the prior.
"""

import time

_t0 = time.perf_counter()

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402

from benchmarks.child_report import write_report  # noqa: E402
from benchmarks.g2opy_pipeline import measurement_lines, open_text, plain_copy  # noqa: E402

THREE_D_TAGS = ("VERTEX_SE3", "EDGE_SE3", "VERTEX_TRACKXYZ", "EDGE3", "VERTEX3", "POINT3")


def file_kind(path: str) -> tuple[str, bool]:
    """``(reader, is3D, tags)``: ``"readG2o"`` or ``"load2D"``, by the file's tags."""
    tags = set()
    with open_text(path) as stream:
        for line in stream:
            if line.strip():
                tags.add(line.split(maxsplit=1)[0])
    is3d = any(tag.startswith(THREE_D_TAGS) for tag in tags)
    g2o = any(tag.startswith(("VERTEX_", "EDGE_")) for tag in tags)
    return ("readG2o" if g2o or is3d else "load2D"), is3d, tags


def model_difference(reader: str, tags: set) -> str | None:
    """Why gtsam's graph is not the file's model as posegraph (and iSAM) read it, or None."""
    if reader == "load2D" and "LANDMARK" in tags:
        return ("gtsam.load2D makes each LANDMARK dx dy line a bearing-range factor (BearingRangeFactor2D, "
                "diagonal noise of its own), not iSAM's position measurement")
    return None


def read(gtsam, path: str, reader: str, is3d: bool):
    """``(graph, initial)`` by gtsam's reader for the format."""
    if reader == "load2D":
        return gtsam.load2D(path)
    return gtsam.readG2o(path, is3d)


def pose_keys(gtsam, values, is3d: bool) -> list:
    """The keys of the poses among ``values``."""
    poses = gtsam.utilities.allPose3s(values) if is3d else gtsam.utilities.allPose2s(values)
    return list(poses.keys())


def optimise(gtsam, graph, initial, is3d: bool):
    """``(result, iterations, anchor key)``: LM from ``initial`` with a tight prior on the first pose."""
    anchor = min(pose_keys(gtsam, initial, is3d))
    with_prior = gtsam.NonlinearFactorGraph(graph)
    if is3d:
        with_prior.add(gtsam.PriorFactorPose3(anchor, initial.atPose3(anchor), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    else:
        with_prior.add(gtsam.PriorFactorPose2(anchor, initial.atPose2(anchor), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    optimizer = gtsam.LevenbergMarquardtOptimizer(with_prior, initial, gtsam.LevenbergMarquardtParams())
    return optimizer.optimize(), int(optimizer.iterations()), int(anchor)


def run(args, seconds: dict) -> dict:
    """Read, (optimise, write), and the report's fields."""
    t = time.perf_counter()
    import gtsam

    seconds["import"] = time.perf_counter() - t
    t = time.perf_counter()
    reader, is3d, tags = file_kind(args.input)
    lines = measurement_lines(args.input)
    try:
        with tempfile.TemporaryDirectory(prefix="gtsam-") as tmp:
            graph, initial = read(gtsam, plain_copy(args.input, tmp), reader, is3d)
    except (RuntimeError, ValueError) as error:  # gtsam refuses the file
        reason = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
        return {"tool": "gtsam", "reader": reader, "measurement_lines": lines, "not_read": f"gtsam.{reader} raised: {reason}"}
    seconds["read"] = time.perf_counter() - t
    factors = int(graph.size())
    report = {"tool": "gtsam", "reader": f"{reader}({'3D' if is3d else '2D'})", "values": int(initial.size()),
              "factors": factors, "measurement_lines": lines, "initial_cost": None, "final_cost": None, "iterations": 0}
    report["model_differs"] = model_difference(reader, tags)
    report["not_read"] = None if factors == lines else f"gtsam.{reader} built {factors} factors of {lines} measurement lines"
    if report["not_read"] is None and not pose_keys(gtsam, initial, is3d):
        report["not_read"] = f"gtsam.{reader} gave no initial pose values"
    if report["not_read"]:
        return report
    report["initial_cost"] = graph.error(initial)
    t = time.perf_counter()
    result, report["iterations"], report["anchor"] = optimise(gtsam, graph, initial, is3d)
    seconds["optimize"] = time.perf_counter() - t
    report["final_cost"] = graph.error(result)
    t = time.perf_counter()
    gtsam.writeG2o(graph, result, args.output)
    seconds["write"] = time.perf_counter() - t
    return report


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gtsam_landmarks", description=__doc__.splitlines()[0])
    parser.add_argument("input")
    parser.add_argument("-o", "--output", required=True)
    parser.add_argument("--report", required=True)
    args = parser.parse_args(argv)
    seconds: dict = {}
    return write_report(args.report, run(args, seconds), seconds, _t0)


if __name__ == "__main__":
    sys.exit(main())
