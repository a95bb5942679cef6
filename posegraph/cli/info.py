"""``posegraph info``: counts, components, degrees, information ranges and cost of one graph."""

from __future__ import annotations

import re

from posegraph.cli.common import reader_options, EXIT_OK, Status, display_name, fmt_cost, read_graph, repair_option

NAME = "info"
HELP = "counts, components, degrees, information ranges, cost"
DESCRIPTION = (
    "Describe a g2o pose graph: vertex and edge counts, FIX vertices, connected components, "
    "degree statistics, odometry edges (consecutive ids) against loop closures, ranges of the "
    "information matrices, and the cost, chi2 and chi2/dof at the file's poses. A graph that "
    "optimize would refuse (information matrices not positive semi-definite, no edges) is described "
    "all the same, with what optimize would refuse and why."
)
EXAMPLES = """
  posegraph info parking-garage.g2o
  posegraph info sphere2500.g2o --json"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph (- for standard input)")
    repair_option(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


def run(args) -> int:
    from posegraph.analysis.report import graph_info

    graph, refusals, notes = _read_for_description(args)
    info = graph_info(graph)
    info["optimize_refuses"] = refusals
    info["notes"] = notes
    if args.json:
        import json

        print(json.dumps(info, indent=2))
        return EXIT_OK
    rows = _rows(args.input, info)
    width = max(len(key) for key, _ in rows) + 2
    for key, value in rows:
        print(f"{key + ':':<{width}}{value}")
    return EXIT_OK


_REPAIRED = re.compile(r":(\d+): repaired (\d+) information matrices")
"""The reader's warning for ``repair_information=True`` (``posegraph.io.g2o_checks.check_information``)."""


def _read_for_description(args):
    """``(graph, what optimize would refuse, notes)``: the file read as leniently as the reader allows.

    Indefinite information matrices are repaired (counted, and described as a refusal unless
    ``--repair-information`` was asked for), and a file without edges is read as a trajectory.
    """
    import warnings

    from posegraph.errors import PosegraphWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PosegraphWarning)  # the others as the command line filters them
        graph, notes = _read_leniently(args)
    refusals = []
    for w in caught:
        match = _REPAIRED.search(str(w.message))
        if match and not args.repair_information:
            refusals.append(f"{match.group(2)} information matrices are not positive semi-definite (the first at "
                            f"line {match.group(1)}): optimize refuses the file without --repair-information; "
                            "the figures here are of the repaired matrices")
        else:
            warnings.warn(w.message, stacklevel=1)
    if graph.num_edges == 0:
        refusals.append("the file has no edges: there is nothing to optimise")
    return graph, refusals, notes


def _read_leniently(args):
    """``(graph, notes)``: the file read as a trajectory (vertex lines required, edges not), or, when it has
    edges but no vertex lines (gtsam's ``sphere2500.txt``, ``victoria_park.txt``), as ``optimize`` reads it:
    the vertices its edges name, at the identity, said in a note. Standard input is read once only."""
    from posegraph.errors import GraphError

    options = reader_options(args)
    try:
        return read_graph(args.input, Status(True), require_edges=False, repair_information=True, **options)[0], []
    except GraphError as err:
        if args.input == "-" or "gives no poses to read" not in str(err):
            raise
    graph, _ = read_graph(args.input, Status(True), repair_information=True, uses_file_poses=False, **options)
    return graph, [f"the file has no vertex lines: the {graph.num_vertices} vertices its edges name are at the "
                   "identity, so the cost below is at identity poses (optimize starts from the chordal relaxation)"]


_GROUP_NOTES = {"SE3": "", "SE2": " (2D: SE(2) poses)", "SIM3": " (Sim(3) poses: rotation, translation, scale)"}
"""What the ``file`` line adds per group (by :attr:`posegraph.lie.group.LieGroup.name`)."""
_TANGENT_SIZES = {"SE3": 6, "SE2": 3, "SIM3": 7}


def _landmark_text(facts: dict) -> str:
    """``"151 points (2D), 0 fixed; 3640 measurements: EDGE_SE2_XY ×3640 (position)"``."""
    tags = ", ".join(f"{tag} ×{count}" for tag, count in facts["tags"].items())
    kinds = ", ".join(facts["measurements"])
    total = sum(facts["measurements"].values())
    return f"{facts['count']} points ({facts['dimension']}D), {facts['fixed']} fixed; {total} measurements: {tags} ({kinds})"


def _rows(path: str, info: dict) -> list[tuple[str, str]]:
    """The text output's ``(label, value)`` lines from :func:`posegraph.analysis.report.graph_info`."""
    rows = [
        ("file", display_name(path) + _GROUP_NOTES[info["group"]]),
        ("vertices", f"{info['num_vertices']} (ids {info['id_min']}..{info['id_max']}, "
                     + ("contiguous" if info["ids_contiguous"] else "not contiguous")
                     + f"), {info['num_fixed']} fixed"),
        ("edges", f"{info['num_edges']}: {info['num_odometry_edges']} odometry (consecutive ids), "
                  f"{info['num_loop_closures']} loop closures"),
        ("components", str(info["num_components"])),
        *([("landmarks", _landmark_text(info["landmarks"]))] if info["landmarks"]["count"] else []),
        *([("priors", f"{info['priors']['pose']} pose, {info['priors']['position']} position (unary edges; "
                      "they hold the gauge of the components they reach)")] if sum(info["priors"].values()) else []),
        ("degree", f"min {info['degree_min']}, max {info['degree_max']}, mean {info['degree_mean']:.3f}, "
                   f"median {info['degree_median']:g}"),
    ]
    for part in ("rotation", "translation"):
        r = info["information"][part]
        rows.append((f"information, {part} block",
                     f"diagonal {r['diagonal_min']:.4g} .. {r['diagonal_max']:.4g}, "
                     f"eigenvalues {r['eigenvalue_min']:.4g} .. {r['eigenvalue_max']:.4g}"))
    whole = info["information"]
    size = _TANGENT_SIZES[info["group"]]
    rows.append((f"information, {size}x{size}", f"eigenvalues {whole['eigenvalue_min']:.4g} .. {whole['eigenvalue_max']:.4g}; "
                                     f"{whole['coupled_edges']} edges couple rotation and translation"))
    rows.append(("initial cost", f"{fmt_cost(info['initial_cost'])} (½χ² at the file's poses; χ² "
                                 f"{fmt_cost(info['chi2'])}, χ²/dof {_per_dof(info)}, dof {info['dof']})"))
    rows += [("note", note) for note in info["notes"]]
    for refusal in info["optimize_refuses"]:
        rows.append(("optimize refuses", refusal))
    return rows


def _per_dof(info: dict) -> str:
    """χ²/dof, or "undefined" when dof ≤ 0."""
    return f"{info['chi2_per_dof']:.4g}" if info["dof"] > 0 else "undefined"
