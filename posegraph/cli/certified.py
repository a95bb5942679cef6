"""``optimize --certify``: certify SE-Sync's isotropic problem, polish its estimate with LM on the
file's full cost, and compare that with LM from the chordal start. With ``--robust gnc`` the problem
certified and polished is that of the edges (and priors) GNC kept, and the report says so."""

from __future__ import annotations

import dataclasses

import numpy as np

from posegraph.cli.common import Status, Timer, UsageError, warn


def check_certify_options(args) -> None:
    """``--certify`` certifies a least-squares problem: the file's, or with ``--robust gnc`` that of the edges
    GNC kept; an M-estimator's cost (huber, cauchy, …) has no such certificate."""
    if args.certify and args.robust not in ("none", "gnc"):
        raise UsageError(f"--certify cannot be combined with --robust {args.robust} (the certificate is for a "
                         "least-squares problem: the file's, or with --robust gnc that of the edges it kept)")


def pose_differences(group, poses_a: np.ndarray, poses_b: np.ndarray) -> tuple[float, float]:
    """``(largest translation distance, largest rotation angle in rad)`` between two ``(n, k, k)`` pose sets."""
    r = group.space_dim
    translation = float(np.max(np.linalg.norm(poses_a[:, :r, r] - poses_b[:, :r, r], axis=1), initial=0.0))
    relative = np.swapaxes(poses_a[:, :r, :r], 1, 2) @ poses_b[:, :r, :r]
    # cos θ of the relative rotation: (tr − 1)/2 in 3D, its first entry in 2D
    cosine = (np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0 if r == 3 else relative[:, 0, 0]
    cosine = np.clip(cosine, -1.0, 1.0)
    return translation, float(np.max(np.arccos(cosine), initial=0.0))


def polish_certified(held, chordal_result, params, status: Status, seconds: dict, dropped: int | None = None):
    """``(result to write, report section)``: LM on ``held``'s least-squares cost from the certified estimate.

    ``chordal_result`` is LM's result from the chordal start (with ``--robust gnc``: GNC's, whose last
    solve is least squares over the edges it kept, ``held`` then being those edges' graph and
    ``dropped`` how many it left out), compared with the polished one: the cost difference and the
    largest pose differences (both hold the same vertices at their file pose, so they share a gauge).
    The section holds the certificate's fields too.
    """
    from posegraph.certification.certificate import certify
    from posegraph.model.graph import held_vertices
    from posegraph.solve import optimize

    with Timer() as t_cert:
        certificate = certify(held)
    seconds["certify"] = t_cert.seconds
    kept = "" if dropped is None else f" of the {held.num_edges} edges GNC kept ({dropped} dropped)"
    status(f"certify{kept}: {certificate.status}, F(x) = {certificate.sesync_objective:.6g} ({t_cert.seconds:.3f} s)")
    start = certificate.poses.copy()
    fixed = held_vertices(held)
    start[fixed] = held.poses[fixed]
    with Timer() as t_polish:
        polished = optimize(held, initial=start, params=dataclasses.replace(params, loss=None))
    seconds["polish"] = t_polish.seconds
    translation, rotation = pose_differences(held.group, polished.poses, chordal_result.poses)
    difference = polished.final_cost - chordal_result.final_cost
    same = abs(difference) <= 1e-6 * max(abs(chordal_result.final_cost), 1e-12) and translation <= 1e-3 and rotation <= 1e-4
    section = {
        **certificate.report(), "polished_cost": polished.final_cost, "chordal_lm_cost": chordal_result.final_cost,
        "cost_difference": difference, "max_translation_difference": translation,
        "max_rotation_difference_rad": rotation, "same_basin": bool(same),
        "certified_graph": "file" if dropped is None else "gnc_inliers", "certified_edges": held.num_edges,
    }  # fmt: skip
    if not certificate.certified:
        warn(f"SE-Sync's isotropic problem was {certificate.status}; the result is LM's polish of its best "
             "estimate")
    return polished, section


def certify_summary(section: dict) -> list[str]:
    """The summary lines of ``optimize --certify``."""
    verdict = "same basin" if section["same_basin"] else "DIFFERENT basins"
    graph = "" if section["certified_graph"] == "file" else f" of the {section['certified_edges']} edges GNC kept"
    return [
        f"certificate:    {'certified' if section['certified'] else 'NOT certified'} (SE-Sync's isotropic problem{graph}: "
        f"F(x) = {section['sesync_objective']:.6g}, bound {section['suboptimality_bound']:.3g}, rank {section['rank']})",
        f"polished:       cost {section['polished_cost']:.12g} from the certificate's estimate, "
        f"{section['chordal_lm_cost']:.12g} from the chordal start ({verdict}: cost difference "
        f"{section['cost_difference']:.3g}, poses differ by up to {section['max_translation_difference']:.3g} m and "
        f"{section['max_rotation_difference_rad']:.3g} rad)",
    ]
