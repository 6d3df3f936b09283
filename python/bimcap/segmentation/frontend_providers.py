"""Label providers in the form ``bimcap.frontend.run_frontend`` takes: picklable dataclasses
called with the runner's ``FrameContext`` (duck-typed: ``ctx.index``, ``ctx.pinhole``,
``ctx.image``, ``ctx.depth``, ``ctx.world_from_cam``, ``ctx.undistorter.nearest``), returning
(H, W) uint8 label ids in undistorted pinhole pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bimcap.labels import Label
from bimcap.segmentation.base import U8, FrameInput
from bimcap.segmentation.disk import BIMCAP_MASK_SUFFIXES, read_class_masks, read_label_image
from bimcap.segmentation.errors import SegmentationInputError
from bimcap.segmentation.geometric import GeometricOptions, segment_geometric
from bimcap.segmentation.onnx_seg import OnnxSegmentationOptions, OnnxSegmentationProvider


def _undistort(ctx: Any, labels: U8, raw: bool) -> U8:
    if not raw:
        return labels
    return np.asarray(ctx.undistorter.nearest(labels), dtype=np.uint8)


@dataclass(frozen=True)
class GeometricLabelProvider:
    """The no-weights segmenter on ``ctx.depth`` with gravity from ``ctx.world_from_cam``."""

    options: GeometricOptions = field(default_factory=GeometricOptions)
    uses_pose = True  # the runner keys its cache on the initial pose for this provider

    def __call__(self, ctx: Any) -> U8:
        if ctx.depth is None:
            raise SegmentationInputError("the geometric segmenter needs the depth provider's output", field="depth")
        return segment_geometric(ctx.depth, ctx.pinhole, ctx.world_from_cam, self.options)


@dataclass(frozen=True)
class OnnxLabelProvider:
    """An ONNX segmentation model on the undistorted RGB image."""

    options: OnnxSegmentationOptions

    @property
    def cache_token(self) -> str:
        p = Path(self.options.model_path)
        st = p.stat() if p.is_file() else None
        return f"OnnxLabelProvider:{self!r}:{None if st is None else (st.st_size, st.st_mtime_ns)}"

    def __call__(self, ctx: Any) -> U8:
        return OnnxSegmentationProvider(self.options).segment(FrameInput(ctx.pinhole, image=ctx.image))


@dataclass(frozen=True)
class DiskLabelImageProvider:
    """Label-id PNGs ``{directory}/{stem_format.format(index=i)}.png``; ``raw``: they are in the raw
    (distorted) image and are undistorted with nearest-neighbour sampling."""

    directory: Path
    stem_format: str = "{index:06d}"
    raw: bool = True

    def __call__(self, ctx: Any) -> U8:
        path = Path(self.directory) / f"{self.stem_format.format(index=ctx.index)}.png"
        return _undistort(ctx, read_label_image(path, ctx.pinhole), self.raw)


@dataclass(frozen=True)
class DiskMaskLabelProvider:
    """BIMCaP per-class masks ``{directory}/{stem}_{wall,floor,ceiling,columns}.png`` with
    ``stem = stem_format.format(index=i)``; ``raw`` as in :class:`DiskLabelImageProvider`."""

    directory: Path
    stem_format: str = "frame-{index:06d}"
    raw: bool = True
    background: Label = Label.UNKNOWN
    missing_ok: bool = False
    suffixes: tuple[tuple[Label, str], ...] = tuple(BIMCAP_MASK_SUFFIXES.items())

    def __call__(self, ctx: Any) -> U8:
        labels = read_class_masks(
            self.directory,
            self.stem_format.format(index=ctx.index),
            ctx.pinhole,
            dict(self.suffixes),
            background=self.background,
            missing_ok=self.missing_ok,
        )
        return _undistort(ctx, labels, self.raw)
