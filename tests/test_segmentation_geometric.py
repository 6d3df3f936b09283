from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _fusion_scene import frames
from bimcap.fusion import CompletionMethod, CompletionOptions, complete_depth, project_lidar
from bimcap.geometry import quat_to_rotmat
from bimcap.labels import Label
from bimcap.segmentation import FrameInput, SegmentationInputError, iou_per_class
from bimcap.segmentation.geometric import GeometricSegmenter, segment_geometric

# Required IoU on the box-room frames, pooled over frames (pixels of all frames together; columns
# cut by the image border ignored, see _ignore_border_columns); measured 0.98 floor, 0.99 wall,
# 0.81 ceiling, 0.98 column (the same with pitch errors up to ±12°). Floor and walls
# are large planes that the method models exactly: only the low-resolution work and crease pixels
# cost IoU. The ceiling is seen as thin slivers at the top of these images, where a pixel or two
# of border error is a large share. Columns are decided by width and protrusion.
REQUIRED = {Label.FLOOR: 0.95, Label.WALL: 0.95, Label.CEILING: 0.75, Label.COLUMN: 0.9}


def _ignore_border_columns(gt: np.ndarray) -> np.ndarray:
    """GT with columns cut by the image's left/right border set to UNKNOWN (ignored by the IoU):
    by design the segmenter calls a narrow region cut by the border a wall (a wall seen between
    the border and a doorway looks the same, and walls are far more common)."""
    import cv2

    out = gt.copy()
    n, comp = cv2.connectedComponents((gt == Label.COLUMN).astype(np.uint8))
    for c in range(1, n):
        m = comp == c
        if m[:, :3].any() or m[:, -3:].any():
            out[m] = Label.UNKNOWN
    return out


def _pooled_iou(preds: list[np.ndarray], gts: list[np.ndarray]) -> dict[Label, float]:
    return iou_per_class(np.concatenate(preds, 0),
                         np.concatenate([_ignore_border_columns(g) for g in gts], 0))


def _tilt(pose: np.ndarray, pitch_deg: float) -> np.ndarray:
    out = pose.copy()
    rot = quat_to_rotmat(pose[3:]) @ Rotation.from_euler("x", pitch_deg, degrees=True).as_matrix()
    out[3:] = Rotation.from_matrix(rot).as_quat()
    return out


@pytest.mark.parametrize("pitch_error_deg", [0.0, 4.0, -8.0])
def test_iou_on_ground_truth_depth(pitch_error_deg: float) -> None:
    fs = frames(4, 516, 386, 7) + frames(3)
    preds = [segment_geometric(f.depth, f.camera, _tilt(f.world_from_cam, pitch_error_deg))
             for f in fs]
    iou = _pooled_iou(preds, [f.labels for f in fs])
    for label, need in REQUIRED.items():
        assert iou[label] >= need, (label, iou)


def test_iou_on_completed_lidar_depth() -> None:
    fs = frames(3)
    preds = []
    for f in fs:
        sp = project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera)
        dense = complete_depth(sp, CompletionOptions(CompletionMethod.CLASSICAL))
        preds.append(GeometricSegmenter().segment(
            FrameInput(f.camera, depth=dense, world_from_cam=f.world_from_cam)))
    iou = _pooled_iou(preds, [f.labels for f in fs])
    assert iou[Label.FLOOR] >= 0.85 and iou[Label.WALL] >= 0.85, iou


def test_no_depth_is_unknown_and_bad_inputs() -> None:
    f = frames(3)[0]
    d = f.depth.copy()
    d[:, :100] = 0.0
    lab = segment_geometric(d, f.camera, f.world_from_cam)
    assert (lab[:, :100] == Label.UNKNOWN).all()
    with pytest.raises(SegmentationInputError, match="does not match"):
        segment_geometric(d[:-2], f.camera, f.world_from_cam)
    bad = d.copy()
    bad[5, 5] = np.nan
    with pytest.raises(SegmentationInputError, match="NaN"):
        segment_geometric(bad, f.camera, f.world_from_cam)
    with pytest.raises(SegmentationInputError, match="world_from_cam"):
        segment_geometric(d, f.camera, np.zeros(6))
    with pytest.raises(SegmentationInputError, match="needs dense depth"):
        GeometricSegmenter().segment(FrameInput(f.camera))


