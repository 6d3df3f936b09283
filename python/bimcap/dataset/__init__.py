"""On-disk sequence directories (manifest, images, LiDAR, labels, poses) and importers (ConSLAM).

See :mod:`bimcap.dataset.sequence` for the format. The ConSLAM importer lives in
:mod:`bimcap.dataset.conslam` (imported on demand: it needs ``rosbags``).
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
