"""``posegraph info``: counts, components, degrees, information ranges and cost of one graph."""

from __future__ import annotations

from posegraph.cli.common import EXIT_OK, Status, fmt_cost, read_graph, repair_option

NAME = "info"
HELP = "counts, components, degrees, information ranges, cost"
DESCRIPTION = (
    "Describe a g2o pose graph: vertex and edge counts, FIX vertices, connected components, "
    "degree statistics, odometry edges (consecutive ids) against loop closures, ranges of the "
    "information matrices, and the cost at the file's poses."
)
EXAMPLES = """
  posegraph info parking-garage.g2o
  posegraph info sphere2500.g2o --json"""


def add_arguments(p) -> None:
    p.add_argument("input", metavar="IN.g2o", help="input pose graph")
    repair_option(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


def run(args) -> int:
    from posegraph.report import graph_info

    graph, _ = read_graph(args.input, Status(True), repair_information=args.repair_information)
    info = graph_info(graph)
    if args.json:
        import json

        print(json.dumps(info, indent=2))
        return EXIT_OK
    rows = _rows(args.input, info)
    width = max(len(key) for key, _ in rows) + 2
    for key, value in rows:
        print(f"{key + ':':<{width}}{value}")
    return EXIT_OK


def _rows(path: str, info: dict) -> list[tuple[str, str]]:
    """The text output's ``(label, value)`` lines from :func:`posegraph.report.graph_info`."""
    rows = [
        ("file", path + ("" if info["group"] == "SE3" else " (2D: SE(2) poses)")),
        ("vertices", f"{info['num_vertices']} (ids {info['id_min']}..{info['id_max']}, "
                     + ("contiguous" if info["ids_contiguous"] else "not contiguous")
                     + f"), {info['num_fixed']} fixed"),
        ("edges", f"{info['num_edges']}: {info['num_odometry_edges']} odometry (consecutive ids), "
                  f"{info['num_loop_closures']} loop closures"),
        ("components", str(info["num_components"])),
        ("degree", f"min {info['degree_min']}, max {info['degree_max']}, mean {info['degree_mean']:.3f}, "
                   f"median {info['degree_median']:g}"),
    ]
    for part in ("rotation", "translation"):
        r = info["information"][part]
        rows.append((f"information, {part} block",
                     f"diagonal {r['diagonal_min']:.4g} .. {r['diagonal_max']:.4g}, "
                     f"eigenvalues {r['eigenvalue_min']:.4g} .. {r['eigenvalue_max']:.4g}"))
    whole = info["information"]
    size = 6 if info["group"] == "SE3" else 3
    rows.append((f"information, {size}x{size}", f"eigenvalues {whole['eigenvalue_min']:.4g} .. {whole['eigenvalue_max']:.4g}; "
                                     f"{whole['coupled_edges']} edges couple rotation and translation"))
    rows.append(("initial cost", f"{fmt_cost(info['initial_cost'])} (at the file's poses)"))
    return rows
