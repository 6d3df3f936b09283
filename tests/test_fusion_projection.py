from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.fusion import (
    FusionInputError,
    NanPolicy,
    ProjectionOptions,
    pair_by_timestamp,
    project_lidar,
    undistort_image,
)
from bimcap.fusion.synthetic import BoxRoomScene, default_cam_from_lidar, default_camera, look_pose
from bimcap.geometry import Camera

IDENTITY = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
CAM = Camera(640, 480, 500.0, 510.0, 320.0, 240.0)
DIST_CAM = Camera(640, 480, 500.0, 510.0, 320.0, 240.0, (-0.2, 0.05, 0.001, -0.002, 0.0))


def test_known_point_lands_on_known_pixel_pinhole() -> None:
    # LiDAR x forward, y left, z up; camera 0.1 m below the LiDAR: p_in_cam = R p + t
    r = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    cam_from_lidar = np.concatenate([[0.0, 0.1, 0.0], Rotation.from_matrix(r).as_quat()])
    # a point 4 m ahead, 0.5 m left, 0.3 m up of the LiDAR → cam (0.5·-1, -0.3+0.1, 4)
    # = (-0.5, -0.2, 4)
    sp = project_lidar(np.array([[4.0, 0.5, 0.3]]), cam_from_lidar, CAM,
                       ProjectionOptions(occlusion_radius_px=0))
    u = 500.0 * -0.5 / 4.0 + 320.0  # 257.5
    v = 510.0 * -0.2 / 4.0 + 240.0  # 214.5
    np.testing.assert_allclose(sp.uv, [[u, v]], atol=1e-9)
    np.testing.assert_allclose(sp.z, [4.0])
    assert sp.depth[int(np.rint(v)), int(np.rint(u))] == pytest.approx(4.0)
    assert np.count_nonzero(sp.depth) == 1


def test_known_point_with_distortion_matches_opencv() -> None:
    import cv2

    rng = np.random.default_rng(3)
    p = np.stack([rng.uniform(-1.5, 1.5, 50), rng.uniform(-1.0, 1.0, 50),
                  rng.uniform(2.0, 6.0, 50)], 1)
    sp = project_lidar(p, IDENTITY, DIST_CAM, ProjectionOptions(occlusion_radius_px=0),
                       distort=True)
    ref, _ = cv2.projectPoints(p[sp.point_index], np.zeros(3), np.zeros(3), DIST_CAM.K,
                               np.asarray(DIST_CAM.dist))
    np.testing.assert_allclose(sp.uv, ref.reshape(-1, 2), atol=1e-6)
    # without distortion the same camera projects with its pinhole model
    sp0 = project_lidar(p, IDENTITY, DIST_CAM, ProjectionOptions(occlusion_radius_px=0))
    uv0 = p[sp0.point_index, :2] / p[sp0.point_index, 2:] * [500.0, 510.0] + [320.0, 240.0]
    np.testing.assert_allclose(sp0.uv, uv0, atol=1e-9)


def test_points_outside_fov_do_not_wrap_in_through_distortion() -> None:
    # with k1 < 0 the polynomial folds far-off-axis points back into the image; they must go
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0, (-0.4, 0.0, 0.0, 0.0, 0.0))
    far_off_axis = np.array([[1.8, 0.0, 1.0]])  # x/z = 1.8 (61°): outside the FoV (x/z < 0.9)
    xy_d = cam.distort_normalized(far_off_axis[:, :2] / far_off_axis[:, 2:])
    assert cam.in_image(xy_d * 500.0 + [320.0, 240.0]).all()  # the naive projection lands inside
    sp = project_lidar(np.vstack([far_off_axis, [[0.0, 0.0, 3.0]]]), IDENTITY, cam, distort=True)
    assert sp.counts["in_fov"] == 1 and sp.point_index.tolist() == [1]


