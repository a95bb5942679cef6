"""``posegraph plot``: trajectories of one or more graphs drawn in 3D (2D graphs: a top view)."""

from __future__ import annotations

import os

from posegraph.cli.common import (
    reader_options,
    EXIT_OK, Status, UsageError, check_figure, check_inputs, display_name, non_negative_float, positive_int,
    read_graph, repair_option,
)

NAME = "plot"
HELP = "draw trajectories in 3D or, for 2D graphs, from the top (PNG, PDF, SVG), with uncertainty ellipses"
DESCRIPTION = (
    "Draw each graph's vertex positions joined in id order, its loop-closure edges faintly, "
    "several files overlaid with a legend; 2D graphs as a top view of the x-y plane. With "
    "--covariances (from 'posegraph optimize --covariances'), a top view (x-y) with the 1-sigma "
    "ellipse of IN's poses' x-y position. Needs matplotlib (pip install \"posegraph[plot]\")."
)
EXAMPLES = """
  posegraph plot sphere2500.g2o -o sphere.png
  posegraph plot before.g2o after.g2o -o before-after.png --labels before after
  posegraph plot out.g2o -o uncertainty.png --covariances cov.npz --every 10"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="pose graph to draw (- for standard input)")
    p.add_argument("more", metavar="MORE.g2o", nargs="*", help="more graphs overlaid")
    repair_option(p)
    p.add_argument("-o", "--output", metavar="FIG.png", required=True,
                   help="figure file; its extension picks the format")
    p.add_argument("--labels", nargs="+", metavar="NAME", help="legend names, one per input (default file names)")
    p.add_argument("--title", help="figure title")
    p.add_argument("--no-loop-closures", action="store_true", help="draw the trajectories only")
    p.add_argument("--top-view", action="store_true", help="draw the x-y plane (3D graphs seen from above)")
    p.add_argument("--covariances", metavar="COV.npz",
                   help="draw IN's uncertainty ellipses on a top view: the marginal covariance of each pose's "
                        "x-y position in the world frame, from the translation block of COV.npz's tangent "
                        "covariance (SE(3): the v of [ω; v], in the body frame, rotated by the pose's rotation; "
                        "SE(2): [x, y] of [x, y, θ]); 'posegraph optimize --covariances' writes it")
    p.add_argument("--every", type=positive_int, default=1, metavar="K",
                   help="with --covariances: an ellipse for every K-th pose (file order; default 1)")
    p.add_argument("--scale", type=non_negative_float, default=None, metavar="S",
                   help="with --covariances: multiply the 1-sigma semi-axes by S (default: the largest ellipse "
                        "spans ~4%% of the view; the legend states the factor)")


def run(args) -> int:
    inputs = [args.input, *args.more]
    if args.labels is not None and len(args.labels) != len(inputs):
        raise UsageError(f"--labels needs {len(inputs)} names (one per input), got {len(args.labels)}")
    check_inputs(inputs)
    _check_covariance_options(args)
    check_figure(args.output, inputs=inputs)
    from posegraph.analysis.plot import plot_trajectories

    status = Status(True)
    graphs = [read_graph(path, status, require_edges=False, repair_information=args.repair_information,
                         **reader_options(args))[0] for path in inputs]
    labels = args.labels or [os.path.basename(display_name(p)) for p in inputs]
    uncertainty = None
    if args.covariances:
        uncertainty = dict(covariances=read_covariances(args.covariances, graphs[0]), every=args.every,
                           scale=args.scale)
    plot_trajectories(args.output, graphs, labels, loop_closures=not args.no_loop_closures, title=args.title,
                      top_view=args.top_view, uncertainty=uncertainty)
    return EXIT_OK


def _check_covariance_options(args) -> None:
    if not args.covariances and (args.every != 1 or args.scale is not None):
        raise UsageError("--every and --scale apply to --covariances")
    if args.scale == 0:
        raise UsageError("--scale must be > 0")


def read_covariances(path: str, graph):
    """``(n, d, d)`` covariances of ``graph``'s vertices (its order) from an ``optimize --covariances`` file.

    Raises :class:`posegraph.errors.InputError` naming ``path`` when it is not such a file, its
    block size does not match the graph's poses, or an id of the graph is missing from it.
    """
    import numpy as np

    from posegraph.errors import InputError

    try:
        with np.load(path, allow_pickle=False) as data:
            ids, covariances = np.asarray(data["ids"]), np.asarray(data["covariances"], dtype=np.float64)
    except KeyError as exc:
        raise InputError(f"not a covariance file: array {exc} missing (expected 'ids' and 'covariances')", path) from None
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read covariances: {' '.join(str(exc).split())}", path) from None
    d = {4: 6, 3: 3}[graph.poses.shape[-1]]
    if ids.ndim != 1 or covariances.shape != (ids.shape[0], d, d) or not np.issubdtype(ids.dtype, np.integer):
        raise InputError(f"expected integer 'ids' (n,) and 'covariances' (n, {d}, {d}) for this graph's poses, "
                         f"got {ids.shape} {ids.dtype} and {covariances.shape}", path)
    if not np.all(np.isfinite(covariances)):
        raise InputError("covariances hold non-finite values", path)
    order = np.argsort(ids, kind="stable")
    where = np.clip(np.searchsorted(ids, graph.ids, sorter=order), 0, max(ids.shape[0] - 1, 0))
    found = order[where] if ids.size else where
    missing = graph.ids[ids[found] != graph.ids] if ids.size else graph.ids
    if missing.size:
        raise InputError(f"no covariance for vertex ids {missing[:5].tolist()} of the graph", path)
    return covariances[found]
