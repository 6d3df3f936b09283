"""On-disk sequence directories (manifest, images, LiDAR, labels, poses) and importers.

See :mod:`bimcap.dataset.sequence` for the format. The importers are imported on demand:
:mod:`bimcap.dataset.conslam` (ConSLAM bags), :mod:`bimcap.dataset.bag` (any ROS1/ROS2 bag;
``rosbags``), :mod:`bimcap.dataset.folder` (images + PCD/PLY/KITTI clouds or depth; Open3D), with
their shared parts: :mod:`~bimcap.dataset.ros` (message decoding), :mod:`~bimcap.dataset.pairing`,
:mod:`~bimcap.dataset.importing` (the frame plan, trajectories) and :mod:`~bimcap.dataset.calib`
(ROS camera_info YAML, Kalibr camchains, LiDAR extrinsics).
"""

from __future__ import annotations

from bimcap.dataset.sequence import (
    FORMAT,
    MANIFEST,
    VERSION,
    VLP16,
    FrameInfo,
    LidarInfo,
    Sequence,
    SequenceError,
    SequenceWriter,
    add_trajectory,
    frame_info,
    read_sequence,
    write_frame,
)

__all__ = [
    "FORMAT",
    "MANIFEST",
    "VERSION",
    "VLP16",
    "FrameInfo",
    "LidarInfo",
    "Sequence",
    "SequenceError",
    "SequenceWriter",
    "add_trajectory",
    "frame_info",
    "read_sequence",
    "write_frame",
]
