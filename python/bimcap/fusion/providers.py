"""Depth providers and the floor/ceiling refiner in the form ``bimcap.frontend.run_frontend``
takes: picklable dataclasses called with the runner's ``FrameContext`` (duck-typed here, so that
fusion does not import the front end: ``ctx.sequence.load_lidar(i)``, ``ctx.sequence.cam_from_lidar``,
``ctx.index``, ``ctx.pinhole``, ``ctx.image``, ``ctx.depth``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.fusion.completion import (
    CompletionMethod,
    CompletionOptions,
    PlanarSmoothingOptions,
    complete_depth,
    smooth_planar_regions,
)
from bimcap.fusion.projection import ProjectionOptions, project_lidar


def _file_token(path: str | Path | None) -> str:
    if path is None:
        return ""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return f"{p}:missing"
    return f"{p.resolve()}:{st.st_size}:{st.st_mtime_ns}"


@dataclass(frozen=True)
class LidarDepthProvider:
    """Dense depth of a frame from its own LiDAR scan: :func:`project_lidar` into the undistorted
    pinhole image, then :func:`complete_depth` (CLASSICAL by default; ONNX/HYBRID use the
    undistorted RGB image)."""

    completion: CompletionOptions = field(default_factory=lambda: CompletionOptions(CompletionMethod.CLASSICAL))
    projection: ProjectionOptions = field(default_factory=ProjectionOptions)

    @property
    def cache_token(self) -> str:
        model = self.completion.onnx.model_path if self.completion.onnx is not None else None
        return f"LidarDepthProvider:{self!r}:{_file_token(model)}"

    def __call__(self, ctx: Any) -> NDArray[np.float32]:
        points = np.asarray(ctx.sequence.load_lidar(ctx.index))
        sparse = project_lidar(points, ctx.sequence.cam_from_lidar, ctx.pinhole, self.projection)
        return complete_depth(sparse, self.completion, ctx.image)


@dataclass(frozen=True)
class PlanarSmoothingRefiner:
    """The paper's floor/ceiling smoothing as a ``depth_refiner(ctx, labels)``."""

    options: PlanarSmoothingOptions = field(default_factory=PlanarSmoothingOptions)
    seed: int = 0

    def __call__(self, ctx: Any, labels: NDArray[np.integer]) -> NDArray[np.float32]:
        return smooth_planar_regions(ctx.depth, labels, ctx.pinhole, self.options, self.seed)