def test_column_cut_by_the_image_border_is_a_wall() -> None:
    # the documented prior: one visible side cannot tell a column from a wall end at a doorway
    fs = frames(3)
    f = fs[0]
    lab = segment_geometric(f.depth, f.camera, f.world_from_cam)
    gt_ignored = _ignore_border_columns(f.labels)
    cut = (f.labels == Label.COLUMN) & (gt_ignored == Label.UNKNOWN)
    assert cut.sum() > 1000  # this frame has one
    assert np.mean(lab[cut] == Label.WALL) > 0.9


def test_round_column() -> None:
    # a cylinder: no plane takes it whole; the tall, narrow, protruding left-over rule does
    from bimcap.fusion.synthetic import BoxRoom, default_camera, render_default_frames

    room = BoxRoom(round_column=True, column_half=(0.3, 0.3))
    fs = render_default_frames(4, camera=default_camera(516, 386), room=room)
    preds = [segment_geometric(f.depth, f.camera, f.world_from_cam) for f in fs]
    iou = _pooled_iou(preds, [f.labels for f in fs])
    assert iou[Label.COLUMN] >= 0.8 and iou[Label.WALL] >= 0.9, iou


def test_clutter_is_not_taken_for_columns_or_walls() -> None:
    # crates and a table-high box on the floor: narrow, protruding vertical faces like a column's,
    # but they do not reach the ceiling
    from bimcap.fusion.synthetic import BoxRoom, default_camera, render_default_frames

    room = BoxRoom(clutter=((3.0, 1.2, 0.0, 3.8, 1.8, 0.8), (4.0, 2.8, 0.0, 4.5, 3.3, 0.5),
                            (6.5, 3.5, 0.0, 7.2, 4.5, 1.1)))
    fs = render_default_frames(4, camera=default_camera(516, 386), room=room)
    preds = [segment_geometric(f.depth, f.camera, f.world_from_cam) for f in fs]
    gt = np.concatenate([_ignore_border_columns(f.labels) for f in fs])
    pred = np.concatenate(preds)
    iou = iou_per_class(pred, gt)
    assert iou[Label.CLUTTER] >= 0.9 and iou[Label.COLUMN] >= 0.9 and iou[Label.FLOOR] >= 0.9, iou
    assert np.mean(pred[gt == Label.CLUTTER] == Label.COLUMN) < 0.01


def _noisy_wall_frames(noise_m: float, views: tuple[tuple[float, float, float], ...] = (
        (6.0, 3.0, 0.0), (2.0, 3.0, 180.0), (3.0, 3.0, -90.0))) -> list:
    """Frames of the box room through a narrow (1.5× focal length) camera at ``views`` (x, y in
    metres, yaw in degrees; default: looking at walls 2–3 m away), with a VLP-16-like ring LiDAR
    whose ranges have ``noise_m`` Gaussian noise."""
    from bimcap.fusion.synthetic import (
        BoxRoomScene,
        default_cam_from_lidar,
        look_pose,
        narrow_ring_rig,
    )

    cam, lidar = narrow_ring_rig(noise_m)
    scene = BoxRoomScene()
    return [scene.render(cam, look_pose(np.array([x, y, 1.5]), yaw, 12.0),
                         default_cam_from_lidar(), lidar, i)
            for i, (x, y, yaw) in enumerate(views)]


def test_range_noise_from_the_scan_and_noise_aware_options() -> None:
    """scan_range_noise measures the ring LiDAR's range noise from the scan alone (0, 3, 8 cm);
    the options change only well above the 3 cm the defaults are made for."""
    from bimcap.segmentation.geometric import GeometricOptions, scan_range_noise

    for noise in (0.0, 0.03, 0.08):
        for f in _noisy_wall_frames(noise)[:2]:
            est = scan_range_noise(f.points_in_lidar)
            assert est is not None and abs(est - noise) <= 0.1 * noise + 0.002, (noise, est)
    assert scan_range_noise(np.zeros((5, 4))) is None
    base = GeometricOptions()
    assert base.for_noise(None) == base and base.for_noise(0.03) == base
    assert base.for_noise(0.04) == base
    wide = base.for_noise(0.08)
    assert (wide.normal_step_px, wide.normal_smooth_px) == (4, 11)
    assert wide.plane_threshold_m == pytest.approx(0.12)
    assert base.min_normal_baseline_m == 0.0
    assert wide.min_normal_baseline_m == pytest.approx(0.08)


