"""Plain-dict summaries for the command line and its JSON reports.

* :func:`graph_info` — what ``posegraph info`` prints: counts, components, degrees, odometry vs
  loop-closure edges, information-matrix ranges, the cost at the file's poses.
* :func:`chi2_summary` — χ² = Σ eᵀΩe (twice the cost ½ Σ eᵀΩe, as g2o prints it), its degrees
  of freedom, χ²/dof, the split by edge kind (odometry, loop closure) and the worst edges.
* :func:`optimize_report` — what ``posegraph optimize --report`` writes: the run's settings,
  costs, χ², termination, per-phase seconds and one record per iteration.

Every value is a JSON type (int, float, str, bool, list, dict); :func:`posegraph.io.atomic.write_json_atomic`
writes them (non-finite floats become ``null``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["REPORT_VERSION", "CHI2_PER_DOF_WARNING", "edge_chi2", "chi2_summary", "dof_equation", "per_dof_text",
           "graph_info", "optimize_report"]

REPORT_VERSION = 2
"""Bumped when a key of :func:`optimize_report` changes meaning or disappears (2: ``start_cost``
dropped, the same as ``initial_cost``; records' ``attempts`` renamed ``factorizations``)."""

CHI2_PER_DOF_WARNING = 10.0
"""χ²/dof above this is "far above what the noise model predicts": with measurements drawn from
the information matrices, χ² at the optimum is about χ²(dof) distributed, so χ²/dof ≈ 1; ten times
that means outliers or information matrices that overstate the measurements' precision. Measured at
the optimum (chordal + LM): tinyGrid3D 1.04, smallGrid3D 1.00, torus3D 1.00, sphere2500 0.092,
parking-garage 4.6e-5, cubicle (repaired) 0.041; sphere_bignoise_vertex3 77 (its noise is far larger
than its information matrices say: warned); the bundled generator's 1,000-pose grid with 10 %
outliers 799."""

WORST_EDGES = 3
"""How many of the largest-χ² edges the summary names."""


def _range(values: np.ndarray) -> tuple[float, float]:
    return (float(values.min()), float(values.max())) if values.size else (float("nan"), float("nan"))


def graph_info(graph) -> dict:
    """Facts about ``graph`` (a :class:`~posegraph.model.graph.PoseGraph`) as a dict.

    Keys: ``num_vertices, num_edges, num_fixed, num_components, degree_min, degree_max,
    degree_mean, degree_median, num_odometry_edges, num_loop_closures`` (from
    :func:`posegraph.model.graph.graph_facts`); ``id_min, id_max, ids_contiguous``; ``information``:
    for the ``rotation`` and ``translation`` diagonal blocks of Ω (at the group's rotation and
    translation axes: 3×3 and 3×3 of SE(3)'s ``[ω; v]``, 1×1 and 2×2 of SE(2)'s ``[v_x, v_y, ω]``)
    the range of their diagonal entries and of their eigenvalues, the range of the eigenvalues of
    the whole d×d matrices, and ``coupled_edges``, the number of edges whose Ω couples rotation and
    translation (a non-zero off-diagonal block); ``group`` (``"SE3"``, ``"SE2"`` or ``"SIM3"``);
    ``landmarks`` (:func:`landmark_facts`: counts of the landmarks and of their measurements by kind);
    ``initial_cost``, ½ Σ eᵀ Ω e at the file's poses, and there
    ``chi2``, ``dof``, ``chi2_per_dof``, ``chi2_by_kind`` (:func:`chi2_summary`).
    """
    from dataclasses import asdict

    from posegraph.model.graph import graph_facts

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
    priors = graph.priors
    info["priors"] = {"pose": priors.num_pose if priors else 0, "position": priors.num_position if priors else 0}
    info["landmarks"] = landmark_facts(graph)
    chi2 = chi2_summary(graph)
    info["initial_cost"] = chi2["cost"]
    info.update(chi2=chi2["chi2"], dof=chi2["dof"], chi2_per_dof=chi2["chi2_per_dof"], chi2_by_kind=chi2["by_kind"])
    return info


def landmark_facts(graph) -> dict:
    """``{"count", "fixed", "dimension", "measurements": {kind: count}, "tags": {tag: count}}`` of the
    graph's landmarks (all zero and empty for a pose graph)."""
    landmarks = graph.landmarks
    if landmarks is None:
        return {"count": 0, "fixed": 0, "dimension": graph.group.space_dim, "measurements": {}, "tags": {}}
    kinds: dict = {}
    tags: dict = {}
    for family in landmarks.observations:
        kinds[family.kind] = kinds.get(family.kind, 0) + family.count
        tags[family.tag] = tags.get(family.tag, 0) + family.count
    return {"count": landmarks.count, "fixed": int(np.count_nonzero(landmarks.fixed)), "dimension": landmarks.space_dim,
            "measurements": kinds, "tags": tags}


def edge_chi2(graph, poses=None, residuals=None) -> np.ndarray:
    """``(m,)`` per-edge ``χ²_e = e_eᵀ Ω_e e_e`` at ``poses`` (default the graph's), e the edge residual.

    ``residuals`` ``(m, d)``: the residuals at ``poses`` when already known (e.g. an
    :class:`~posegraph.solve.OptimizeResult`'s ``final_residuals``), else they are evaluated.
    """
    from posegraph.solve.residuals import edge_residuals, squared_norms

    if residuals is None:
        residuals = edge_residuals(graph.poses if poses is None else poses, graph)
    return squared_norms(residuals, graph.information)


def chi2_summary(graph, poses=None, residuals=None) -> dict:
    """χ² of ``graph`` at ``poses`` and what it means (``residuals``: as in :func:`edge_chi2`).

    Keys: ``cost`` (½χ², the optimiser's cost and gtsam's ``error``), ``chi2`` (Σ eᵀΩe, g2o's
    ``chi2``), ``dof`` = the measurements' rows − the free unknowns: d·edges (d the tangent dimension,
    the information matrices' size) + the priors' and each landmark family's residual rows (r·q) −
    d·free poses (neither ``FIX`` nor a gauge anchor) − s·free points (s the space dimension),
    ``dof_parts`` (``{"rows": [...], "unknowns": [...]}``, each term ``{"what", "count", "size"}``,
    :func:`dof_equation` prints them), ``chi2_per_dof`` (NaN when dof ≤ 0), ``by_kind`` (``odometry``, ``loop_closure`` and, with
    priors, ``prior``, with landmarks, ``landmark`` (their measurements, at the graph's landmark
    positions; their residuals' rows count in ``dof``, their free points' ``s`` each against it):
    ``count``, ``chi2``, ``chi2_per_edge``)
    and ``worst_edges`` (the :data:`WORST_EDGES` largest: ``line`` in the file or None,
    ``from_id``, ``to_id``, ``chi2``).
    """
    from posegraph.model.graph import held_vertices

    chi2 = edge_chi2(graph, poses, residuals)
    d = graph.information.shape[-1]
    free = graph.num_vertices - int(np.count_nonzero(held_vertices(graph)))
    rows = [_term("edges", graph.num_edges, d)]
    unknowns = [_term("free poses", free, d)]
    odometry = graph.odometry_mask()
    by_kind = {}
    for kind, mask in (("odometry", odometry), ("loop_closure", ~odometry)):
        count = int(np.count_nonzero(mask))
        part = float(chi2[mask].sum())
        by_kind[kind] = {"count": count, "chi2": part, "chi2_per_edge": part / count if count else float("nan")}
    total = float(chi2.sum())
    if graph.priors is not None:  # unary edges: their χ² and their residuals' dimensions count too
        prior, prior_rows = _prior_chi2(graph, poses)
        by_kind["prior"] = {"count": len(prior), "chi2": float(prior.sum()),
                            "chi2_per_edge": float(prior.mean()) if len(prior) else float("nan")}
        total, rows = total + float(prior.sum()), rows + prior_rows
    if graph.landmarks is not None:
        landmark, landmark_rows, free_points = _landmark_chi2(graph, poses)
        by_kind["landmark"] = {"count": len(landmark), "chi2": float(landmark.sum()),
                               "chi2_per_edge": float(landmark.mean()) if len(landmark) else float("nan")}
        total, rows = total + float(landmark.sum()), rows + landmark_rows
        unknowns.append(free_points)
    dof = sum(t["count"] * t["size"] for t in rows) - sum(t["count"] * t["size"] for t in unknowns)
    worst = np.argsort(-chi2, kind="stable")[:WORST_EDGES]
    worst = [{k: v for k, v in row.items() if k != "edge"} for row in edge_rows(graph, worst, chi2[worst])]
    return {"cost": total / 2, "chi2": total, "dof": int(dof), "chi2_per_dof": total / dof if dof > 0 else float("nan"),
            "dof_parts": {"rows": rows, "unknowns": unknowns}, "by_kind": by_kind, "worst_edges": worst}


def edge_rows(graph, edges, chi2) -> list[dict]:
    """``{"edge", "line", "from_id", "to_id", "chi2"}`` for each edge index of ``edges`` ``(k,)`` with its
    ``chi2`` ``(k,)``: ``line`` in the file (None for a graph not read from one), the vertices' ids."""
    lines = getattr(graph, "edge_lines", None)
    return [{"edge": int(e), "line": int(lines[e]) if lines is not None else None,
             "from_id": int(graph.ids[graph.edge_from[e]]), "to_id": int(graph.ids[graph.edge_to[e]]),
             "chi2": float(c)} for e, c in zip(edges, chi2)]


def _term(what: str, count: int, size: int) -> dict:
    return {"what": what, "count": int(count), "size": int(size)}


def dof_equation(chi2: dict) -> str:
    """``"6·4949 edges − 6·2499 free poses = 14700"``: :func:`chi2_summary`'s ``dof`` as the measurement
    rows it counts minus the free unknowns (terms with a zero count left out)."""
    parts = chi2["dof_parts"]
    text = " + ".join(f"{t['size']}·{t['count']} {t['what']}" for t in parts["rows"] if t["count"]) or "0 rows"
    text += "".join(f" − {t['size']}·{t['count']} {t['what']}" for t in parts["unknowns"] if t["count"])
    return f"{text} = {chi2['dof']}"


def per_dof_text(chi2: dict) -> str:
    """χ²/dof to 4 digits, or ``"undefined (dof 0)"`` when dof ≤ 0 (nothing over-determined)."""
    return f"{chi2['chi2_per_dof']:.4g}" if chi2["dof"] > 0 else f"undefined (dof {chi2['dof']})"


def _landmark_chi2(graph, poses=None) -> tuple[np.ndarray, list, dict]:
    """``((Σq,) χ² of each landmark measurement, one dof row term per family (its r·q), the free
    points' term (s each))`` at ``poses`` and the graph's landmark positions."""
    from posegraph.solve.landmark_terms import landmark_errors

    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    landmarks = graph.landmarks
    errors = landmark_errors(graph, poses, landmarks.positions)
    rows = [_term(f"{family.kind.replace('_', '-')} measurements", e.shape[0], e.shape[1])
            for family, e in zip(landmarks.observations, errors.residuals)]
    free = landmarks.count - int(np.count_nonzero(landmarks.fixed))
    return errors.squared, rows, _term("free points", free, landmarks.space_dim)


def _prior_chi2(graph, poses=None) -> tuple[np.ndarray, list]:
    """``((a + b,) χ² of each prior, the dof row terms of the pose and position priors)`` at ``poses``."""
    from posegraph.solve.unary import prior_errors, prior_squared_norms

    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    priors = graph.priors
    rows = [_term("pose priors", priors.num_pose, graph.group.dim),
            _term("position priors", priors.num_position, graph.group.space_dim)]
    return prior_squared_norms(prior_errors(poses, graph), priors), rows


def optimize_report(
    input_path: str,
    output_path: str,
    graph,
    result,
    *,
    init: str,
    file_cost: float,
    seconds: dict,
    params=None,
    chi2: dict | None = None,
) -> dict:
    """The JSON report of one ``posegraph optimize`` run.

    ``result`` is the solver's :class:`~posegraph.solve.result.OptimizeResult`; ``file_cost`` the
    cost at the file's poses; ``seconds`` the CLI's per-phase wall-clock times (``read``,
    ``initialise``, ``optimise``, ``write``); ``chi2`` :func:`chi2_summary` at the result (computed
    if not given).

    Main keys: ``cost_definition`` (what every ``*_cost`` is: ½χ²), ``file_cost``, ``initial_cost``
    (where the optimiser started, after initialisation), ``final_cost``, ``chi2`` (the final χ²,
    twice ``final_cost``), ``dof``, ``chi2_per_dof``, ``chi2_by_kind``, ``worst_edges``,
    ``iterations``, ``converged``, ``termination``, ``linear_solver``, ``seconds`` (CLI phases plus
    the solver's own split under ``solver``), ``records`` (one dict per iteration: ``iteration,
    cost, cost_decrease, lambda, step_norm, gain_ratio, accepted, factorizations, seconds_*``;
    ``factorizations`` is the number of damped systems factorised, 0 when the step reused the
    previous factorisation or none was needed).
    """
    chi2 = chi2_summary(graph, result.poses) if chi2 is None else chi2
    from posegraph import __version__

    return {
        "report_version": REPORT_VERSION,
        "posegraph_version": __version__,
        "input": str(input_path),
        "output": str(output_path),
        "num_vertices": graph.num_vertices,
        "num_edges": graph.num_edges,
        "num_landmarks": graph.landmarks.count if graph.landmarks is not None else 0,
        "num_landmark_measurements": graph.landmarks.num_measurements if graph.landmarks is not None else 0,
        "settings": _settings(init, result, params),
        "cost_definition": "half chi2: 1/2 sum of e^T Omega e over the edges, priors and landmark measurements "
                           "(gtsam's error; g2o's chi2 is twice it)",
        "file_cost": float(file_cost),
        "initial_cost": float(result.initial_cost),
        "final_cost": float(result.final_cost),
        "chi2": chi2["chi2"],
        "dof": chi2["dof"],
        "chi2_per_dof": chi2["chi2_per_dof"],
        "chi2_by_kind": chi2["by_kind"],
        "worst_edges": chi2["worst_edges"],
        "iterations": int(result.iterations),
        "converged": bool(result.converged),
        "termination": str(result.termination),
        "linear_solver": str(result.linear_solver),
        "seconds": _seconds(seconds, result),
        "records": [_record(r) for r in result.records],
    }


def _settings(init: str, result, params) -> dict:
    """The report's ``settings``: the start, the method and, given ``params``, the solver's options."""
    settings = {"init": init, "method": result.method}
    if params is not None:
        settings.update(
            max_iterations=int(params.max_iterations),
            relative_tolerance=float(params.relative_tolerance),
            absolute_tolerance=float(params.absolute_tolerance),
            linear_solver_requested=str(params.linear_solver),
        )
    return settings


def _seconds(seconds: dict, result) -> dict:
    """The report's ``seconds``: the CLI's phases, their total, and the solver's own split."""
    return {
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
    }


def _record(r) -> dict:
    """One :class:`~posegraph.solve.result.IterationRecord` as a JSON dict."""
    return {
        "iteration": int(r.iteration),
        "cost": float(r.cost),
        "cost_decrease": float(r.cost_decrease),
        "lambda": float(r.lambda_),
        "step_norm": float(r.step_norm),
        "gain_ratio": float(r.gain_ratio),
        "accepted": bool(r.accepted),
        "factorizations": int(r.attempts),
        "seconds_linearize": float(r.seconds_linearize),
        "seconds_assemble": float(r.seconds_assemble),
        "seconds_factorize": float(r.seconds_factorize),
        "seconds_solve": float(r.seconds_solve),
        "seconds": float(r.seconds),
    }