def test_zbuffer_keeps_nearest_and_behind_camera_dropped() -> None:
    pts = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 3.0], [0.0, 0.0, -3.0], [0.001, 0.0, 4.0]])
    sp = project_lidar(pts, IDENTITY, CAM, ProjectionOptions(occlusion_radius_px=0))
    assert sp.counts["in_front"] == 3
    assert sp.counts["zbuffer"] == 1
    assert sp.z.tolist() == [3.0] and sp.point_index.tolist() == [1]


def test_occluded_points_are_dropped() -> None:
    # a foreground strip at 2 m (returns every 3 px) with background returns at 6 m between them,
    # as a LiDAR offset from the camera sees behind an edge
    u = np.arange(300.0, 340.0, 3.0)
    fg = np.stack([(u - 320.0) / 500.0 * 2.0, np.zeros_like(u), np.full_like(u, 2.0)], 1)
    ub = u + 1.5
    bg = np.stack([(ub - 320.0) / 500.0 * 6.0, np.zeros_like(ub), np.full_like(ub, 6.0)], 1)
    far = np.array([[(400.0 - 320.0) / 500.0 * 6.0, 0.0, 6.0]])  # background away from the edge
    sp = project_lidar(np.vstack([fg, bg, far]), IDENTITY, CAM)
    kept = set(sp.point_index.tolist())
    assert kept == set(range(len(fg))) | {len(fg) + len(bg)}
    # with the test disabled, the hidden ones stay
    sp_all = project_lidar(np.vstack([fg, bg, far]), IDENTITY, CAM,
                           ProjectionOptions(occlusion_radius_px=0))
    assert sp_all.counts["kept"] == len(fg) + len(bg) + 1


def test_scene_projection_agrees_with_ground_truth_depth() -> None:
    scene = BoxRoomScene()
    cam = default_camera(320, 240)
    f = scene.render(cam, look_pose(np.array([1.5, 2.5, 1.5]), 10.0, 8.0), default_cam_from_lidar())
    sp = project_lidar(f.points_in_lidar, f.cam_from_lidar, cam)
    assert sp.counts["kept"] > 500
    gt = f.depth[np.rint(sp.uv[:, 1]).astype(int), np.rint(sp.uv[:, 0]).astype(int)]
    # a return lies on the surface seen at its pixel up to the rounding to the pixel centre
    assert np.median(np.abs(sp.z - gt)) < 0.01
    assert np.mean(np.abs(sp.z - gt) < 0.05) > 0.98


def test_bad_inputs_give_clear_errors() -> None:
    with pytest.raises(FusionInputError, match="empty"):
        project_lidar(np.zeros((0, 3)), IDENTITY, CAM)
    with pytest.raises(FusionInputError, match="NaN"):
        project_lidar(np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]]), IDENTITY, CAM)
    sp = project_lidar(np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]]), IDENTITY, CAM,
                       ProjectionOptions(nan_policy=NanPolicy.DROP))
    assert sp.counts["finite"] == 1 and sp.counts["kept"] == 1
    with pytest.raises(FusionInputError, match="shape"):
        project_lidar(np.zeros((5, 2)), IDENTITY, CAM)
    with pytest.raises(FusionInputError, match="cam_from_lidar"):
        project_lidar(np.ones((5, 3)), np.zeros(7), CAM)
    with pytest.raises(FusionInputError, match="does not match"):
        undistort_image(np.zeros((100, 100, 3), np.uint8), DIST_CAM)


