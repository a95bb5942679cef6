"""Plain-dict summaries for the command line and its JSON reports.

* :func:`graph_info` — what ``posegraph info`` prints: counts, components, degrees, odometry vs
  loop-closure edges, information-matrix ranges, the cost at the file's poses.
* :func:`optimize_report` — what ``posegraph optimize --report`` writes: the run's settings,
  costs, termination, per-phase seconds and one record per iteration.

Every value is a JSON type (int, float, str, bool, list, dict); :func:`posegraph.atomic.write_json_atomic`
writes them (non-finite floats become ``null``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["REPORT_VERSION", "graph_info", "optimize_report"]

REPORT_VERSION = 1
"""Bumped when a key of :func:`optimize_report` changes meaning or disappears."""


def _range(values: np.ndarray) -> tuple[float, float]:
    return (float(values.min()), float(values.max())) if values.size else (float("nan"), float("nan"))


def graph_info(graph) -> dict:
    """Facts about ``graph`` (a :class:`~posegraph.graph.PoseGraph`) as a dict.

    Keys: ``num_vertices, num_edges, num_fixed, num_components, degree_min, degree_max,
    degree_mean, degree_median, num_odometry_edges, num_loop_closures`` (from
    :func:`posegraph.graph.graph_facts`); ``id_min, id_max, ids_contiguous``; ``information``:
    for the ``rotation`` and ``translation`` diagonal blocks of Ω (at the group's rotation and
    translation axes: 3×3 and 3×3 of SE(3)'s ``[ω; v]``, 1×1 and 2×2 of SE(2)'s ``[v_x, v_y, ω]``)
    the range of their diagonal entries and of their eigenvalues, the range of the eigenvalues of
    the whole d×d matrices, and ``coupled_edges``, the number of edges whose Ω couples rotation and
    translation (a non-zero off-diagonal block); ``group`` (``"SE3"`` or ``"SE2"``);
    ``initial_cost``, ½ Σ eᵀ Ω e at the file's poses.
    """
    from dataclasses import asdict

    from posegraph.graph import graph_facts
    from posegraph.solve.residuals import cost

    info = asdict(graph_facts(graph))
    ids = graph.ids
    info["id_min"] = int(ids.min())
    info["id_max"] = int(ids.max())
    info["ids_contiguous"] = bool(info["id_max"] - info["id_min"] + 1 == graph.num_vertices)

    omega = graph.information
    rotation, translation = graph.group.rotation_block, graph.group.translation_block
    blocks = {"rotation": omega[:, rotation, rotation], "translation": omega[:, translation, translation]}
    information: dict = {}
    for name, block in blocks.items():
        diagonal = np.diagonal(block, axis1=-2, axis2=-1)
        eigenvalues = np.linalg.eigvalsh(block)
        lo, hi = _range(diagonal)
        elo, ehi = _range(eigenvalues)
        information[name] = {"diagonal_min": lo, "diagonal_max": hi, "eigenvalue_min": elo, "eigenvalue_max": ehi}
    eigenvalues = np.linalg.eigvalsh(omega)
    information["eigenvalue_min"], information["eigenvalue_max"] = _range(eigenvalues)
    coupling = omega[:, rotation, translation]
    information["coupled_edges"] = int(np.count_nonzero(np.any(coupling != 0, axis=(1, 2))))
    info["information"] = information
    info["group"] = graph.group.name
    info["initial_cost"] = float(cost(graph))
    return info


def optimize_report(
    input_path: str,
    output_path: str,
    graph,
    result,
    *,
    init: str,
    file_cost: float,
    start_cost: float,
    seconds: dict,
    params=None,
) -> dict:
    """The JSON report of one ``posegraph optimize`` run.

    ``result`` is the solver's :class:`~posegraph.solve.result.OptimizeResult`; ``file_cost`` the
    cost at the file's poses, ``start_cost`` after initialisation; ``seconds`` the CLI's per-phase
    wall-clock times (``read``, ``initialise``, ``optimise``, ``write``).

    Main keys: ``initial_cost`` (the optimiser's start, = ``start_cost``), ``final_cost``,
    ``iterations``, ``converged``, ``termination``, ``linear_solver``, ``seconds`` (CLI phases plus
    the solver's own split under ``solver``), ``records`` (one dict per iteration: ``iteration,
    cost, cost_decrease, lambda, step_norm, gain_ratio, accepted, attempts, seconds_*``).
    """
    records = []
    for r in result.records:
        records.append(
            {
                "iteration": int(r.iteration),
                "cost": float(r.cost),
                "cost_decrease": float(r.cost_decrease),
                "lambda": float(r.lambda_),
                "step_norm": float(r.step_norm),
                "gain_ratio": float(r.gain_ratio),
                "accepted": bool(r.accepted),
                "attempts": int(r.attempts),
                "seconds_linearize": float(r.seconds_linearize),
                "seconds_assemble": float(r.seconds_assemble),
                "seconds_factorize": float(r.seconds_factorize),
                "seconds_solve": float(r.seconds_solve),
                "seconds": float(r.seconds),
            }
        )
    settings = {"init": init, "method": result.method}
    if params is not None:
        settings.update(
            max_iterations=int(params.max_iterations),
            relative_tolerance=float(params.relative_tolerance),
            absolute_tolerance=float(params.absolute_tolerance),
            linear_solver_requested=str(params.linear_solver),
        )
    from posegraph import __version__

    return {
        "report_version": REPORT_VERSION,
        "posegraph_version": __version__,
        "input": str(input_path),
        "output": str(output_path),
        "num_vertices": graph.num_vertices,
        "num_edges": graph.num_edges,
        "settings": settings,
        "file_cost": float(file_cost),
        "initial_cost": float(result.initial_cost),
        "start_cost": float(start_cost),
        "final_cost": float(result.final_cost),
        "iterations": int(result.iterations),
        "converged": bool(result.converged),
        "termination": str(result.termination),
        "linear_solver": str(result.linear_solver),
        "seconds": {
            **{k: float(v) for k, v in seconds.items()},
            "total": float(sum(seconds.values())),
            "solver": {
                "setup": float(result.seconds_setup),
                "linearize": float(result.seconds_linearize),
                "assemble": float(result.seconds_assemble),
                "factorize": float(result.seconds_factorize),
                "solve": float(result.seconds_solve),
                "total": float(result.seconds_total),
            },
        },
        "records": records,
    }
