"""``bimcap solve-demo``: the solver alone on a generated problem, with before/after pose errors."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "solve-demo"
HELP = "solve a generated room/corridor problem and print the pose errors before and after"
EXAMPLES = ("bimcap solve-demo",
            "bimcap solve-demo --frames 100 --terms G,F,W --weighting paper -o solve/ -v")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_deprecated_option, add_out_argument

    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Generate a synthetic BIM + trajectory + drift (bimcap.optimize.synthetic), "
        "refine it with the C++ Ceres core and print the pose errors and the per-term summary.",
    )
    p.add_argument("--frames", type=int, default=200, help="number of frames (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seed of the problem and its drift (0)")
    p.add_argument("--terms", default="G,F,Ce,W,Co", help="terms to use, e.g. G,F,W (default all)")
    p.add_argument("--weighting", choices=["paper", "robust"], default="robust",
                   help="the solver preset (default robust)")
    geometric = ["point", "reprojection", "landmark"]
    p.add_argument("--geometric", dest="geometric_mode", choices=geometric, default="point",
                   help="the G term's residual (default point)")
    add_deprecated_option(p, "--geometric-mode", "--geometric", "geometric_mode",
                          choices=geometric)
    p.add_argument("--drift", type=float, default=0.03, help="translation drift per frame, m")
    p.add_argument("--drift-yaw", type=float, default=0.3, help="yaw drift per frame, degrees")
    add_out_argument(p, "also write problem.bimcap, refined.tum, summary.json here", type=Path,
                     metavar="DIR")
    p.set_defaults(func=run, output_dirs=["out"])


def run(args: argparse.Namespace) -> int:
    from bimcap.cli import verbosity
    from bimcap.geometry.trajectory import Trajectory, write_tum
    from bimcap.io.atomic import atomic_write_text
    from bimcap.optimize import GeometricMode, SolverOptions, Weighting, solve, write_problem
    from bimcap.optimize.errors import SolverError
    from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors

    synthetic = make_synthetic_problem(
        num_frames=args.frames,
        seed=args.seed,
        drift_translation_sigma=args.drift,
        drift_yaw_sigma_deg=args.drift_yaw,
    )
    options = SolverOptions(
        weighting=Weighting(args.weighting.upper()),
        geometric_mode=GeometricMode(args.geometric_mode.upper()),
        verbose=verbosity(args) > 0,  # -v: Ceres' per-iteration progress
    ).with_terms(args.terms)
    problem = synthetic.problem
    print(
        f"problem: {problem.num_poses} frames, {len(problem.match_frames)} matches, "
        f"{len(problem.floor_frame)} floor / {len(problem.ceiling_frame)} ceiling / "
        f"{len(problem.wall_frame)} wall / {len(problem.column_frame)} column points"
    )
    t0, r0 = pose_errors(problem.poses, synthetic.gt_poses)
    result = solve(problem, options, check=False)
    t1, r1 = pose_errors(result.poses, synthetic.gt_poses)
    print(result.summary.table())
    print(f"pose error (RMSE vs ground truth): before {t0:.4f} m / {r0:.3f} deg, "
          f"after {t1:.4f} m / {r1:.3f} deg")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        write_problem(args.out / "problem.bimcap", problem, options)
        write_tum(args.out / "refined.tum", Trajectory(problem.timestamps, result.poses))
        atomic_write_text(args.out / "summary.json", result.summary.to_json() + "\n")
        print(f"wrote {args.out}/problem.bimcap, refined.tum, summary.json")
    if not result.summary.success:
        raise SolverError(f"solve failed: {result.summary.termination}: {result.summary.message}")
    return 0
