"""``posegraph eval``: trajectory errors (ATE, RPE) of an estimate against a reference."""

from __future__ import annotations

from posegraph.cli.common import EXIT_OK, check_inputs, display_name, repair_option, warn

LENGTH_UNIT = "m"
"""g2o files carry no unit; translations are in the files' own length unit, metres in the standard
datasets (and in evo's reports, whose layout this follows)."""

NAME = "eval"
HELP = "trajectory errors (ATE, RPE) against a reference"
DESCRIPTION = (
    "Absolute trajectory error after a least-squares SE(3) alignment (Umeyama/Horn, no scale) "
    "and relative pose error between consecutive ids, as rmse/mean/median/std/min/max in the way "
    "evo reports them. Poses are matched by vertex id."
)
EXAMPLES = """
  posegraph eval optimised.g2o ground-truth.g2o
  posegraph eval optimised.g2o ground-truth.g2o --json > errors.json"""


def add_arguments(p) -> None:
    p.add_argument("estimate", metavar="EST.g2o", help="estimated poses (- for standard input)")
    p.add_argument("reference", metavar="GT.g2o", help="reference (ground-truth) poses")
    repair_option(p)
    p.add_argument("--no-align", action="store_true", help="compute ATE without aligning the trajectories")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    from posegraph.evaluate import evaluate, read_trajectory

    check_inputs([args.estimate, args.reference])
    estimate_ids, estimate_poses = read_trajectory(args.estimate, repair_information=args.repair_information)
    reference_ids, reference_poses = read_trajectory(args.reference, repair_information=args.repair_information)
    result = evaluate(estimate_ids, estimate_poses, reference_ids, reference_poses,
                      align=not args.no_align, source=args.estimate)
    estimate, reference = display_name(args.estimate), display_name(args.reference)
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
    print(f"matched:   {result.num_matched} poses by vertex id; ATE after "
          + ("a least-squares SE(3) alignment (Umeyama, no scale)" if not args.no_align else "no alignment")
          + f"; RPE between consecutive ids; translations in {LENGTH_UNIT} (the files' unit), rotations in degrees")
    names = ("rmse", "mean", "median", "std", "min", "max")
    print(f"{'':<24}" + "".join(f"{n:>12}" for n in names))
    rows = ((f"ATE translation ({LENGTH_UNIT})", result.ate_translation), ("ATE rotation (deg)", result.ate_rotation),
            (f"RPE translation ({LENGTH_UNIT})", result.rpe_translation), ("RPE rotation (deg)", result.rpe_rotation))
    for label, stats in rows:
        print(f"{label:<24}" + "".join(f"{getattr(stats, n):>12.6f}" for n in names))
    return EXIT_OK
