"""The fusion / segmentation adapters driving the runner (skipped until those stages are merged)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _frontend_scene import SceneSequence, default_poses

from bimcap.frontend import FrontendConfig, GroundTruthDepthProvider, GroundTruthLabelProvider, run_frontend
from bimcap.frontend.providers import LidarDepthProvider, PlanarDepthRefiner, SegmenterLabelProvider
from bimcap.features import MatchFilterOptions, RequireDepth, SiftOptions
from bimcap.geometry.poses import transform_points

fusion = pytest.importorskip("bimcap.fusion")
if not hasattr(fusion, "project_lidar"):
    pytest.skip("bimcap.fusion is not merged on this branch yet", allow_module_level=True)

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
        seq, CONFIG, seq.gt, depth, labels, workers=1, progress=False, depth_refiner=PlanarDepthRefiner()
    )
    m = res.match_frames
    pa = transform_points(seq.gt[m[:, 0]], res.camera.backproject(res.match_uv[:, :2], res.match_depth[:, 0], distorted=False))
    pb = transform_points(seq.gt[m[:, 1]], res.camera.backproject(res.match_uv[:, 2:], res.match_depth[:, 1], distorted=False))
    err = np.linalg.norm(pa - pb, axis=1)
    assert len(m) > 300 and np.median(err) < 0.05
    floor = transform_points(seq.gt[res.floor_frame], res.floor_p_in_cam)
    assert len(floor) > 100 and np.median(np.abs(floor[:, 2])) < 0.03


def test_lidar_keypoint_depths_match_ground_truth(seq: SceneSequence) -> None:
    """Same images → same keypoints and matches; their LiDAR-completed depths agree with the
    ground-truth depths (checks the projection convention: pinhole pixels, ``cam_from_lidar``)."""
    cfg = dataclasses.replace(
        CONFIG, filters=MatchFilterOptions(max_initial_distance_m=None, require_depth=RequireDepth.NONE)
    )
    gt = run_frontend(seq, cfg, seq.gt, GroundTruthDepthProvider(), GroundTruthLabelProvider(), workers=1, progress=False)
    li = run_frontend(seq, cfg, seq.gt, LidarDepthProvider(), GroundTruthLabelProvider(), workers=1, progress=False)
    assert np.array_equal(gt.match_uv, li.match_uv)
    both = (gt.match_depth > 0) & (li.match_depth > 0)
    assert both.mean() > 0.8
    rel = np.abs(li.match_depth[both] - gt.match_depth[both]) / gt.match_depth[both]
    assert np.median(rel) < 0.01
