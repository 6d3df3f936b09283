"""``bimcap evaluate EST.tum GT.tum``: ATE, yaw/pitch/roll RMSE and, given point maps, MME/MPV/NND.

Prints a table; with ``-o`` writes the metrics as JSON atomically (never over an input).
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "evaluate"
HELP = "ATE, yaw/pitch/roll RMSE, MME/MPV/NND of an estimate against the ground truth"
EXAMPLES = ("bimcap evaluate out/refined.tum seq/poses/gt.tum -o metrics.json",
            "bimcap evaluate out/refined.tum seq/poses/gt.tum --map out/map_after.ply "
            "--reference out/map_gt.ply")


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_out_argument
    from bimcap.evaluation.map_metrics import (
        DEFAULT_MIN_NEIGHBOURS,
        DEFAULT_NND_CUTOFF,
        DEFAULT_RADIUS,
        CutoffMode,
    )
    from bimcap.evaluation.metrics import DEFAULT_MAX_DT, AlignMode

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "Trajectory metrics of EST against GT, both TUM files "
            "(timestamp tx ty tz qx qy qz qw, world_from_cam), matched by timestamp. "
            "ATE_pos/ATE_rot equal evo's APE (translation part / rotation angle in degrees); "
            "yaw/pitch/roll: E = R_est R_gt^T split with scipy as_euler('ZYX'). "
            "With --map, MME/MPV of that point map (as the map-metrics package computes them) and, "
            "with --reference, NND against it."
        ),
    )
    p.add_argument("est", type=Path, metavar="EST.tum", help="estimated trajectory")
    p.add_argument("gt", type=Path, metavar="GT.tum", help="ground-truth trajectory")
    p.add_argument(
        "--align",
        choices=[m.value for m in AlignMode],
        default=AlignMode.NONE.value,
        help="Umeyama alignment of EST onto GT before measuring (default: none)",
    )
    p.add_argument(
        "--max-dt",
        type=float,
        default=DEFAULT_MAX_DT,
        metavar="S",
        help=f"timestamp tolerance in seconds for the association (default {DEFAULT_MAX_DT})",
    )
    p.add_argument("--map", type=Path, metavar="EST_MAP.ply", help="point map (PLY) for MME/MPV")
    p.add_argument(
        "--reference",
        type=Path,
        metavar="REF.ply",
        help="reference cloud (PLY: GT map or BIM cloud) for NND; needs --map",
    )
    p.add_argument(
        "--radius",
        type=float,
        default=DEFAULT_RADIUS,
        metavar="M",
        help=f"MME/MPV neighbourhood radius in metres (default {DEFAULT_RADIUS})",
    )
    p.add_argument(
        "--min-neighbours",
        type=int,
        default=DEFAULT_MIN_NEIGHBOURS,
        metavar="K",
        help="use points with more than K neighbours, themselves included "
        f"(default {DEFAULT_MIN_NEIGHBOURS})",
    )
    p.add_argument(
        "--nnd-cutoff",
        type=float,
        default=DEFAULT_NND_CUTOFF,
        metavar="M",
        help=f"NND cut-off in metres (default {DEFAULT_NND_CUTOFF})",
    )
    p.add_argument(
        "--nnd-cutoff-mode",
        choices=[m.value for m in CutoffMode],
        default=CutoffMode.EXCLUDE.value,
        help="points at or beyond the cut-off: excluded (ConSLAM's constrained_RMSE rule), or "
        "counted as the cut-off (default exclude)",
    )
    add_out_argument(p, "write the metrics JSON", type=Path, metavar="metrics.json")
    p.set_defaults(func=run, output_files=["out"], input_paths=["est", "gt", "map", "reference"])


def run(args: argparse.Namespace) -> int:
    from bimcap.evaluation.errors import EvaluationError
    from bimcap.evaluation.map_metrics import (
        CutoffMode,
        map_metrics,
        map_metrics_with_reference,
        read_ply_points,
    )
    from bimcap.evaluation.metrics import AlignMode, evaluate_trajectory
    from bimcap.geometry.trajectory import read_tum
    from bimcap.io.atomic import atomic_write_json, check_not_input

    inputs = [p for p in (args.est, args.gt, args.map, args.reference) if p is not None]
    if args.out is not None:
        check_not_input(args.out, inputs)
    if args.reference is not None and args.map is None:
        raise EvaluationError("--reference needs --map (the map to compare with it)")
    est = read_tum(args.est)
    gt = read_tum(args.gt)
    traj = evaluate_trajectory(est, gt, AlignMode(args.align), args.max_dt)
    result: dict[str, object] = {
        "est": str(args.est),
        "gt": str(args.gt),
        "trajectory": traj.to_dict(),
    }
    print(traj.format_table())
    if args.map is not None:
        points = read_ply_points(args.map)
        if args.reference is not None:
            mm = map_metrics_with_reference(
                points,
                read_ply_points(args.reference),
                str(args.reference),
                args.radius,
                args.min_neighbours,
                args.nnd_cutoff,
                CutoffMode(args.nnd_cutoff_mode),
            )
        else:
            mm = map_metrics(points, args.radius, args.min_neighbours)
        result["map"] = {"path": str(args.map), **mm.to_dict()}
        print(mm.format_table())
    if args.out is not None:
        atomic_write_json(args.out, result)
        print(f"wrote {args.out}")
    return 0
