"""Per-frame BIM observability: which degrees of freedom the F / W / Co samples pin."""

from __future__ import annotations

import numpy as np

from bimcap.geometry.poses import invert, transform_points
from bimcap.optimize import SolverOptions
from bimcap.optimize.observability import DOF_NAMES, bim_observability, irls_weight
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
