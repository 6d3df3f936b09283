"""Fusion and segmentation inside the real front-end runner (through bimcap.frontend.providers),
on a sequence written with bimcap.dataset from the box-room scene (raw distorted camera, LiDAR
scans, GT poses)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimcap.fusion import CompletionMethod, CompletionOptions
from bimcap.fusion.synthetic import BoxRoom, SpinningLidar, default_camera, render_default_frames
from bimcap.geometry import transform_points
from bimcap.segmentation.geometric import GeometricSegmenter


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
    from bimcap.frontend.providers import (
        LidarDepthProvider,
        PlanarDepthRefiner,
        SegmenterLabelProvider,
    )
    from bimcap.frontend.runner import run_frontend

    seq = read_sequence(sequence_dir)
    gt = seq.trajectory("gt").poses
    depth = LidarDepthProvider(completion=CompletionOptions(CompletionMethod.CLASSICAL))
    labels = SegmenterLabelProvider(GeometricSegmenter(), uses_pose=True)
    res = run_frontend(seq, None, gt, depth, labels, workers=1, progress=False,
                       depth_refiner=PlanarDepthRefiner())
    room = BoxRoom()
    assert len(res.floor_frame) > 100 and len(res.wall_frame) > 100
    floor_w = transform_points(gt[res.floor_frame], res.floor_p_in_cam)
    assert np.mean(np.abs(floor_w[:, 2]) < 0.05) > 0.95
    if len(res.ceiling_frame):
        ceil_w = transform_points(gt[res.ceiling_frame], res.ceiling_p_in_cam)
        # measured 0.92 (112 samples) without the label check, 0.88 (110) with it: it drops 2
        # pixels' samples, which reshuffles frame 2's random sampling (8 -> 12 of 54 > 5 cm off)
        assert np.mean(np.abs(ceil_w[:, 2] - room.height) < 0.05) > 0.85
    wall_w = transform_points(gt[res.wall_frame], res.wall_p_in_cam)
    d_wall = np.min(np.abs(np.stack([wall_w[:, 0], wall_w[:, 0] - room.size_x,
                                     wall_w[:, 1], wall_w[:, 1] - room.size_y])), axis=0)
    assert np.mean(d_wall < 0.1) > 0.9
    if len(res.column_frame):
        col_w = transform_points(gt[res.column_frame], res.column_p_in_cam)
        lo = np.array(room.column_center) - np.array(room.column_half) - 0.1
        hi = np.array(room.column_center) + np.array(room.column_half) + 0.1
        assert np.mean(((col_w[:, :2] > lo) & (col_w[:, :2] < hi)).all(1)) > 0.9
