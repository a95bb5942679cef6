"""``posegraph eval``: trajectory errors (ATE, RPE) of an estimate against a reference."""

from __future__ import annotations

from posegraph.cli.common import EXIT_OK, UsageError, check_inputs, display_name, non_negative_float, repair_option, warn

LENGTH_UNIT = "m"
"""g2o files carry no unit; translations are in the files' own length unit, metres in the standard
datasets (and in evo's reports, whose layout this follows)."""

NAME = "eval"
HELP = "trajectory errors (ATE, RPE) against a reference"
DESCRIPTION = (
    "Absolute trajectory error after a least-squares SE(3) alignment (SE(2) for two 2D graphs; "
    "Umeyama/Horn, no scale) "
    "and relative pose error between consecutive ids, as rmse/mean/median/std/min/max in the way "
    "evo reports them. Each file may be g2o (poses keyed by vertex id), TUM ('timestamp tx ty tz qx "
    "qy qz qw', keyed by timestamp) or KITTI (3x4 matrix per line, keyed by line number), plain or "
    "gzip/bzip2/xz-compressed, recognised by its content. Poses are matched by key: exactly for "
    "integer keys (vertex ids, TUM files written by 'posegraph export --tum'), otherwise as evo "
    "does, to the nearest timestamp within --max-time-diff."
)
EXAMPLES = """
  posegraph eval optimised.g2o ground-truth.g2o
  posegraph eval optimised.g2o ground-truth.g2o --json > errors.json
  posegraph eval optimised.g2o groundtruth_tum.txt"""


def add_arguments(p) -> None:
    p.add_argument("estimate", metavar="EST", help="estimated poses (g2o, TUM or KITTI file; - for standard input)")
    p.add_argument("reference", metavar="GT", nargs="?",
                   help="reference (ground-truth) poses (g2o, TUM or KITTI file); omitted with --priors")
    p.add_argument("--priors", action="store_true",
                   help="compare EST (a g2o file) with its own priors instead of a reference: each prior's vertex "
                        "against the pose the prior gives it (a position prior: its point, ATE rotation 0), "
                        "without alignment, since the priors fix the frame (e.g. the optimised poses against "
                        "their GNSS fixes)")
    repair_option(p)
    # 0.01 = posegraph.io.trajectory.EVO_MAX_TIME_DIFF, not imported here: --help stays free of numpy.
    p.add_argument("--max-time-diff", metavar="SECONDS", type=non_negative_float, default=0.01,
                   help="largest timestamp difference of two matched TUM poses (default 0.01, as evo's "
                        "--t_max_diff); integer keys match exactly")
    p.add_argument("--no-align", action="store_true", help="compute ATE without aligning the trajectories")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def read_poses(path: str, repair_information: bool):
    """``(keys (n,), poses, "g2o" | "tum" | "kitti")`` of a g2o, TUM or KITTI file: vertex ids, timestamps
    or line numbers, the poses, and the file's format."""
    from posegraph.io import trajectory

    kind = "g2o" if path == "-" else trajectory.file_format(path)
    if kind == "tum":
        keys, poses = trajectory.read_tum(path)
    elif kind == "kitti":
        keys, poses = trajectory.read_kitti(path)
    else:
        from posegraph.analysis.evaluate import read_trajectory

        keys, poses = read_trajectory(path, repair_information=repair_information)
    return keys, poses, kind


PLANE_TOLERANCE = 1e-6
"""A 3D trajectory compared with a 2D one must lie in the plane z = 0 (rotations about z) to this much:
|z| relative to the trajectory's extent (at least 1), and the out-of-plane entries of its rotations."""


def _off_plane(poses) -> tuple[float, float]:
    """``(largest |z| relative to max(1, extent), largest out-of-plane rotation entry)`` of ``(n, 4, 4)`` poses."""
    import numpy as np

    if not len(poses):
        return 0.0, 0.0
    positions = poses[:, :3, 3]
    extent = max(1.0, float(np.ptp(positions, axis=0).max()))
    tilt = np.concatenate([poses[:, 2, :2], poses[:, :2, 2]], axis=1)
    return float(np.abs(positions[:, 2]).max()) / extent, float(np.abs(tilt).max())


def _kind(path: str, poses, file_format: str) -> str:
    """``"a 2D g2o file (SE(2) poses)"``, ``"a 3D TUM file"`` … for messages."""
    from posegraph.analysis.evaluate import is_similarity_trajectory

    if file_format != "g2o":
        return f"a 3D {file_format.upper()} file"
    if poses.shape[-1] == 3:
        return "a 2D g2o file (SE(2) poses)"
    return f"a 3D g2o file ({'Sim(3)' if is_similarity_trajectory(poses) else 'SE(3)'} poses)"


