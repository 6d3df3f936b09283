"""The common interface of segmentation providers.

Every provider turns one frame into an (H, W) uint8 image of :class:`bimcap.labels.Label` ids in
the front end's pixels (undistorted pinhole, ``camera.pinhole()``). A provider takes a
:class:`FrameInput` and uses the fields it needs (disk: ``stem``; ONNX: ``image``; geometric:
``depth``, ``camera``, ``world_from_cam``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry import Camera
from bimcap.segmentation.errors import SegmentationInputError

U8 = NDArray[np.uint8]


class SegmentationMethod(Enum):
    DISK_IDS = "disk_ids"  #: bimcap label images from disk
    DISK_MASKS = "disk_masks"  #: BIMCaP-style per-class binary masks from disk
    ONNX = "onnx"  #: any ONNX segmentation model with a class map
    GEOMETRIC = "geometric"  #: the built-in no-weights segmenter


@dataclass(frozen=True)
class FrameInput:
    """What a provider may look at for one frame.

    image: (H, W, 3) uint8 RGB, undistorted. depth: (H, W) float32 dense depth, metres.
    camera: the pinhole camera of both. world_from_cam: (7,) TUM-order initial pose (its
    rotation gives gravity). stem: the frame's file stem (disk providers). index: frame index.
    range_noise_m: the depth sensor's range noise σ (metres) measured on the frame's own scan
    (:func:`bimcap.segmentation.geometric.scan_range_noise`), None when unknown; the geometric
    segmenter widens its normals and plane thresholds when it is well above what its defaults
    are made for.
    """

    camera: Camera
    image: U8 | None = None
    depth: NDArray[np.float32] | None = None
    world_from_cam: NDArray[np.float64] | None = None
    stem: str | None = None
    index: int = 0
    range_noise_m: float | None = None


class SegmentationProvider(Protocol):
    def segment(self, frame: FrameInput) -> U8:
        """(H, W) uint8 label ids of the frame."""
        ...


def check_shape(arr: NDArray[np.generic], camera: Camera, field: str,
                path: str | None = None) -> None:
    if arr.shape[:2] != (camera.height, camera.width):
        raise SegmentationInputError(
            f"shape {arr.shape[:2]} does not match the camera's {camera.height}x{camera.width}",
            path=path,
            field=field,
        )
