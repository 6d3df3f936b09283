"""The front end's check of labels against the depth's surface orientation
(:func:`bimcap.frontend.semantic_map.check_label_orientation`): patches of wrong labels, as a
segmenter (or the simulator's label noise) gives them, are dropped; right labels are kept."""

from __future__ import annotations

import numpy as np
import pytest

from _fusion_scene import frames
from bimcap.frontend import SemanticSamplingOptions
from bimcap.frontend.semantic_map import check_label_orientation
from bimcap.labels import Label


def _disk_inside(mask: np.ndarray, radius: int) -> np.ndarray:
    """A disk of ``radius`` pixels around the point of ``mask`` farthest from its border."""
    import cv2

    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    v, u = np.unravel_index(int(np.argmax(dist)), mask.shape)
    assert dist[v, u] > radius, "no room for the patch"
    vv, uu = np.mgrid[0:mask.shape[0], 0:mask.shape[1]]
    return (vv - v) ** 2 + (uu - u) ** 2 <= radius**2


def _corrupt(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Labels with a floor and a ceiling patch painted on a wall and a wall patch on the floor;
    and the mask of the painted pixels."""
    noisy = labels.copy()
    painted = np.zeros(labels.shape, dtype=bool)
    wall = labels == Label.WALL
    for cls, radius in ((Label.FLOOR, 30), (Label.CEILING, 14)):
        d = _disk_inside(wall & ~painted, radius)
        noisy[d] = cls
        painted |= d
    if (labels == Label.FLOOR).sum() > 5000:
        d = _disk_inside(labels == Label.FLOOR, 20)
        noisy[d] = Label.WALL
        painted |= d
    return noisy, painted


def test_wrong_patches_are_dropped_right_labels_kept() -> None:
    kept = total = dropped = painted_total = 0
    for f in frames(3):
        noisy, painted = _corrupt(f.labels)
        checked, stats = check_label_orientation(noisy, f.depth, f.camera, f.world_from_cam)
        assert stats["dropped_regions"] >= 2
        dropped += int((checked[painted] == Label.UNKNOWN).sum())
        painted_total += int(painted.sum())
        right = ~painted & np.isin(f.labels, [Label.FLOOR, Label.WALL, Label.CEILING]) & (
            f.depth > 0)
        kept += int((checked[right] == f.labels[right]).sum())
        total += int(right.sum())
    assert dropped >= 0.9 * painted_total, (dropped, painted_total)
    assert kept >= 0.97 * total, (kept, total)


def test_close_wall_under_8cm_noise_is_kept() -> None:
    """A wall 1 m away through a narrow lens, completed from a ring LiDAR with 8 cm range noise:
    local normals point anywhere, the plane fitted over the region does not; the wall stays and
    a floor patch painted on it goes."""
    from bimcap.fusion import CompletionOptions, complete_depth, project_lidar
    from bimcap.fusion.synthetic import (
        BoxRoomScene,
        default_cam_from_lidar,
        look_pose,
        narrow_ring_rig,
    )

    cam, lidar = narrow_ring_rig(0.08)
    f = BoxRoomScene().render(cam, look_pose(np.array([7.0, 3.0, 1.5]), 0.0, 10.0),
                              default_cam_from_lidar(), lidar, 0)
    dense = complete_depth(project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera),
                           CompletionOptions())
    wall = (f.labels == Label.WALL) & (dense > 0)
    assert wall.mean() > 0.8
    noisy = f.labels.copy()
    patch = _disk_inside(wall, 60)
    noisy[patch] = Label.FLOOR
    checked, _ = check_label_orientation(noisy, dense, f.camera, f.world_from_cam)
    assert (checked[wall & ~patch] == Label.WALL).mean() >= 0.9
    assert (checked[patch] == Label.UNKNOWN).mean() >= 0.9


def test_check_off_and_bad_options() -> None:
    f = frames(3)[0]
    noisy, _ = _corrupt(f.labels)
    off = SemanticSamplingOptions(orientation_check_deg=None)
    same, stats = check_label_orientation(noisy, f.depth, f.camera, f.world_from_cam, off)
    assert (same == noisy).all() and stats["dropped_pixels"] == 0
    with pytest.raises(Exception, match="orientation_check_deg"):
        SemanticSamplingOptions(orientation_check_deg=95.0)
