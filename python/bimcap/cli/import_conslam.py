"""``bimcap import-conslam``: turn a ConSLAM ROS1 bag (+ ground truth) into a sequence directory."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "import-conslam"
HELP = "import a ConSLAM ROS1 bag (RGB, VLP-16, camera_info, GT poses) as a sequence"
EXAMPLES = ("bimcap import-conslam data_2.bag --gt gt_poses/ -o seq/",
            "bimcap import-conslam data_2.bag --gt poses_bim.tum --ifc model.ifc --stride 5 "
            "-o seq/")


def register(subparsers: Any) -> None:
    from bimcap.cli import add_out_argument, add_overwrite_argument

    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Read pp_rgb/synced2points, pp_points/synced2rgb and pp_rgb/camera_info with "
        "rosbags (no ROS needed), pair images and scans by nearest header stamp, attach ground "
        "truth (LiDAR poses converted to camera poses with the LiDAR->camera extrinsic) and write "
        "a sequence directory.",
    )
    p.add_argument("bag", type=Path, metavar="BAG", help="the ROS1 .bag file")
    add_out_argument(p, "sequence directory to write", required=True, type=Path, metavar="SEQ")
    p.add_argument(
        "--gt",
        type=Path,
        default=None,
        metavar="DIR_OR_TUM",
        help="ground truth: folder of <microseconds>.txt 4x4 files, or a TUM file",
    )
    p.add_argument(
        "--gt-frame",
        choices=("lidar", "camera"),
        default="lidar",
        help="the sensor the GT poses describe (default lidar, as ConSLAM ships them)",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        default=0.05,
        metavar="S",
        help="max image/scan time difference of a pair (default 0.05 s)",
    )
    p.add_argument(
        "--gt-tolerance",
        type=float,
        default=0.05,
        metavar="S",
        help="max scan/GT time difference (default 0.05 s)",
    )
    p.add_argument("--ifc", type=Path, default=None, metavar="MODEL.ifc",
                   help="IFC file to record in the manifest")
    p.add_argument("--stride", type=int, default=1, help="keep every N-th frame (default 1)")
    p.add_argument("--max-frames", type=int, default=None, help="keep at most N frames")
    p.add_argument(
        "--png-compression",
        type=int,
        default=None,
        choices=range(10),
        metavar="0-9",
        help="PNG compression level of the images (default: OpenCV's)",
    )
    add_overwrite_argument(p, "an existing sequence at -o", deprecated_force=True)
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["bag"])


def run(args: argparse.Namespace) -> int:
    from bimcap.dataset.conslam import ConslamImportOptions, GtFrame, import_conslam
    from bimcap.io.atomic import check_not_input

    inputs = [args.bag] + ([args.gt] if args.gt is not None else [])
    check_not_input(args.out, inputs)
    options = ConslamImportOptions(
        gt_frame=GtFrame(args.gt_frame),
        tolerance_s=args.tolerance,
        gt_tolerance_s=args.gt_tolerance,
        ifc=args.ifc,
        stride=args.stride,
        max_frames=args.max_frames,
        overwrite=args.overwrite,
        png_compression=args.png_compression,
    )
    result = import_conslam(args.bag, args.out, args.gt, options=options)
    seq = result.sequence
    print(
        f"{seq.root}: {result.n_frames} frames from {result.n_images} images / {result.n_scans} "
        f"scans ({result.n_pairs} pairs, max |dt| {result.max_pair_dt_s * 1e3:.1f} ms; "
        f"{result.n_without_gt} without ground truth)"
    )
    print(
        f"  camera {seq.camera.width}x{seq.camera.height} from {result.camera_source}; "
        f"trajectories: {', '.join(seq.poses) or 'none'}"
    )
    return 0
