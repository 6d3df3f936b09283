"""LiDAR → camera projection and depth completion (interpolation, classical, ONNX, hybrid).

Public API (arrays in, arrays out; the front-end runner pairs files and calls these):
:func:`undistort_image`, :func:`project_lidar` → :class:`SparseDepth`, :func:`pair_by_timestamp`,
:func:`complete_depth` with :class:`CompletionOptions` / :class:`CompletionMethod`,
:func:`fill_nearest` (baseline), :func:`smooth_planar_regions`, :func:`depth_errors`.
"""

from __future__ import annotations

from bimcap.fusion.completion import (
    BlurType,
    ClassicalOptions,
    CompletionMethod,
    CompletionOptions,
    LinearOptions,
    PixelOwner,
    PlanarSmoothing,
    PlanarSmoothingOptions,
    PlaneFitPoints,
    Triangulation,
    complete_classical,
    complete_depth,
    complete_linear,
    fill_nearest,
    smooth_planar_regions,
)
from bimcap.fusion.metrics import DepthErrors, depth_errors
from bimcap.fusion.projection import (
    FusionError,
    FusionInputError,
    NanPolicy,
    ProjectionOptions,
    SparseDepth,
    pair_by_timestamp,
    project_lidar,
    undistort_image,
)

__all__ = [
    "BlurType",
    "ClassicalOptions",
    "CompletionMethod",
    "CompletionOptions",
    "DepthErrors",
    "FusionError",
    "FusionInputError",
    "LinearOptions",
    "NanPolicy",
    "PixelOwner",
    "PlanarSmoothing",
    "PlanarSmoothingOptions",
    "PlaneFitPoints",
    "ProjectionOptions",
    "SparseDepth",
    "Triangulation",
    "complete_classical",
    "complete_depth",
    "complete_linear",
    "depth_errors",
    "fill_nearest",
    "pair_by_timestamp",
    "project_lidar",
    "smooth_planar_regions",
    "undistort_image",
]
