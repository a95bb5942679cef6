"""``posegraph export``: trajectory files (TUM, KITTI), an Open3D pose-graph JSON, a PLY line set."""

from __future__ import annotations

from posegraph.cli.common import (
    reader_options,
    EXIT_OK, Status, UsageError, check_distinct, check_output, read_graph, repair_option, warn,
)

NAME = "export"
HELP = "write the poses as TUM/KITTI trajectories, an Open3D PoseGraph JSON and/or a PLY line set"
DESCRIPTION = (
    "Export the file's poses. --tum writes 'timestamp tx ty tz qx qy qz qw' per vertex in id order "
    "(timestamp = vertex id, or from --timestamps), --kitti the 12 entries of each 3x4 pose matrix "
    "per line in id order (KITTI has no ids: line k is the k-th vertex), both readable by evo; 2D "
    "graphs are written at z = 0. --open3d writes an open3d.pipelines.registration.PoseGraph (read "
    "it with open3d.io.read_pose_graph; node k is the k-th vertex of the file, an edge i->j becomes "
    "source j, target i, transformation Z_ij; every edge certain unless --uncertain-loop-closures), "
    "--ply the trajectory as a line set, --landmarks the points of a landmark graph ('id x y [z]' per line). --open3d and --ply need Open3D (pip install open3d; on "
    "Debian also apt install libusb-1.0-0)."
)
EXAMPLES = """
  posegraph export optimised.g2o --tum estimate.txt
  evo_ape tum groundtruth.txt estimate.txt -a
  posegraph export optimised.g2o --kitti poses.txt
  posegraph export optimised.g2o --tum estimate.txt --timestamps times.txt
  posegraph export optimised.g2o --open3d graph.json
  posegraph export optimised.g2o --ply trajectory.ply --loop-closures"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="pose graph to export (may be .gz, .bz2, .xz)")
    repair_option(p)
    p.add_argument("--tum", metavar="OUT.txt", help="TUM trajectory to write (timestamp tx ty tz qx qy qz qw)")
    p.add_argument("--timestamps", metavar="TABLE.txt",
                   help="timestamps for --tum: one per line in id order (as KITTI's times.txt), or "
                        "'id timestamp' lines; default: the vertex id")
    p.add_argument("--kitti", metavar="OUT.txt", help="KITTI trajectory to write (3x4 matrix per line, id order)")
    p.add_argument("--open3d", metavar="GRAPH.json", help="Open3D pose-graph JSON to write")
    p.add_argument("--uncertain-loop-closures", action="store_true",
                   help="mark loop closures uncertain in the Open3D graph (its line process may then prune "
                        "them, as in Open3D's multiway registration); default: every edge certain")
    p.add_argument("--ply", metavar="LINES.ply", help="PLY line set of the trajectory to write")
    p.add_argument("--loop-closures", action="store_true", help="also put loop-closure edges in the PLY")
    p.add_argument("--landmarks", metavar="POINTS.txt",
                   help="the landmarks of a landmark graph, one 'id x y' (2D) or 'id x y z' (3D) line each, in id order")


def _check_options(args) -> None:
    outputs = ((args.tum, "TUM trajectory"), (args.kitti, "KITTI trajectory"),
               (args.open3d, "Open3D pose graph"), (args.ply, "line set"), (args.landmarks, "landmarks"))
    if not any(path for path, _ in outputs):
        raise UsageError("nothing to export: give --tum, --kitti, --open3d, --ply and/or --landmarks with an output file")
    if args.timestamps and not args.tum:
        raise UsageError("--timestamps applies to --tum only")
    if args.uncertain_loop_closures and not args.open3d:
        raise UsageError("--uncertain-loop-closures applies to --open3d only")
    if args.loop_closures and not args.ply:
        raise UsageError("--loop-closures applies to --ply only")
    for path, what in outputs:
        if path:
            check_output(path, inputs=[args.input] + ([args.timestamps] if args.timestamps else []), what=what)
    check_distinct([path for path, _ in outputs])


def run(args) -> int:
    _check_options(args)
    if args.open3d or args.ply:
        from posegraph.io.export_open3d import require_open3d

        require_open3d()
    import numpy as np

    from posegraph.io.atomic import StagedOutputs
    from posegraph.io import trajectory

    graph, _ = read_graph(args.input, Status(True), require_edges=False, repair_information=args.repair_information,
                          **reader_options(args))
    landmarks = graph.landmarks
    if args.landmarks and (landmarks is None or not landmarks.count):
        raise UsageError(f"--landmarks: {args.input} has no landmarks")
    if (args.open3d or args.ply) and landmarks is not None and landmarks.count:
        warn(f"Open3D's PoseGraph and the line set hold poses only: the file's {landmarks.count} landmarks are left out "
             "(--landmarks writes them)")
    if args.open3d and graph.priors is not None and len(graph.priors):
        warn(f"{args.open3d}: Open3D's PoseGraph has no unary edges: the file's {len(graph.priors)} priors are left out")
    order = np.argsort(graph.ids, kind="stable")
    stamps = trajectory.read_timestamp_table(args.timestamps, graph.ids)[order] if args.timestamps else None
    if args.kitti and not np.array_equal(graph.ids[order], np.arange(graph.num_vertices)):
        warn(f"the vertex ids are not 0..{graph.num_vertices - 1}: KITTI has no ids, line k of {args.kitti} "
             "is the k-th vertex in id order")
    with StagedOutputs() as outputs:
        if args.tum:
            with outputs.writing(args.tum) as tmp:
                trajectory.write_tum(tmp, graph.ids[order] if stamps is None else stamps, graph.poses[order])
        if args.kitti:
            with outputs.writing(args.kitti) as tmp:
                trajectory.write_kitti(tmp, graph.poses[order])
        _write_open3d(args, graph, outputs)
        if args.landmarks:
            with outputs.writing(args.landmarks) as tmp, open(tmp, "w") as f:
                f.write(_landmark_lines(landmarks))
        outputs.commit()
    return EXIT_OK


def _landmark_lines(landmarks) -> str:
    """``"id x y[ z]"`` per landmark in id order, numbers as ``repr`` writes them (exact round trip)."""
    import numpy as np

    order = np.argsort(landmarks.ids, kind="stable")
    rows = zip(landmarks.ids[order].tolist(), landmarks.positions[order].tolist())
    return "".join(f"{i} " + " ".join(repr(v) for v in point) + "\n" for i, point in rows)


def _write_open3d(args, graph, outputs) -> None:
    if not (args.open3d or args.ply):
        return
    from posegraph.io.export_open3d import write_open3d_pose_graph, write_trajectory_ply

    if args.open3d:
        with outputs.writing(args.open3d, suffix=".json") as tmp:
            write_open3d_pose_graph(tmp, graph, uncertain_loop_closures=args.uncertain_loop_closures)
    if args.ply:
        with outputs.writing(args.ply, suffix=".ply") as tmp:
            write_trajectory_ply(tmp, graph, loop_closures=args.loop_closures)
