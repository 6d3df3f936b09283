"""The global alignment retried without one BIM wall that the scan saw through (a wall missing
as built: :mod:`bimcap.registration.missing_wall`)."""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.geometry import Trajectory
from bimcap.geometry.poses import compose, invert
from bimcap.registration import SemanticSamples
from bimcap.registration.errors import GlobalAlignmentError
from bimcap.registration.global_align import _wall_faces, global_align
from bimcap.registration.missing_wall import (
    align_without_missing_wall,
    dominant_seen_through_wall,
)
from bimcap.registration.synthetic import merge, poses_along, scan_sequence, solids
from bimcap.sim.drift import DriftParams, apply_drift, to_slam_frame

pytest.importorskip("cv2")

T = 0.2
#: Two rooms 13 m x 5 m in all, a few columns and stubs so that the plan has one placement.
OUTER = [(-T, -T, 13.0 + T, 0.0), (-T, 5.0, 13.0 + T, 5.0 + T), (-T, 0.0, 0.0, 5.0),
         (13.0, 0.0, 13.0 + T, 5.0), (1.5, 3.6, 2.3, 4.0), (9.5, 0.8, 10.5, 1.0),
         (11.0, 3.0, 11.4, 3.4), (3.0, 0.0, 3.2, 1.2)]
#: The partition between them, with a door from y = 2 to 3 m: missing as built.
PARTITION = [(5.9, 0.0, 6.1, 2.0), (5.9, 3.0, 6.1, 5.0)]


def test_the_faces_of_a_wall_are_its_parallel_near_segments_on_both_sides_of_a_door() -> None:
    seg = np.array([[6.0, 0.0, 6.0, 2.0],    # 0: the most-crossed face
                    [6.2, 2.0, 6.2, 0.0],    # 1: its other face (reversed)
                    [6.0, 3.0, 6.0, 5.0],    # 2: the piece beyond a 1 m door
                    [6.0, 2.0, 6.2, 2.0],    # 3: the end cap (perpendicular)
                    [9.0, 0.0, 9.0, 2.0],    # 4: a parallel wall 3 m away
                    [6.0, 7.0, 6.0, 9.0]])   # 5: collinear, 5 m away along the line
    assert sorted(_wall_faces(seg, 0).tolist()) == [0, 1, 2]


def _samples(cam: np.ndarray, pts: np.ndarray) -> SemanticSamples:
    """Wall samples of one level camera per point (identity rotation: camera = world axes)."""
    n = len(pts)
    return SemanticSamples.from_arrays(wall_frame=np.arange(n, dtype=np.int32),
                                       wall_p_in_cam=pts - cam)


def test_the_dominant_wall_is_the_one_most_rays_cross() -> None:
    """Half the points lie behind the partition at x = 6 m (seen through its two faces), the
    rest in front of it: the partition is the wall, seen through by all of them."""
    plan = merge(solids([(-T, -T, 13.0 + T, 0.0), (-T, 5.0, 13.0 + T, 5.0 + T),
                         (-T, 0.0, 0.0, 5.0), (13.0, 0.0, 13.0 + T, 5.0), *PARTITION])
                 ).floor_plan()
    y = np.linspace(0.5, 4.5, 20)
    pts = np.r_[np.c_[np.full(20, 13.0), y, np.full(20, 1.5)],
                np.c_[np.full(20, 0.0), y, np.full(20, 1.5)]]
    cam = np.tile([3.0, 2.5, 1.5], (40, 1))
    poses = np.c_[cam, np.tile([0.0, 0.0, 0.0, 1.0], (40, 1))]
    wall = dominant_seen_through_wall(poses, _samples(cam, pts), plan, 0.0)
    assert wall is not None
    assert np.allclose(np.sort(np.unique(wall.segments[:, [0, 2]])), [5.9, 6.1])
    assert wall.share == 1.0 and wall.see_through_without == 0.0
    assert 0.0 < wall.see_through < 0.5  # the rays through the door do not count
    assert "missing as built" in wall.describe()


def test_a_refusal_without_placements_stands() -> None:
    plan = merge(solids(OUTER)).floor_plan()
    samples = _samples(np.zeros((1, 3)), np.ones((1, 3)))
    assert align_without_missing_wall(np.zeros((3, 7)), samples, plan,
                                      GlobalAlignmentError("no placement", None)) is None


