"""The fusion and segmentation providers inside the real front-end runner, on a sequence written
with bimcap.dataset from the box-room scene (raw distorted camera, LiDAR scans, GT poses)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bimcap.fusion.providers import LidarDepthProvider, PlanarSmoothingRefiner
from bimcap.fusion.synthetic import BoxRoom, SpinningLidar, default_camera, render_default_frames
from bimcap.geometry import transform_points
from bimcap.segmentation.frontend_providers import GeometricLabelProvider


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from bimcap.dataset import SequenceWriter

    cam = default_camera(516, 386, distorted=True)
    frames = render_default_frames(3, camera=cam, lidar=SpinningLidar(32, (-25.0, 25.0)), seed=0)
    root = tmp_path_factory.mktemp("seq") / "box"
    with SequenceWriter(root, cam, frames[0].cam_from_lidar) as w:
        for i, f in enumerate(frames):
            scan = np.concatenate([f.points_in_lidar, np.ones((len(f.points_in_lidar), 1))], 1)
            w.add_frame(0.1 * i, f.image, scan, f.labels, f.depth)
        w.add_trajectory("gt", np.stack([f.world_from_cam for f in frames]))
    return root


def test_runner_with_lidar_depth_and_geometric_labels(sequence_dir: Path) -> None:
    from bimcap.dataset import read_sequence
    from bimcap.frontend.runner import run_frontend

    seq = read_sequence(sequence_dir)
    gt = seq.trajectory("gt").poses
    res = run_frontend(
        seq, None, gt, LidarDepthProvider(), GeometricLabelProvider(),
        workers=1, progress=False, depth_refiner=PlanarSmoothingRefiner(),
    )
    room = BoxRoom()
    assert len(res.floor_frame) > 100 and len(res.wall_frame) > 100
    floor_w = transform_points(gt[res.floor_frame], res.floor_p_in_cam)
    assert np.mean(np.abs(floor_w[:, 2]) < 0.05) > 0.95
    if len(res.ceiling_frame):
        ceil_w = transform_points(gt[res.ceiling_frame], res.ceiling_p_in_cam)
        assert np.mean(np.abs(ceil_w[:, 2] - room.height) < 0.05) > 0.9
    wall_w = transform_points(gt[res.wall_frame], res.wall_p_in_cam)
    d_wall = np.min(np.abs(np.stack([wall_w[:, 0], wall_w[:, 0] - room.size_x, wall_w[:, 1], wall_w[:, 1] - room.size_y])), axis=0)
    assert np.mean(d_wall < 0.1) > 0.9
    if len(res.column_frame):
        col_w = transform_points(gt[res.column_frame], res.column_p_in_cam)
        lo = np.array(room.column_center) - np.array(room.column_half) - 0.1
        hi = np.array(room.column_center) + np.array(room.column_half) + 0.1
        assert np.mean(((col_w[:, :2] > lo) & (col_w[:, :2] < hi)).all(1)) > 0.9


def test_providers_with_a_plain_context() -> None:
    f = render_default_frames(1, camera=default_camera(258, 193), seed=3)[0]
    seq = SimpleNamespace(load_lidar=lambda i: f.points_in_lidar, cam_from_lidar=f.cam_from_lidar)
    ctx = SimpleNamespace(sequence=seq, index=0, pinhole=f.camera, image=f.image, depth=None, world_from_cam=f.world_from_cam)
    ctx.depth = LidarDepthProvider()(ctx)
    assert ctx.depth.shape == f.depth.shape and (ctx.depth > 0).mean() > 0.95
    labels = GeometricLabelProvider()(ctx)
    assert labels.shape == f.labels.shape and np.mean(labels == f.labels) > 0.8
    refined = PlanarSmoothingRefiner()(ctx, labels)
    assert refined.shape == f.depth.shape
    assert GeometricLabelProvider.uses_pose
    assert "LidarDepthProvider" in LidarDepthProvider().cache_token

