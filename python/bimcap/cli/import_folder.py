"""``bimcap import-folder``: turn a folder of images + point clouds (or depth) into a sequence."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "import-folder"
HELP = "import a folder of images + PCD/PLY/KITTI .bin clouds (or depth PNGs) as a sequence"
EXAMPLES = ("bimcap import-folder kitti_like/ --calib camera_info.yaml --lidar-extrinsic "
            "extrinsic.yaml -o seq/",
            "bimcap import-folder rgbd/ --calib camera_info.yaml --depth-dir depth "
            "--depth-scale 1000 --lidar-extrinsic identity -o seq/")


def register(subparsers: Any) -> None:
    from bimcap.cli.import_options import add_calibration_arguments, add_common_arguments

    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Pair the images (png/jpg) of DIR/images with the clouds of DIR/clouds "
        "(PCD, PLY, KITTI .bin float32 x y z intensity) by time: DIR/timestamps.txt ('NAME "
        "SECONDS' lines, or one time per line for the i-th image and cloud) or numeric file "
        "names. With --depth-dir, depth PNGs registered to the camera are back-projected into "
        "clouds in the camera frame (RGB-D).",
    )
    p.add_argument("folder", type=Path, metavar="DIR", help="the folder")
    add_calibration_arguments(p, required=True)
    p.add_argument("--images", default=None, metavar="SUBDIR",
                   help="image folder, relative to DIR (default: images/, image/, rgb/, cam0/ "
                   "or DIR)")
    p.add_argument("--clouds", default=None, metavar="SUBDIR",
                   help="cloud folder, relative to DIR (default: clouds/, cloud/, lidar/, "
                   "velodyne/, points/ or DIR)")
    p.add_argument("--depth-dir", default=None, metavar="SUBDIR",
                   help="RGB-D: folder of depth PNGs registered to the camera, used instead of "
                   "clouds")
    p.add_argument("--depth-scale", type=float, default=1000.0, metavar="UNITS_PER_M",
                   help="raw depth units per metre (default 1000: millimetres; TUM RGB-D 5000)")
    p.add_argument("--timestamps", type=Path, default=None, metavar="FILE",
                   help="timestamps file (default DIR/timestamps.txt when present, else the "
                   "file names)")
    add_common_arguments(p)
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["folder"])


def run(args: argparse.Namespace) -> int:
    from bimcap.cli.import_options import import_options, input_paths
    from bimcap.dataset.folder import import_folder
    from bimcap.io.atomic import check_not_input

    check_not_input(args.out, input_paths(args, "folder")
                    + ([args.timestamps] if args.timestamps is not None else []))
    result = import_folder(
        args.folder,
        args.out,
        args.calib,
        calib_camera=args.calib_camera,
        lidar_extrinsic=args.lidar_extrinsic,
        images=args.images,
        clouds=args.clouds,
        depth=args.depth_dir,
        depth_scale=args.depth_scale,
        timestamps=args.timestamps,
        options=import_options(args, NAME),
    )
    for line in result.summary_lines():
        print(line)
    return 0
