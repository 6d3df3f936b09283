"""The fusion / segmentation adapters driving the runner."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from _frontend_scene import TEST_CAMERA, SceneSequence, default_poses
from bimcap.features import MatchFilterOptions, RequireDepth, SiftOptions
from bimcap.frontend import (
    FrontendConfig,
    GroundTruthDepthProvider,
    GroundTruthLabelProvider,
    run_frontend,
)
from bimcap.frontend.providers import LidarDepthProvider, PlanarDepthRefiner, SegmenterLabelProvider
from bimcap.geometry.poses import transform_points

CONFIG = FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2)


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> SceneSequence:
    return SceneSequence.write(tmp_path_factory.mktemp("lidar"), poses=default_poses(3), lidar=True)


def test_lidar_depth_and_geometric_labels(seq: SceneSequence) -> None:
    """LiDAR → completion → geometric segmentation → planar smoothing, end to end: matches still
    agree with ground truth, and floor samples lie on the floor."""
    from bimcap.fusion import CompletionMethod, CompletionOptions
    from bimcap.segmentation.geometric import GeometricSegmenter

    depth = LidarDepthProvider(completion=CompletionOptions(method=CompletionMethod.LINEAR))
    labels = SegmenterLabelProvider(GeometricSegmenter())
    res = run_frontend(
        seq, CONFIG, seq.gt, depth, labels, workers=1, progress=False,
        depth_refiner=PlanarDepthRefiner(),
    )
    m = res.match_frames
    pa = transform_points(seq.gt[m[:, 0]], res.camera.backproject(
        res.match_uv[:, :2], res.match_depth[:, 0], distorted=False))
    pb = transform_points(seq.gt[m[:, 1]], res.camera.backproject(
        res.match_uv[:, 2:], res.match_depth[:, 1], distorted=False))
    err = np.linalg.norm(pa - pb, axis=1)
    assert len(m) > 300 and np.median(err) < 0.05
    floor = transform_points(seq.gt[res.floor_frame], res.floor_p_in_cam)
    assert len(floor) > 100 and np.median(np.abs(floor[:, 2])) < 0.03


def test_lidar_keypoint_depths_match_ground_truth(seq: SceneSequence) -> None:
    """Same images → same keypoints and matches; their LiDAR-completed depths agree with the
    ground-truth depths (checks the projection convention: pinhole pixels, ``cam_from_lidar``)."""
    cfg = dataclasses.replace(
        CONFIG,
        filters=MatchFilterOptions(max_initial_distance_m=None, require_depth=RequireDepth.NONE),
    )
    gt = run_frontend(seq, cfg, seq.gt, GroundTruthDepthProvider(), GroundTruthLabelProvider(),
                      workers=1, progress=False)
    li = run_frontend(seq, cfg, seq.gt, LidarDepthProvider(), GroundTruthLabelProvider(),
                      workers=1, progress=False)
    assert np.array_equal(gt.match_uv, li.match_uv)
    both = (gt.match_depth > 0) & (li.match_depth > 0)
    assert both.mean() > 0.8
    rel = np.abs(li.match_depth[both] - gt.match_depth[both]) / gt.match_depth[both]
    assert np.median(rel) < 0.01


def test_lidar_depth_only_where_the_lidar_supports_it(seq: SceneSequence) -> None:
    """Pixels far from every LiDAR return get no depth (classical methods extrapolate there)."""
    import cv2

    from bimcap.frontend.runner import FrameContext, Undistorter
    from bimcap.fusion import project_lidar

    und = Undistorter(TEST_CAMERA)
    ctx = FrameContext(seq, 0, TEST_CAMERA, und.pinhole, und.image(seq.load_image(0)), und,
                       seq.gt[0])
    sparse = project_lidar(seq.load_lidar(0), seq.cam_from_lidar, TEST_CAMERA, distort=False)
    dist = cv2.distanceTransform((sparse.depth <= 0).astype(np.uint8), cv2.DIST_L2, 5)
    radius = 0.01 * np.hypot(320, 240)
    masked = LidarDepthProvider(support_radius=0.01)(ctx)
    full = LidarDepthProvider(support_radius=None)(ctx)
    assert (dist > radius).any() and (masked[dist > radius] == 0).all()
    near = dist <= radius
    assert np.array_equal(masked[near], full[near])


class _ScanBehind:
    """``seq`` whose LiDAR scans lie behind the camera (a view out of a window into the sky)."""

    def __init__(self, seq: SceneSequence, keep: int) -> None:
        self._seq, self._keep = seq, keep
        self.cam_from_lidar = seq.cam_from_lidar

    def __getattr__(self, name: str) -> object:
        return getattr(self._seq, name)

    def load_lidar(self, i: int) -> np.ndarray:
        from bimcap.geometry.poses import invert, transform_points

        scan = np.array(self._seq.load_lidar(i), dtype=np.float64)
        p_in_cam = transform_points(np.asarray(self.cam_from_lidar), scan[:, :3])
        behind = p_in_cam.copy()
        behind[:, 2] = -np.abs(behind[:, 2]) - 0.01  # all behind the image plane
        keep = np.argsort(p_in_cam[:, 2])[-self._keep:] if self._keep else np.array([], int)
        behind[keep] = p_in_cam[keep]
        scan[:, :3] = transform_points(invert(np.asarray(self.cam_from_lidar)), behind)
        return scan


@pytest.mark.parametrize("keep", [0, 2])
def test_a_scan_that_misses_the_image_gives_no_depth(seq: SceneSequence, keep: int) -> None:
    """A frame whose scan has (almost) no return in the image gets an empty depth map, not an
    error that stops the run (SampleHouse4's 250-frame walk, frame 168: 23 106 returns, none in
    view, looking out of a window)."""
    from bimcap.frontend.runner import FrameContext, Undistorter
    from bimcap.fusion import project_lidar

    blind = _ScanBehind(seq, keep)
    und = Undistorter(TEST_CAMERA)
    ctx = FrameContext(blind, 0, TEST_CAMERA, und.pinhole, und.image(seq.load_image(0)), und,
                       seq.gt[0])
    sparse = project_lidar(blind.load_lidar(0), seq.cam_from_lidar, TEST_CAMERA, distort=False)
    assert int((sparse.depth > 0).sum()) <= keep  # the scan misses the image
    depth = LidarDepthProvider()(ctx)
    assert depth.shape == (TEST_CAMERA.height, TEST_CAMERA.width) and not depth.any()


@dataclasses.dataclass(frozen=True)
class _PushedOff:
    """A depth refiner that puts the left third of every frame 10 cm further (a plane fitted
    off the wall there)."""

    def __call__(self, ctx: object, labels: np.ndarray) -> np.ndarray:
        depth = np.array(ctx.depth, np.float32)  # type: ignore[attr-defined]
        third = depth.shape[1] // 3
        depth[:, :third] = np.where(depth[:, :third] > 0, depth[:, :third] + 0.10, 0.0)
        return depth


def test_keypoints_where_the_refined_depth_left_the_returns_get_no_depth(
        seq: SceneSequence) -> None:
    """The front end drops a keypoint's depth where the depth map left the LiDAR returns around
    it (``DepthLookupOptions.max_support_z``): G then keeps the match's other direction
    (gen-small-s3 hard frame 56, docs/generalization.md). Elsewhere the depths stay."""
    from bimcap.features import DepthLookupOptions

    cfg = dataclasses.replace(
        CONFIG,
        filters=MatchFilterOptions(max_initial_distance_m=None, require_depth=RequireDepth.NONE),
    )
    off = dataclasses.replace(cfg, depth_lookup=DepthLookupOptions(max_support_z=None))
    runs = [run_frontend(seq, c, seq.gt, LidarDepthProvider(), GroundTruthLabelProvider(),
                         workers=1, progress=False, depth_refiner=_PushedOff())
            for c in (cfg, off)]
    assert np.array_equal(runs[0].match_uv, runs[1].match_uv)
    third = TEST_CAMERA.width / 3
    for side in (0, 1):
        u = runs[0].match_uv[:, 2 * side]
        pushed, kept = u < third - 30, u > third + 30
        now, before = runs[0].match_depth[:, side], runs[1].match_depth[:, side]
        assert pushed.sum() > 20 and (before[pushed] > 0).mean() > 0.8
        assert (now[pushed] == 0).mean() > 0.95
        assert (now[kept] == before[kept]).mean() > 0.95
