"""``bimcap import-bag``: turn a ROS1 or ROS2 bag (images + LiDAR clouds) into a sequence."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "import-bag"
HELP = "import a ROS1/ROS2 bag (image + PointCloud2 topics, camera_info or calib) as a sequence"
EXAMPLES = ("bimcap import-bag run.bag --list",
            "bimcap import-bag run.bag --image-topic /cam/image_raw --cloud-topic /velodyne_points "
            "--lidar-extrinsic tf -o seq/",
            "bimcap import-bag rosbag2_dir --image-topic /cam/image/compressed "
            "--cloud-topic /points --calib camchain.yaml --trajectory slam.tum -o seq/")


def register(subparsers: Any) -> None:
    from bimcap.cli.import_options import add_calibration_arguments, add_common_arguments

    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Read a ROS1 .bag or a ROS2 bag (directory, .db3 or .mcap) with rosbags (no "
        "ROS needed), pair each image with the nearest cloud by header stamp, attach a "
        "trajectory if given, and write a sequence directory. The camera comes from a "
        "camera_info topic (default: the camera_info beside the image topic) or --calib; the "
        "LiDAR->camera extrinsic from --lidar-extrinsic (a YAML, or 'tf': the bag's /tf_static) or "
        "the calibration file. "
        "--list prints the bag's topics.",
    )
    p.add_argument("bag", type=Path, metavar="BAG", help="ROS1 .bag, ROS2 bag directory, .db3 "
                   "or .mcap")
    p.add_argument("--list", action="store_true",
                   help="print the bag's topics (type, count) and exit")
    p.add_argument("--image-topic", metavar="T",
                   help="sensor_msgs/Image or CompressedImage topic")
    p.add_argument("--cloud-topic", metavar="T", help="sensor_msgs/PointCloud2 topic")
    p.add_argument("--camera-info-topic", metavar="T",
                   help="sensor_msgs/CameraInfo topic (instead of --calib)")
    add_calibration_arguments(p, required=False, from_tf=True)
    add_common_arguments(p, output_required=False)  # --list needs no -o; run() checks it
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["bag"])


def run(args: argparse.Namespace) -> int:
    from bimcap.cli.import_options import import_options, input_paths
    from bimcap.dataset.bag import BagError, BagTopics, import_bag, list_topics
    from bimcap.io.atomic import check_not_input

    if args.list:
        for topic, msgtype, count in list_topics(args.bag):
            print(f"{topic}\t{msgtype}\t{count}")
        return 0
    missing = [flag for flag, value in (("-o/--out", args.out),
                                        ("--image-topic", args.image_topic),
                                        ("--cloud-topic", args.cloud_topic)) if value is None]
    if missing:
        raise BagError(f"missing {', '.join(missing)} (bimcap import-bag BAG --list shows the "
                       "topics)", args.bag)
    if args.calib is not None and args.camera_info_topic is not None:
        raise BagError("give --camera-info-topic or --calib, not both", args.bag)
    check_not_input(args.out, input_paths(args, "bag"))
    result = import_bag(
        args.bag,
        args.out,
        BagTopics(args.image_topic, args.cloud_topic, args.camera_info_topic),
        calib=args.calib,
        calib_camera=args.calib_camera,
        lidar_extrinsic=args.lidar_extrinsic,
        options=import_options(args, NAME),
    )
    for line in result.summary_lines():
        print(line)
    return 0