@pytest.mark.parametrize("seed", [1, 3])
def test_a_partition_missing_as_built_is_placed_without_it(seed: int) -> None:
    """The walk crosses from one room to the other through the door and sees the far room
    through where the design's partition stands: the right placement is refused (about 20 %
    of its points through walls, maximum 15 %); without the partition it is placed, right."""
    design = merge(solids(OUTER + PARTITION))
    built = merge(solids(OUTER))
    gt = poses_along(np.array([[1.0, 2.5], [5.0, 2.5], [5.0, 1.5], [8.0, 2.2], [12.0, 2.0]]),
                     0.25)
    drifted = apply_drift(Trajectory(np.arange(len(gt)) * 0.5, gt),
                          DriftParams.from_preset("exp2", seed=seed))
    samples = scan_sequence(gt, built, seed=seed, clutter_fraction=0.05)
    slam = to_slam_frame(drifted.init, seed)
    with pytest.raises(GlobalAlignmentError, match="seen through walls") as info:
        global_align(slam.trajectory.poses, samples, design.floor_plan())
    found = align_without_missing_wall(slam.trajectory.poses, samples, design.floor_plan(),
                                       info.value)
    assert found is not None
    res, wall = found
    assert np.allclose(np.sort(np.unique(wall.segments[:, [0, 2]])), [5.9, 6.1])
    assert len(wall.rows) == 4  # both faces of both pieces
    true = compose(invert(slam.slam_from_world), slam.trajectory.poses)
    assert np.linalg.norm(res.poses[:, :3] - true[:, :3], axis=1).mean() < 0.5
    assert res.hypotheses[0].see_through <= 0.15


def test_a_wall_missing_as_built_skips_the_turned_search_and_the_retry_reuses_the_maps() -> None:
    """Refused for its see-through alone, with one wall crossed by most seen-through rays: the
    frames' yaw errors do not explain that, so ``frame_yaw = on_refusal`` does not search the
    turned scan again (``frame_yaw_wall_share``); the wall is kept in the refusal's result and
    the retry places the walk as before. The retry with the refused alignment's maps
    (``maps_cache``) gives the same placement, bit for bit, as with maps built again."""
    from bimcap.registration import GlobalAlignOptions

    design = merge(solids(OUTER + PARTITION))
    built = merge(solids(OUTER))
    gt = poses_along(np.array([[1.0, 2.5], [5.0, 2.5], [5.0, 1.5], [8.0, 2.2], [12.0, 2.0]]),
                     0.25)
    drifted = apply_drift(Trajectory(np.arange(len(gt)) * 0.5, gt),
                          DriftParams.from_preset("exp2", seed=1))
    samples = scan_sequence(gt, built, seed=1, clutter_fraction=0.05)
    poses = to_slam_frame(drifted.init, 1).trajectory.poses
    plan = design.floor_plan()
    cache: dict[bytes, object] = {}
    with pytest.raises(GlobalAlignmentError, match="seen through walls") as info:
        global_align(poses, samples, plan, None, cache)
    res = info.value.result
    assert res is not None and not res.frames_turned
    assert res.seen_through_wall is not None and res.seen_through_wall.share >= 0.6
    assert "frame_yaw_wall" in res.timings and len(cache) >= 1
    assert res.to_dict()["seen_through_wall"]["share"] == res.seen_through_wall.share
    # Above 1: the turned scan is searched, as before the bar.
    with pytest.raises(GlobalAlignmentError) as turned:
        global_align(poses, samples, plan, GlobalAlignOptions(frame_yaw_wall_share=2.0))
    assert turned.value.result is not None and turned.value.result.frames_turned
    assert turned.value.result.seen_through_wall is None
    with_cache = align_without_missing_wall(poses, samples, plan, info.value, None, cache)
    without = align_without_missing_wall(poses, samples, plan, info.value)
    assert with_cache is not None and without is not None
    assert np.array_equal(with_cache[0].poses, without[0].poses)
    assert np.array_equal(with_cache[1].rows, without[1].rows)