def check_dimensions(estimate: tuple, reference: tuple) -> None:
    """A :class:`UsageError` when one trajectory is 2D and the other 3D off the plane z = 0.

    ``estimate``, ``reference``: ``(path, poses, file format)``. A 2D trajectory is compared in its
    embedding at z = 0 (:func:`posegraph.analysis.evaluate.evaluate`), which is meaningful only against
    a 3D one in that plane (a 2D graph exported to TUM or KITTI); anything else is two different
    kinds of trajectory, and the figures would measure the third dimension, not an error.
    """
    (path_a, poses_a, format_a), (path_b, poses_b, format_b) = estimate, reference
    if poses_a.shape[-1] == poses_b.shape[-1]:
        return
    flat = poses_b if poses_a.shape[-1] == 3 else poses_a
    height, tilt = _off_plane(flat)
    if height <= PLANE_TOLERANCE and tilt <= PLANE_TOLERANCE:
        return
    solid = path_b if poses_a.shape[-1] == 3 else path_a
    raise UsageError(
        f"cannot compare a 2D with a 3D trajectory: {display_name(path_a)} is {_kind(path_a, poses_a, format_a)}, "
        f"{display_name(path_b)} {_kind(path_b, poses_b, format_b)}, and {display_name(solid)} leaves the plane "
        "z = 0; give two 2D or two 3D trajectories ('posegraph export --tum' writes a 2D graph's poses in 3D)")


def run(args) -> int:
    from posegraph.analysis.evaluate import evaluate
    from posegraph.io.trajectory import matching_keys

    if (args.reference is None) != args.priors:
        raise UsageError("give a reference file GT, or --priors to compare EST with its own priors (not both)")
    check_inputs([args.estimate] + ([args.reference] if args.reference else []))
    if args.priors:
        estimate_ids, estimate_poses, reference_ids, reference_poses = _against_priors(args)
        args.no_align = True  # the priors fix the frame
    else:
        estimate_stamps, estimate_poses, estimate_format = read_poses(args.estimate, args.repair_information)
        reference_stamps, reference_poses, reference_format = read_poses(args.reference, args.repair_information)
        check_dimensions((args.estimate, estimate_poses, estimate_format),
                         (args.reference, reference_poses, reference_format))
        estimate_ids, reference_ids = matching_keys(estimate_stamps, reference_stamps, args.max_time_diff)
    result = evaluate(estimate_ids, estimate_poses, reference_ids, reference_poses,
                      align=not args.no_align, source=args.estimate)
    estimate = display_name(args.estimate)
    reference = f"the priors of {estimate}" if args.priors else display_name(args.reference)
    if result.num_matched < max(result.num_estimate, result.num_reference):
        warn(f"compared the {result.num_matched} vertex ids present in both files "
             f"({result.num_estimate} in {estimate}, {result.num_reference} in {reference})")
    if args.json:
        import json

        data = result.as_dict()
        data["units"] = {"translation": LENGTH_UNIT, "rotation": "deg"}
        print(json.dumps(data, indent=2))
        return EXIT_OK
    print(f"estimate:  {estimate}")
    print(f"reference: {reference}")
    matched = "priors, each with its vertex" if args.priors else "poses by vertex id"
    group = _alignment_group(estimate_poses, reference_poses)
    print(f"matched:   {result.num_matched} {matched}; ATE after "
          + (f"a least-squares {group} alignment "
             + ("(Umeyama with scale, each pose's scale applied)" if group == "Sim(3)" else "(Umeyama, no scale)")
             if not args.no_align else "no alignment")
          + f"; RPE between consecutive ids; translations in {LENGTH_UNIT} (the files' unit), rotations in degrees")
    names = ("rmse", "mean", "median", "std", "min", "max")
    print(f"{'':<24}" + "".join(f"{n:>12}" for n in names))
    rows = ((f"ATE translation ({LENGTH_UNIT})", result.ate_translation), ("ATE rotation (deg)", result.ate_rotation),
            (f"RPE translation ({LENGTH_UNIT})", result.rpe_translation), ("RPE rotation (deg)", result.rpe_rotation))
    for label, stats in rows:
        print(f"{label:<24}" + "".join(f"{getattr(stats, n):>12.6f}" for n in names))
    return EXIT_OK


def _against_priors(args):
    """``(keys, EST's poses, keys, the poses its priors give)``, one key per prior (:func:`posegraph.model.priors.prior_poses`)."""
    import numpy as np

    from posegraph.errors import InputError
    from posegraph.io.g2o import read_g2o
    from posegraph.model.priors import prior_poses

    graph = read_g2o(args.estimate, require_edges=False, repair_information=args.repair_information)
    vertex, poses = prior_poses(graph)
    if len(vertex) == 0:
        raise InputError("--priors: the file has no prior lines to compare with", path=args.estimate)
    keys = np.arange(len(vertex))
    return keys, graph.poses[vertex], keys, poses


def _alignment_group(estimate_poses, reference_poses) -> str:
    """``"SE(2)"`` when both trajectories are planar ``(n, 3, 3)`` (:func:`posegraph.analysis.evaluate.evaluate` then
    aligns in the plane), ``"Sim(3)"`` when either carries scales (a similarity alignment), else ``"SE(3)"``."""
    from posegraph.analysis.evaluate import is_similarity_trajectory

    if is_similarity_trajectory(estimate_poses) or is_similarity_trajectory(reference_poses):
        return "Sim(3)"
    return "SE(2)" if estimate_poses.shape[-1] == reference_poses.shape[-1] == 3 else "SE(3)"