def test_walls_under_8cm_lidar_noise() -> None:
    """With 8 cm range noise the completed depth of a wall seen from 2 m has normals that point
    anywhere at the default 2-pixel baseline: the defaults keep 8 % of the wall pixels as wall
    (measured; the rest clutter). Told the noise (FrameInput.range_noise_m, measured on the scan
    as the pipeline does), the segmenter widens its normals and plane threshold and keeps 73 %;
    nothing else is called wall."""
    from bimcap.segmentation.geometric import scan_range_noise

    counts = {"default": np.zeros(2), "noise-aware": np.zeros(2)}
    n_wall = 0
    for f in _noisy_wall_frames(0.08):
        dense = complete_depth(project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera),
                               CompletionOptions())
        wall = (f.labels == Label.WALL) & (dense > 0)
        n_wall += int(wall.sum())
        for name, noise in (("default", None), ("noise-aware",
                                                 scan_range_noise(f.points_in_lidar))):
            lab = GeometricSegmenter().segment(FrameInput(
                f.camera, depth=dense, world_from_cam=f.world_from_cam, range_noise_m=noise))
            said_wall = (lab == Label.WALL) & (dense > 0)
            counts[name] += [(said_wall & wall).sum(), said_wall.sum()]
            assert (said_wall & ~wall).sum() <= 0.02 * said_wall.sum(), name
    assert counts["default"][0] < 0.3 * n_wall, counts
    assert counts["noise-aware"][0] >= 0.6 * n_wall, counts


def _wall_share(views: tuple[tuple[float, float, float], ...], metric: bool) -> tuple[float, float]:
    """Over the 8 cm noise frames at ``views``: the share of the wall pixels (with depth) labelled
    wall, and the share of the pixels labelled wall that are wall, by the noise-aware segmenter
    (``metric`` False: without the normals' metric baseline, the pixel step alone)."""
    from dataclasses import replace

    from bimcap.segmentation.geometric import GeometricOptions, scan_range_noise

    hit = said = n_wall = 0
    for f in _noisy_wall_frames(0.08, views):
        dense = complete_depth(project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera),
                               CompletionOptions())
        opts = GeometricOptions().for_noise(scan_range_noise(f.points_in_lidar))
        if not metric:
            opts = replace(opts, min_normal_baseline_m=0.0)
        lab = segment_geometric(dense, f.camera, f.world_from_cam, opts)
        wall = (f.labels == Label.WALL) & (dense > 0)
        said_wall = (lab == Label.WALL) & (dense > 0)
        n_wall += int(wall.sum())
        hit += int((said_wall & wall).sum())
        said += int(said_wall.sum())
    return hit / max(1, n_wall), hit / max(1, said)


def test_a_wall_1_m_away_under_8cm_lidar_noise_is_wall() -> None:
    """gen-small-s3 hard, frames 24–26 and 54: a wall 0.8–1.05 m away fills the narrow view. The
    4-pixel step of the noise-aware options spans 2 cm there (working fx 441 px), against 4 cm of
    error in the completed depth: the normals point anywhere, no vertical plane gathers agreeing
    inliers, and the wall was all clutter (measured: 0–9 % wall; the planar smoothing then left
    the keypoints' depth 4 cm off). With the step widened to span 1 σ at the median depth, most
    of it is wall and nothing else is; at 2–3 m the step is nearly unchanged and so are the
    labels."""
    near = ((1.0, 3.0, 180.0), (3.0, 5.0, 90.0), (2.0, 1.0, -90.0))
    rec_pix, _ = _wall_share(near, metric=False)
    rec, prec = _wall_share(near, metric=True)
    assert rec_pix < 0.3, rec_pix
    assert rec >= 0.6 and prec >= 0.98, (rec, prec)
    far_pix, _ = _wall_share(((6.0, 3.0, 0.0),), metric=False)
    far, far_prec = _wall_share(((6.0, 3.0, 0.0),), metric=True)
    assert far >= far_pix - 0.05 and far_prec >= 0.98, (far_pix, far, far_prec)