def test_undistort_image_matches_a_pinhole_rendering() -> None:
    scene = BoxRoomScene()
    raw_cam = default_camera(320, 240, distorted=True)
    pose = look_pose(np.array([1.5, 2.5, 1.5]), 10.0, 8.0)
    raw = scene.render(raw_cam, pose, default_cam_from_lidar())
    pin = scene.render(raw_cam.pinhole(), pose, default_cam_from_lidar())
    und = undistort_image(raw.labels, raw_cam, nearest=True)
    und_depth = undistort_image(raw.depth, raw_cam, nearest=True)
    inside = und_depth > 0
    assert inside.mean() > 0.95
    assert np.mean(und[inside] == pin.labels[inside]) > 0.995
    rel = np.abs(und_depth[inside] - pin.depth[inside]) / pin.depth[inside]
    assert np.median(rel) < 0.005
    # and the raw image itself differs from the pinhole one (the test is not vacuous)
    assert np.mean(raw.labels == pin.labels) < np.mean(und[inside] == pin.labels[inside])


def test_undistortion_maps_agree_with_the_camera_model() -> None:
    # the maps from cv2.initUndistortRectifyMap must send each pinhole pixel to the raw pixel that
    # Camera.project (the project's reference distortion) gives for the same ray
    from bimcap.fusion.projection import undistort_maps

    cam = default_camera(320, 240, distorted=True)
    map_x, map_y = undistort_maps(cam)
    rays = cam.pinhole().rays(cam.pixel_grid(), distorted=False)
    uv, _ = cam.project(rays, distort=True)
    np.testing.assert_allclose(map_x.ravel(), uv[:, 0], atol=1e-3)
    np.testing.assert_allclose(map_y.ravel(), uv[:, 1], atol=1e-3)


def test_pair_by_timestamp() -> None:
    img = [0.0, 0.1, 0.2, 0.3, 0.5]
    scans = [0.012, 0.098, 0.31, 0.33, 0.9]
    pairs = pair_by_timestamp(img, scans, tol=0.02)
    assert pairs.tolist() == [[0, 0], [1, 1], [3, 2]]
    # one to one: two images near the same scan, the nearer wins
    assert pair_by_timestamp([1.0, 1.004], [1.003], 0.01).tolist() == [[1, 0]]
    # unsorted scan times
    assert pair_by_timestamp([0.0, 1.0], [1.001, 0.002], 0.01).tolist() == [[0, 1], [1, 0]]
    assert pair_by_timestamp([], [1.0], 0.1).shape == (0, 2)
    with pytest.raises(FusionInputError):
        pair_by_timestamp([0.0], [np.nan], 0.1)
    with pytest.raises(FusionInputError):
        pair_by_timestamp([0.0], [0.0], -1.0)


@pytest.mark.parametrize("radius", [0, 1, 4, 9])
def test_window_min_at_the_returns_is_opencvs_erosion(radius: int) -> None:
    """The occlusion test's nearest return in each window, read at the returns (compiled), is
    OpenCV's erosion of the positive depths read there: returns at the image's edges and
    corners, windows with no other return, NaN and negative depths ignored; bad input named."""
    import cv2

    from bimcap import _core

    rng = np.random.default_rng(radius)
    for h, w in ((1, 1), (7, 3), (60, 90)):
        depth = np.zeros((h, w), np.float32)
        n = max(1, h * w // 6)
        at = rng.choice(h * w, n, replace=False)
        depth.flat[at] = rng.uniform(0.5, 20.0, n).astype(np.float32)
        depth.flat[rng.choice(h * w, max(1, n // 10))] = np.float32(np.nan)
        depth.flat[rng.choice(h * w, max(1, n // 10))] = np.float32(-1.0)
        at = np.concatenate([at, [0, h * w - 1, w - 1]]).astype(np.int64)
        big = np.float32(np.finfo(np.float32).max)
        want = cv2.erode(np.where(depth > 0, depth, big),
                         np.ones((2 * radius + 1,) * 2, np.uint8)).reshape(-1)[at]
        got = _core.window_min_at(depth, at, radius)
        assert got.dtype == np.float32 and got.tobytes() == want.tobytes()
    with pytest.raises(_core.InputError, match="at"):
        _core.window_min_at(depth, np.array([h * w], np.int64), radius)
    with pytest.raises(_core.InputError, match="radius"):
        _core.window_min_at(depth, at, -1)
