"""``bimcap drift``: make a drifted initial trajectory (the paper's synthetic SLAM output).

Reads the sequence's ground truth (``poses/gt.tum``), writes ``poses/init.tum`` (listed in the
manifest) and ``poses/init.drift.json`` (seed, σs, model, preset, calibration scales, resulting
ATE). ``gt.tum`` is never overwritten; an existing ``init.tum`` only with ``--overwrite``
(``--force``: deprecated alias). With
``-o FILE.tum`` the trajectory goes there instead (and ``FILE.drift.json`` beside it) and the
sequence is left untouched.

``--slam-frame`` then moves the drifted trajectory into a random SLAM frame (what a real SLAM
system writes: yaw uniform in 0-360°, x/y within ±50 m, z within ±5 m, seeded by ``--seed``);
the true transform is ``slam_frame.slam_from_world`` in the ``.drift.json`` (``bimcap refine
--global-align`` has to find it).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "drift"
HELP = "write a drifted initial trajectory poses/init.tum from the ground truth"
EXAMPLES = ("bimcap drift seq/ --preset exp2 --seed 1",
            "bimcap drift seq/ --preset exp1 --seed 1 --slam-frame -o slam.tum",
            "bimcap drift seq/ --mode slam --sigma-t 0.02 --name init_slam")


def register(subparsers: Any) -> None:
    from bimcap.cli import add_out_argument, add_overwrite_argument
    from bimcap.sim.drift import PRESETS, DriftModel

    presets = ", ".join(f"{k} ({v.description})" for k, v in PRESETS.items())
    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Sample the paper's drift model (translation random walk, pitch/yaw offsets) "
        "or a smooth SLAM-like drift on a sequence's ground truth. Presets: " + presets + ". "
        "Preset sigmas are rescaled so that the ATE hits the preset's target exactly.",
    )
    p.add_argument("sequence", type=Path, metavar="SEQ", help="sequence directory")
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default=None,
        help="paper experiment to imitate (default: none, give sigmas)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--mode",
        choices=[m.value for m in DriftModel],
        default=None,
        help="drift model (default: paper)",
    )
    p.add_argument("--sigma-t", type=float, default=None, help="translation step sigma, metres")
    p.add_argument("--sigma-pitch-deg", type=float, default=None, help="pitch sigma, degrees")
    p.add_argument("--sigma-yaw-deg", type=float, default=None, help="yaw sigma, degrees")
    p.add_argument(
        "--target-ate-pos",
        type=float,
        default=None,
        metavar="M",
        help="rescale translation drift to this ATE_pos (metres)",
    )
    p.add_argument(
        "--target-ate-rot",
        type=float,
        default=None,
        metavar="DEG",
        help="rescale rotation drift to this ATE_rot (degrees)",
    )
    p.add_argument("--no-z", action="store_true", help="keep the height: planar translation walk")
    p.add_argument("--gt", default="gt", help="name of the ground-truth trajectory (default gt)")
    p.add_argument("--name", default="init", help="name of the trajectory to write (default init)")
    add_out_argument(p, "write here instead of into the sequence", type=Path, metavar="FILE.tum")
    p.add_argument(
        "--slam-frame",
        action="store_true",
        help="after the drift, move the trajectory into a random SLAM frame (yaw 0-360 deg, "
        "x/y within +-50 m, z within +-5 m; seeded by --seed); the true slam_from_world goes "
        "into the .drift.json",
    )
    p.add_argument("--slam-xy-range", type=float, default=None, metavar="M",
                   help="with --slam-frame: half-width of the x/y offset (default 50 m)")
    p.add_argument("--slam-z-range", type=float, default=None, metavar="M",
                   help="with --slam-frame: half-width of the z offset (default 5 m)")
    add_overwrite_argument(p, "an existing output trajectory", deprecated_force=True)
    p.set_defaults(func=run, output_files=["out"])


def _params(args: argparse.Namespace) -> Any:
    from bimcap.sim.drift import DriftParams

    overrides: dict[str, Any] = {}
    for flag, name in (
        ("sigma_t", "sigma_t"),
        ("sigma_pitch_deg", "sigma_pitch_deg"),
        ("sigma_yaw_deg", "sigma_yaw_deg"),
        ("target_ate_pos", "target_ate_pos_m"),
        ("target_ate_rot", "target_ate_rot_deg"),
        ("mode", "mode"),
    ):
        value = getattr(args, flag)
        if value is not None:
            overrides[name] = value
    if args.no_z:
        overrides["drift_z"] = False
    if args.preset is not None:
        return DriftParams.from_preset(args.preset, args.seed, **overrides)
    return DriftParams(seed=args.seed, **overrides)


def run(args: argparse.Namespace) -> int:
    from bimcap.dataset import SequenceError, add_trajectory, read_sequence
    from bimcap.geometry.trajectory import write_tum
    from bimcap.io.atomic import atomic_write_json, check_not_input
    from bimcap.sim.drift import (
        SLAM_FRAME_XY_RANGE_M,
        SLAM_FRAME_Z_RANGE_M,
        DriftError,
        apply_drift,
        to_slam_frame,
    )

    seq = read_sequence(args.sequence)
    if args.name == args.gt:
        raise SequenceError(
            "the output trajectory must not be the ground truth", seq.root, "--name"
        )
    gt_path = seq.trajectory_path(args.gt)
    gt = seq.trajectory(args.gt)
    params = _params(args)
    if not args.slam_frame and (args.slam_xy_range is not None or args.slam_z_range is not None):
        raise DriftError("needs --slam-frame", field="--slam-xy-range/--slam-z-range")
    result = apply_drift(gt, params)
    header = (
        f"world_from_cam, bimcap drift: mode {params.mode.value}, preset {params.preset}, "
        f"seed {params.seed}, ATE_pos {result.ate_pos:.6f} m, ATE_rot {result.ate_rot:.6f} deg"
    )
    out_traj = result.init
    slam = None
    if args.slam_frame:
        slam = to_slam_frame(
            result.init,
            args.seed,
            SLAM_FRAME_XY_RANGE_M if args.slam_xy_range is None else args.slam_xy_range,
            SLAM_FRAME_Z_RANGE_M if args.slam_z_range is None else args.slam_z_range,
        )
        out_traj = slam.trajectory
        header = header.replace("world_from_cam", "slam_from_cam (SLAM frame)", 1)
    if args.out is None:
        tum = add_trajectory(seq, args.name, out_traj, header=header, overwrite=args.overwrite)
    else:
        tum = args.out
        check_not_input(tum, [gt_path, seq.manifest_path])
        if tum.exists() and not args.overwrite:
            raise SequenceError("already exists (use --overwrite to replace it)", tum)
        write_tum(tum, out_traj, header=header)
    info = tum.with_name(tum.name.removesuffix(".tum") + ".drift.json")
    check_not_input(info, [gt_path, seq.manifest_path])
    doc = result.to_dict()
    doc["sequence"] = str(seq.root)
    doc["gt"] = str(gt_path)
    doc["output"] = str(tum)
    doc["slam_frame"] = None if slam is None else slam.to_dict()
    atomic_write_json(info, doc)
    print(
        f"{tum}: {len(result.init)} poses, ATE_pos {result.ate_pos:.3f} m, "
        f"ATE_rot {result.ate_rot:.2f} deg (mode {params.mode.value}, preset {params.preset}, "
        f"seed {params.seed}, scale_t {result.scale_t:.4g}, scale_rot {result.scale_rot:.4g})"
    )
    if slam is not None:
        print(
            f"  in a SLAM frame: yaw {slam.yaw_deg:.1f} deg, translation "
            f"({slam.translation_m[0]:.2f}, {slam.translation_m[1]:.2f}, "
            f"{slam.translation_m[2]:.2f}) m (the ATE above is before that motion)"
        )
    print(f"  parameters and ATE: {info}")
    return 0
