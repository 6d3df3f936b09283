"""Segmentation providers producing label ids: from disk, any ONNX model, a no-weights segmenter.

Providers (each with ``segment(FrameInput) -> (H, W) uint8``): :class:`DiskLabelProvider`,
:class:`DiskMaskProvider` (``bimcap.segmentation.disk``), :class:`OnnxSegmentationProvider`
(``.onnx_seg``), :class:`GeometricSegmenter` (``.geometric``). Heavy imports (cv2, onnxruntime)
happen inside the functions.
"""

from __future__ import annotations

from bimcap.segmentation.base import FrameInput, SegmentationMethod, SegmentationProvider
from bimcap.segmentation.errors import SegmentationError, SegmentationInputError
from bimcap.segmentation.metrics import iou_per_class

__all__ = [
    "FrameInput",
    "SegmentationError",
    "SegmentationInputError",
    "SegmentationMethod",
    "SegmentationProvider",
    "iou_per_class",
]
