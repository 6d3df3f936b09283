"""The scan's samples added to a front-end result (bimcap.frontend.scan_samples)."""

from __future__ import annotations

import numpy as np

from bimcap.frontend.runner import FrontendResult
from bimcap.frontend.scan_samples import frames_without_matches, with_scan_samples
from bimcap.fusion.scan import ScanSamplingOptions
from bimcap.geometry import Camera

CAMERA = Camera(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
#: camera looking along world +x, level: world z is -y in the camera
WORLD_FROM_CAM = np.array([0.0, 0.0, 1.5, -0.5, 0.5, -0.5, 0.5])


def _result(num_frames: int = 4) -> FrontendResult:
    empty = {f"{p}_frame": np.zeros(0, np.int32) for p in ("floor", "ceiling", "column")}
    empty |= {f"{p}_p_in_cam": np.zeros((0, 3)) for p in ("floor", "ceiling", "column")}
    # one pixel wall sample per frame; scan: per frame a wall point (normal along camera x,
    # horizontal) and a floor point 1.4 m below (normal along camera -y, up)
    frames = np.arange(num_frames, dtype=np.int32)
    scan_frame = np.repeat(frames, 2)
    scan_p = np.tile([[2.0, 0.0, -1.0], [0.0, 1.4, -2.0]], (num_frames, 1))
    scan_n = np.tile([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], (num_frames, 1))
    return FrontendResult(
        camera=CAMERA, num_frames=num_frames,
        match_frames=np.array([[0, 1], [1, 2]], np.int32), match_uv=np.zeros((2, 4)),
        match_depth=np.ones((2, 2)), track_obs_frame=np.zeros(0, np.int32),
        track_obs_point=np.zeros(0, np.int32), track_obs_uv=np.zeros((0, 2)),
        track_obs_depth=np.zeros(0), track_points=np.zeros((0, 3)),
        wall_frame=frames, wall_p_in_cam=np.tile([[0.0, 0.0, 3.0]], (num_frames, 1)),
        scan_frame=scan_frame, scan_p_in_cam=scan_p, scan_n_in_cam=scan_n, **empty)


def test_scan_points_become_wall_and_floor_samples_frame_by_frame() -> None:
    fe = _result()
    poses = np.tile(WORLD_FROM_CAM, (4, 1))
    out, stats = with_scan_samples(fe, poses)
    assert (stats.wall, stats.floor, stats.ceiling) == (4, 4, 0)
    # each frame: its pixel sample first, then its scan's
    np.testing.assert_array_equal(out.wall_frame, [0, 0, 1, 1, 2, 2, 3, 3])
    np.testing.assert_array_equal(out.wall_p_in_cam[1], [2.0, 0.0, -1.0])
    np.testing.assert_array_equal(out.floor_frame, [0, 1, 2, 3])
    # the input is untouched
    assert len(fe.wall_frame) == 4 and len(fe.floor_frame) == 0


def test_only_the_frames_asked_for() -> None:
    fe = _result()
    unlinked = frames_without_matches(fe)
    np.testing.assert_array_equal(unlinked, [3])
    out, stats = with_scan_samples(fe, np.tile(WORLD_FROM_CAM, (4, 1)), frames=unlinked)
    assert (stats.wall, stats.floor) == (1, 1)
    np.testing.assert_array_equal(out.wall_frame, [0, 1, 2, 3, 3])
    # a cap of 0 switches a class off
    out, stats = with_scan_samples(fe, np.tile(WORLD_FROM_CAM, (4, 1)),
                                   ScanSamplingOptions(max_floor=0))
    assert stats.floor == 0 and stats.wall == 4


def test_the_scan_arrays_survive_save_and_load(tmp_path) -> None:
    fe = _result()
    fe.save(tmp_path / "fe.npz")
    back = FrontendResult.load(tmp_path / "fe.npz")
    np.testing.assert_array_equal(back.scan_frame, fe.scan_frame)
    np.testing.assert_array_equal(back.scan_n_in_cam, fe.scan_n_in_cam)
