"""The options ``import-bag`` and ``import-folder`` share (not a sub-command itself): pairing,
calibration, trajectory, thinning and output settings."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_calibration_arguments(p: argparse.ArgumentParser, required: bool,
                              from_tf: bool = False) -> None:
    """``--calib FILE``, ``--calib-camera camN``, ``--lidar-extrinsic FILE|identity`` (``|tf``
    for bags)."""
    p.add_argument("--calib", type=Path, default=None, required=required, metavar="FILE",
                   help="camera calibration: a ROS camera_info YAML or a Kalibr camchain "
                   "(pinhole-radtan)")
    p.add_argument("--calib-camera", default="cam0", metavar="camN",
                   help="which camera of a Kalibr camchain (default cam0)")
    tf = ("; 'tf' to compose it along the bag's /tf_static from the cloud's frame_id to the "
          "image's (an optical frame)") if from_tf else ""
    p.add_argument("--lidar-extrinsic", default=None,
                   metavar="FILE|identity" + ("|tf" if from_tf else ""),
                   help="LiDAR->camera extrinsic: a YAML with T_cam_lidar, T_lidar_cam or "
                   "T_imu_lidar (with a camchain's T_cam_imu); 'identity' when the clouds are in "
                   f"the camera frame{tf}; not needed when the calibration file has one")


def add_common_arguments(p: argparse.ArgumentParser, output_required: bool = True) -> None:
    """Output, pairing tolerance, trajectory, thinning, manifest and overwrite options."""
    from bimcap.cli import add_out_argument, add_overwrite_argument

    add_out_argument(p, "sequence directory to write", required=output_required, type=Path,
                     metavar="SEQ")
    p.add_argument("--tolerance", type=float, default=0.05, metavar="S",
                   help="max image/cloud time difference of a pair (default 0.05 s)")
    p.add_argument("--trajectory", type=Path, default=None, metavar="FILE",
                   help="poses to attach to the frames (see --trajectory-format)")
    p.add_argument("--trajectory-format", choices=("tum", "kitti", "colmap"), default="tum",
                   help="tum: 'timestamp tx ty tz qx qy qz qw'; kitti: 12 numbers per line, one "
                   "pose per image in time order (or with --trajectory-times); colmap: "
                   "images.txt, matched by image name (default tum)")
    p.add_argument("--trajectory-times", type=Path, default=None, metavar="FILE",
                   help="KITTI times.txt: one time in seconds per pose")
    p.add_argument("--trajectory-sensor", choices=("camera", "lidar"), default="camera",
                   help="whose poses the trajectory holds; LiDAR poses are turned into camera "
                   "poses with the extrinsic (default camera)")
    p.add_argument("--trajectory-name", default="init", metavar="NAME",
                   help="the sequence trajectory it becomes: init (poses to refine, the "
                   "default) or gt (ground truth)")
    p.add_argument("--trajectory-tolerance", type=float, default=0.05, metavar="S",
                   help="max frame/pose time difference when matching by time (default 0.05 s)")
    p.add_argument("--lidar-model", default="unknown", metavar="NAME",
                   help="the LiDAR's name in the manifest (e.g. VLP-16, Ouster OS1-64)")
    p.add_argument("--ifc", type=Path, default=None, help="IFC file to record in the manifest")
    p.add_argument("--stride", type=int, default=1, help="keep every N-th frame (default 1)")
    p.add_argument("--max-frames", type=int, default=None, help="keep at most N frames")
    p.add_argument("--png-compression", type=int, default=None, choices=range(10),
                   metavar="0-9", help="PNG compression level of the images (default: OpenCV's)")
    add_overwrite_argument(p, "an existing sequence at -o")


def import_options(args: argparse.Namespace, command: str) -> Any:
    """The :class:`~bimcap.dataset.importing.ImportOptions` of the parsed arguments."""
    from bimcap.dataset.importing import ImportOptions, PoseSensor, TrajectoryInput
    from bimcap.geometry.pose_formats import PoseFormat
    from bimcap.progress import StageProgress

    traj = None
    if args.trajectory is not None:
        traj = TrajectoryInput(path=args.trajectory, fmt=PoseFormat(args.trajectory_format),
                               times=args.trajectory_times,
                               sensor=PoseSensor(args.trajectory_sensor),
                               name=args.trajectory_name, tolerance_s=args.trajectory_tolerance)
    return ImportOptions(tolerance_s=args.tolerance, trajectory=traj, stride=args.stride,
                         max_frames=args.max_frames, lidar_model=args.lidar_model, ifc=args.ifc,
                         overwrite=args.overwrite, png_compression=args.png_compression,
                         progress=StageProgress())


def input_paths(args: argparse.Namespace, first: str) -> list[Any]:
    """The paths the command reads (none may be the output)."""
    names = (first, "calib", "trajectory", "trajectory_times")
    paths = [getattr(args, n, None) for n in names]
    if args.lidar_extrinsic not in (None, "identity", "tf"):
        paths.append(Path(args.lidar_extrinsic))
    return [p for p in paths if p is not None]
