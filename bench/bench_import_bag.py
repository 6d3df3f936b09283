"""import-bag throughput: a ROS2 (or ROS1) bag of raw RGB images and VLP-16-sized clouds,
written here with rosbags, imported with ``bimcap.dataset.bag.import_bag``.

Usage: PYTHONPATH=python python bench/bench_import_bag.py [--frames 60] [--scale 0.5] [--ros1]
       [--stride 1]

Prints the bag size, the time of pass 1 (header stamps only: the bag is read but no image is
deserialised) and of the whole import (pass 2 decodes and writes the planned frames; PNG
encoding dominates, --png-compression 1 in the CLI halves it).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

from bimcap.dataset.bag import BagTopics, import_bag
from bimcap.dataset.conslam import CONSLAM_CAMERA
from bimcap.dataset.importing import ImportOptions


def _write(path: Path, ros2: bool, frames: int, w: int, h: int) -> None:
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    ty = ts.types
    ser = ts.serialize_cdr if ros2 else ts.serialize_ros1
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (h, w, 3), np.uint8).ravel()
    cloud = rng.normal(0, 5, (28_800, 4)).astype(np.float32)
    fields = [ty["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7, count=1)
              for k, n in enumerate(("x", "y", "z", "intensity"))]
    cloud_bytes = np.frombuffer(cloud.tobytes(), np.uint8)

    def header(t_ns: int) -> object:
        stamp = ty["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        extra = {} if ros2 else {"seq": 0}
        return ty["std_msgs/msg/Header"](stamp=stamp, frame_id="f", **extra)

    writer = Writer2(path, version=9) if ros2 else Writer1(path)
    with writer:
        c_img = writer.add_connection("/cam/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        c_pts = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        for k in range(frames):
            t = 1_700_000_000 * 10**9 + k * 100_000_000
            img = ty["sensor_msgs/msg/Image"](header=header(t), height=h, width=w,
                                              encoding="rgb8", is_bigendian=0, step=3 * w,
                                              data=image)
            writer.write(c_img, t, bytes(ser(img, "sensor_msgs/msg/Image")))
            pc = ty["sensor_msgs/msg/PointCloud2"](header=header(t + 2_000_000), height=1,
                                                   width=len(cloud), fields=fields,
                                                   is_bigendian=False, point_step=16,
                                                   row_step=16 * len(cloud), data=cloud_bytes,
                                                   is_dense=True)
            writer.write(c_pts, t + 2_000_000, bytes(ser(pc, "sensor_msgs/msg/PointCloud2")))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--ros1", action="store_true")
    args = ap.parse_args()
    cam = CONSLAM_CAMERA.scaled(args.scale)
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / ("rec.bag" if args.ros1 else "rec")
        _write(bag, not args.ros1, args.frames, cam.width, cam.height)
        size = sum(f.stat().st_size for f in ([bag] if bag.is_file() else bag.iterdir()))
        (Path(tmp) / "ext.yaml").write_text("T_cam_lidar: [1,0,0,0, 0,1,0,0, 0,0,1,0]\n")
        (Path(tmp) / "cam.yaml").write_text(
            f"image_width: {cam.width}\nimage_height: {cam.height}\n"
            f"camera_matrix: {{data: {cam.K.ravel().tolist()}}}\n"
            f"distortion_model: plumb_bob\ndistortion_coefficients: {{data: {list(cam.dist)}}}\n")
        marks: dict[str, float] = {}
        t0 = time.perf_counter()

        def progress(stage: str, done: int, total: int) -> None:
            if done == total:
                marks[stage] = time.perf_counter() - t0

        res = import_bag(bag, Path(tmp) / "seq", BagTopics("/cam/image_raw", "/points"),
                         calib=Path(tmp) / "cam.yaml", lidar_extrinsic=Path(tmp) / "ext.yaml",
                         options=ImportOptions(stride=args.stride, progress=progress))
        total = time.perf_counter() - t0
    kind = "ROS1" if args.ros1 else "ROS2"
    print(f"{kind} bag: {args.frames} images {cam.width}x{cam.height} + clouds of 28800 points, "
          f"{size / 1e6:.0f} MB")
    print(f"pass 1 (stamps): {marks['index']:.2f} s ({size / 1e6 / marks['index']:.0f} MB/s); "
          f"whole import: {total:.2f} s, {res.n_frames} frames, "
          f"{1e3 * (total - marks['index']) / max(res.n_frames, 1):.0f} ms/frame written")


if __name__ == "__main__":
    main()
