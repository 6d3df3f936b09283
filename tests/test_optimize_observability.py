"""Per-frame BIM observability: which degrees of freedom the F / W / Co samples pin."""

from __future__ import annotations

import numpy as np

from bimcap.geometry.poses import invert, transform_points
from bimcap.optimize import SolverOptions
from bimcap.optimize.observability import (
    DOF_NAMES,
    FrameObservability,
    Observability,
    bim_observability,
    irls_weight,
    unanchored_frames,
)
from bimcap.optimize.options import Loss


def _frame(world_from_cam: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    return transform_points(np.repeat(invert(world_from_cam)[None], len(p_world), 0), p_world)


def _arrays(pose: np.ndarray, walls: list[np.ndarray], floor: np.ndarray | None) -> dict:
    """One camera; wall points on the given segments' faces; floor points on z = 0."""
    rng = np.random.default_rng(0)
    segments, wall_p = [], []
    for seg in walls:
        t = rng.random(200)
        xy = seg[:2] + t[:, None] * (seg[2:] - seg[:2])
        wall_p.append(np.column_stack([xy, rng.uniform(0.3, 2.5, 200)]))
        segments.append(seg)
    p_wall = np.concatenate(wall_p)
    a = {
        "wall_frame": np.zeros(len(p_wall), np.int32),
        "wall_p_in_cam": _frame(pose, p_wall),
        "segments": np.array(segments, float),
        "planes": np.array([[0.0, 0.0, 1.0, 0.0]]),
    }
    if floor is not None:
        a.update(floor_frame=np.zeros(len(floor), np.int32), floor_p_in_cam=_frame(pose, floor),
                 floor_plane=np.zeros(len(floor), np.int32))
    return a


def test_one_wall_ahead_pins_distance_pitch_and_yaw_only() -> None:
    # camera at (0, 0, 1.5) looking along +x (optical z = world x, x = −y, y = −z)
    pose = np.array([0.0, 0.0, 1.5, -0.5, 0.5, -0.5, 0.5])
    wall = np.array([2.0, -1.5, 2.0, 1.5])  # the face x = 2 in front of it
    a = _arrays(pose, [wall], None)
    obs = bim_observability(a, pose[None], SolverOptions(), wall_segment=np.zeros(200, np.int32))
    f = obs.frames[0]
    assert f.samples == {"W": 200}
    assert set(f.observed) == {"along", "pitch", "yaw"}
    assert set(f.unobserved) == {"across", "up", "roll"}
    assert np.isinf(f.sigma[DOF_NAMES.index("across")])
    # 200 samples, σ 5 cm: the distance to the wall to σ/√200 ≈ 3.5 mm
    assert 0.002 < f.sigma[DOF_NAMES.index("along")] < 0.006


def test_floor_and_a_corner_pin_everything() -> None:
    pose = np.array([0.0, 0.0, 1.5, -0.5, 0.5, -0.5, 0.5])
    rng = np.random.default_rng(1)
    floor = np.column_stack([rng.uniform(0.5, 2.0, 300), rng.uniform(-1.0, 1.0, 300),
                             np.zeros(300)])
    a = _arrays(pose, [np.array([2.0, -1.5, 2.0, 1.5]), np.array([-0.5, 1.5, 2.0, 1.5])], floor)
    assoc = np.repeat(np.arange(2, dtype=np.int32), 200)
    obs = bim_observability(a, pose[None], SolverOptions(), wall_segment=assoc)
    assert obs.frames[0].observed == list(DOF_NAMES)
    assert obs.fully_observed() == 1 and obs.count_unobserved() == dict.fromkeys(DOF_NAMES, 0)
    d = obs.to_dict()
    assert d["frames"][0]["samples"] == {"F": 300, "W": 400}


def test_outliers_weigh_less_under_a_robust_loss() -> None:
    r = np.array([0.0, 1.0, 10.0])
    np.testing.assert_allclose(irls_weight(Loss.CAUCHY, 1.0, r), [1.0, 0.5, 1.0 / 101.0])
    np.testing.assert_allclose(irls_weight(Loss.NONE, 1.0, r), 1.0)
    np.testing.assert_allclose(irls_weight(Loss.HUBER, 2.0, r), [1.0, 1.0, 0.2])


def _obs(observed: list[list[str]]) -> Observability:
    return Observability(frames=[FrameObservability(frame=i, samples={}, sigma=np.zeros(6),
                                                    observed=list(o))
                                 for i, o in enumerate(observed)])


def test_unanchored_frames_follow_g_components() -> None:
    full, wall = list(DOF_NAMES), ["along", "pitch", "yaw"]
    # 0-1-2 chained, 2 fully observed; 3 alone on one wall; 4-5 an island that together
    # observe everything; 6-7 an island of wall-only frames.
    obs = _obs([wall, wall, full, wall, ["along", "across", "yaw"], ["up", "roll", "pitch"],
                wall, wall])
    matches = np.array([[0, 1], [1, 0], [2, 1], [4, 5], [6, 7], [7, 6]])
    assert unanchored_frames(matches, obs) == [3, 6, 7]
    # a link needs min_matches matches: 0-1 and 6-7 have two, 1-2 and 4-5 one
    assert unanchored_frames(matches, obs, min_matches=2) == [0, 1, 3, 4, 5, 6, 7]
    # without G every frame stands alone
    assert unanchored_frames(None, obs) == [0, 1, 3, 4, 5, 6, 7]
    assert unanchored_frames(np.zeros((0, 2), np.int32), _obs([full, full])) == []


def test_a_lone_one_wall_frame_is_unanchored_a_matched_one_is_not() -> None:
    # frames 0 and 1 stand in front of a corner with floor, frame 2 before one wall only;
    # the BIM observes all of 0 and 1, only part of 2.
    pose = np.array([0.0, 0.0, 1.5, -0.5, 0.5, -0.5, 0.5])
    rng = np.random.default_rng(2)
    floor = np.column_stack([rng.uniform(0.5, 2.0, 300), rng.uniform(-1.0, 1.0, 300),
                             np.zeros(300)])
    corner = _arrays(pose, [np.array([2.0, -1.5, 2.0, 1.5]), np.array([-0.5, 1.5, 2.0, 1.5])],
                     floor)
    wall = _arrays(pose, [np.array([2.0, -1.5, 2.0, 1.5])], None)
    parts = [corner, corner, wall]
    a = {
        "segments": np.concatenate([p["segments"] for p in parts]),
        "planes": corner["planes"],
        "wall_p_in_cam": np.concatenate([p["wall_p_in_cam"] for p in parts]),
        "wall_frame": np.concatenate([np.full(len(p["wall_p_in_cam"]), i, np.int32)
                                      for i, p in enumerate(parts)]),
        "floor_p_in_cam": np.concatenate([corner["floor_p_in_cam"]] * 2),
        "floor_frame": np.repeat(np.arange(2, dtype=np.int32), 300),
        "floor_plane": np.zeros(600, np.int32),
    }
    assoc = np.concatenate([np.repeat([0, 1], 200), np.repeat([2, 3], 200), np.full(200, 4)])
    poses = np.repeat(pose[None], 3, 0)
    obs = bim_observability(a, poses, SolverOptions(), wall_segment=assoc.astype(np.int32))
    assert [len(f.observed) for f in obs.frames] == [6, 6, 3]
    assert unanchored_frames(np.array([[0, 1]] * 5), obs) == [2]
    assert unanchored_frames(np.array([[0, 1]] * 5 + [[1, 2]] * 5), obs) == []
