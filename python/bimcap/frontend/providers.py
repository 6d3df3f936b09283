"""Adapters that plug the fusion and segmentation stages into :func:`run_frontend`.

* :class:`LidarDepthProvider`: the frame's LiDAR scan → ``bimcap.fusion.project_lidar`` (pinhole
  pixels of ``camera.pinhole()``, ``distort=False``: the front end's convention) →
  ``bimcap.fusion.complete_depth`` (linear, classical, ONNX or the paper's hybrid).
* :class:`SegmenterLabelProvider`: any ``bimcap.segmentation`` provider (``segment(FrameInput)``:
  label images from disk, an ONNX model, the no-weights geometric segmenter).
* :class:`PlanarDepthRefiner`: ``bimcap.fusion.smooth_planar_regions`` on floor, ceiling and
  walls, run after the labels (the paper's smoothing).

The ground-truth providers for simulated sequences are
:class:`bimcap.frontend.runner.GroundTruthDepthProvider` and ``GroundTruthLabelProvider``.
All are frozen dataclasses (picklable, and their ``repr`` keys the cache).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bimcap.frontend.errors import FrontendInputError
from bimcap.frontend.runner import FrameContext

_LOG = logging.getLogger(__name__)

#: Fewer LiDAR returns in the image than this (a triangle's worth) and a frame gets no depth.
MIN_RETURNS_IN_VIEW = 3

if TYPE_CHECKING:  # the fusion / segmentation stages are imported only when used
    from bimcap.fusion import CompletionOptions, PlanarSmoothingOptions, ProjectionOptions


@dataclass(frozen=True)
class LidarDepthProvider:
    """Dense depth from the frame's LiDAR scan: projection, then completion.

    The classical methods (linear, classical) fill the whole image, also far from any LiDAR
    return (above and below a VLP-16's ±15° band, where their depth is an extrapolation). For
    them, pixels further than ``support_radius`` × the image diagonal from the nearest projected
    return are set to 0 (unknown), so that no keypoint depth or semantic sample comes from
    there. The learned methods (ONNX, hybrid) are trusted everywhere: predicting depth beyond the
    LiDAR's coverage is what the paper uses CompletionFormer for.

    Attributes
    ----------
    projection: ``bimcap.fusion.ProjectionOptions`` (None: defaults).
    completion: ``bimcap.fusion.CompletionOptions`` (None: linear interpolation).
    support_radius: fraction of the image diagonal (0.03: 39 px at 1032×772, more than half the
        2° ring spacing of a VLP-16 there); None keeps the completed depth everywhere.
    """

    projection: ProjectionOptions | None = None
    completion: CompletionOptions | None = None
    support_radius: float | None = 0.03

    def __post_init__(self) -> None:
        # Concrete defaults, so that the repr (which keys the front-end cache) changes whenever
        # a default does.
        from bimcap.fusion import CompletionOptions, ProjectionOptions

        if self.projection is None:
            object.__setattr__(self, "projection", ProjectionOptions())
        if self.completion is None:
            object.__setattr__(self, "completion", CompletionOptions())

    def __call__(self, ctx: FrameContext) -> NDArray[np.float32]:
        from bimcap.fusion import NanPolicy, complete_depth, project_lidar
        from bimcap.fusion.projection import FusionInputError

        seq = ctx.sequence
        if not hasattr(seq, "load_lidar") or not hasattr(seq, "cam_from_lidar"):
            raise FrontendInputError(
                "the sequence has no LiDAR (load_lidar / cam_from_lidar)", None, "lidar"
            )
        scan = ctx.lidar()
        drop = self.projection is not None and self.projection.nan_policy is NanPolicy.DROP
        xyz = np.asarray(scan)[:, :3] if np.ndim(scan) == 2 else np.zeros((0, 3))
        valid = int(np.isfinite(xyz).all(axis=1).sum())
        if drop and valid == 0:
            # Nothing to project: this frame gets no depth (its samples and keypoints drop out).
            return np.zeros((ctx.camera.height, ctx.camera.width), np.float32)
        try:
            sparse = project_lidar(scan, seq.cam_from_lidar, ctx.camera, self.projection,
                                   distort=False)
        except FusionInputError as exc:
            raise FrontendInputError(_scan_message(len(xyz), valid, exc), _lidar_path(ctx),
                                     f"frames[{ctx.index}].lidar") from None
        ctx.measured_depth = np.asarray(sparse.depth, np.float32)
        empty = np.zeros((ctx.camera.height, ctx.camera.width), np.float32)
        in_view = int(np.count_nonzero(sparse.depth > 0))
        if in_view < MIN_RETURNS_IN_VIEW:
            # The scan misses the image (a view out of a window into the sky, a driver that cut
            # the scan): this frame gets no depth, like a scan of NaNs dropped above.
            _LOG.debug("frame %d: %d LiDAR returns in view, no depth", ctx.index, in_view)
            return empty
        try:
            dense = np.array(complete_depth(sparse, self.completion, image=ctx.image), np.float32)
        except FusionInputError as exc:
            if exc.field != "sparse_depth":
                raise
            # Returns on one line (a single ring across the image) cannot be triangulated.
            _LOG.debug("frame %d: no depth (%s)", ctx.index, exc)
            return empty
        method = getattr(self.completion, "method", None)
        learned = method is not None and method.name in ("ONNX", "HYBRID")
        if self.support_radius is not None and not learned:
            import cv2

            h, w = dense.shape
            far = cv2.distanceTransform((sparse.depth <= 0).astype(np.uint8), cv2.DIST_L2, 5)
            dense[far > self.support_radius * float(np.hypot(w, h))] = 0.0
        return dense


def _lidar_path(ctx: FrameContext) -> Any:
    """The scan file of the frame (None for sequences that are not directories)."""
    frame = ctx.sequence.frames[ctx.index]
    rel = frame.get("lidar") if isinstance(frame, dict) else getattr(frame, "lidar", None)
    root = getattr(ctx.sequence, "root", None)
    return None if rel is None or root is None else Path(root) / str(rel)


def _scan_message(points: int, valid: int, exc: Exception) -> str:
    """What is wrong with a scan, and the command-line option that handles it."""
    hint = ("bimcap refine --lidar-nan drop drops non-finite points and gives a frame without any "
            "valid return no depth")
    if points == 0:
        return f"the LiDAR scan is empty (0 points); {hint}"
    if valid < points:
        return (f"{points - valid} of {points} LiDAR points are NaN/inf"
                f"{' (all of them)' if valid == 0 else ''}; {hint}")
    return f"{exc}"


def _frame_stem(ctx: FrameContext) -> str | None:
    frame = ctx.sequence.frames[ctx.index]
    image = frame.get("image") if isinstance(frame, dict) else getattr(frame, "image", None)
    return None if image is None else Path(str(image)).stem


@dataclass(frozen=True)
class SegmenterLabelProvider:
    """Labels from a ``bimcap.segmentation`` provider.

    Attributes
    ----------
    segmenter: an object with ``segment(FrameInput) -> (H, W) uint8``.
    uses_pose: whether its labels depend on the initial pose (True for the geometric segmenter,
        which takes gravity from it; then a new initial trajectory re-segments). Keys the cache.
    range_noise: whether to measure the range noise of the frame's LiDAR scan
        (:func:`bimcap.segmentation.geometric.scan_range_noise`) and pass it as
        ``FrameInput.range_noise_m`` (the geometric segmenter adapts to it).
    """

    segmenter: Any
    uses_pose: bool = True
    range_noise: bool = False

    def __call__(self, ctx: FrameContext) -> NDArray[np.uint8]:
        from bimcap.segmentation import FrameInput

        noise = None
        if self.range_noise and hasattr(ctx.sequence, "load_lidar"):
            noise = ctx.range_noise_m()

        frame = FrameInput(
            camera=ctx.pinhole,
            image=ctx.image,
            depth=ctx.depth,
            world_from_cam=ctx.world_from_cam,
            stem=_frame_stem(ctx),
            index=ctx.index,
            range_noise_m=noise,
        )
        return np.asarray(self.segmenter.segment(frame), dtype=np.uint8)


@dataclass(frozen=True)
class PlanarDepthRefiner:
    """Smooth the dense depth inside floor and ceiling regions once the labels are known.

    Attributes
    ----------
    options: ``bimcap.fusion.PlanarSmoothingOptions`` (None: defaults).
    seed: RANSAC seed.
    range_noise: whether to measure the range noise of the frame's LiDAR scan
        (:func:`bimcap.segmentation.geometric.scan_range_noise`) and smooth with
        ``options.for_noise(σ)`` (wider plane thresholds above 4.5 cm of noise).
    """

    options: PlanarSmoothingOptions | None = None
    seed: int = 0
    range_noise: bool = True

    def __post_init__(self) -> None:
        from bimcap.fusion import PlanarSmoothingOptions  # concrete defaults key the cache

        if self.options is None:
            object.__setattr__(self, "options", PlanarSmoothingOptions())

    def __call__(self, ctx: FrameContext, labels: NDArray[np.integer]) -> NDArray[np.float32]:
        from bimcap.fusion import smooth_planar_regions

        if ctx.depth is None:
            raise FrontendInputError("no depth to refine", None, f"frames[{ctx.index}].depth")
        options = self.options
        if self.range_noise and options is not None and hasattr(ctx.sequence, "load_lidar"):
            options = options.for_noise(ctx.range_noise_m())
        return np.asarray(
            smooth_planar_regions(ctx.depth, labels, ctx.pinhole, options, seed=self.seed,
                                  measured=ctx.measured_depth),
            np.float32,
        )
