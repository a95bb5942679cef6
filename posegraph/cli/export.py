"""``posegraph export``: an Open3D pose-graph JSON and/or a PLY line set of the trajectory."""

from __future__ import annotations

from posegraph.cli.common import EXIT_OK, Status, UsageError, check_distinct, check_output, read_graph, repair_option

NAME = "export"
HELP = "write an Open3D PoseGraph JSON and/or a PLY line set"
DESCRIPTION = (
    "Export through Open3D: --open3d writes an open3d.pipelines.registration.PoseGraph "
    "(read it with open3d.io.read_pose_graph; node k is the k-th vertex of the file, an edge i->j "
    "becomes source j, target i, transformation Z_ij), --ply the trajectory as a line set. Needs "
    "Open3D (pip install open3d; on Debian also apt install libusb-1.0-0)."
)
EXAMPLES = """
  posegraph export optimised.g2o --open3d graph.json
  posegraph export optimised.g2o --ply trajectory.ply --loop-closures"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="pose graph to export")
    repair_option(p)
    p.add_argument("--open3d", metavar="GRAPH.json", help="Open3D pose-graph JSON to write")
    p.add_argument("--ply", metavar="LINES.ply", help="PLY line set of the trajectory to write")
    p.add_argument("--loop-closures", action="store_true", help="also put loop-closure edges in the PLY")


def run(args) -> int:
    if not args.open3d and not args.ply:
        raise UsageError("nothing to export: give --open3d GRAPH.json and/or --ply LINES.ply")
    for path, what in ((args.open3d, "Open3D pose graph"), (args.ply, "line set")):
        if path:
            check_output(path, inputs=[args.input], what=what)
    check_distinct([args.open3d, args.ply])
    from posegraph.export_open3d import require_open3d, write_open3d_pose_graph, write_trajectory_ply

    require_open3d()
    from posegraph.atomic import StagedOutputs

    graph, _ = read_graph(args.input, Status(True), require_edges=False, repair_information=args.repair_information)
    with StagedOutputs() as outputs:
        if args.open3d:
            write_open3d_pose_graph(outputs.stage(args.open3d, suffix=".json"), graph)
        if args.ply:
            write_trajectory_ply(outputs.stage(args.ply, suffix=".ply"), graph, loop_closures=args.loop_closures)
        outputs.commit()
    return EXIT_OK
