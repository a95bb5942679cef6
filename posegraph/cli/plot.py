"""``posegraph plot``: trajectories of one or more graphs drawn in 3D (2D graphs: a top view)."""

from __future__ import annotations

import os

from posegraph.cli.common import (
    EXIT_OK, Status, UsageError, check_figure, check_inputs, display_name, read_graph, repair_option,
)

NAME = "plot"
HELP = "draw trajectories in 3D or, for 2D graphs, from the top (PNG, PDF, SVG)"
DESCRIPTION = (
    "Draw each graph's vertex positions joined in id order, its loop-closure edges faintly, "
    "several files overlaid with a legend; 2D graphs as a top view of the x-y plane. Needs matplotlib (pip install \"posegraph[plot]\")."
)
EXAMPLES = """
  posegraph plot sphere2500.g2o -o sphere.png
  posegraph plot before.g2o after.g2o -o before-after.png --labels before after"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="pose graph to draw (- for standard input)")
    p.add_argument("more", metavar="MORE.g2o", nargs="*", help="more graphs overlaid")
    repair_option(p)
    p.add_argument("-o", "--output", metavar="FIG.png", required=True,
                   help="figure file; its extension picks the format")
    p.add_argument("--labels", nargs="+", metavar="NAME", help="legend names, one per input (default file names)")
    p.add_argument("--title", help="figure title")
    p.add_argument("--no-loop-closures", action="store_true", help="draw the trajectories only")


def run(args) -> int:
    inputs = [args.input, *args.more]
    if args.labels is not None and len(args.labels) != len(inputs):
        raise UsageError(f"--labels needs {len(inputs)} names (one per input), got {len(args.labels)}")
    check_inputs(inputs)
    check_figure(args.output, inputs=inputs)
    from posegraph.plot import plot_trajectories

    status = Status(True)
    graphs = [read_graph(path, status, require_edges=False, repair_information=args.repair_information)[0]
              for path in inputs]
    labels = args.labels or [os.path.basename(display_name(p)) for p in inputs]
    plot_trajectories(args.output, graphs, labels, loop_closures=not args.no_loop_closures, title=args.title)
    return EXIT_OK
