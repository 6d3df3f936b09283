"""``registration.window_shift``: windows of a solved walk held off the plan by a rigid shift.

The scans are ray-cast in the demo building's plan section from known poses
(:mod:`bimcap.registration.synthetic`): its walls are solids, so the plan repeats a wall's
thickness across the corridor, the local minimum the bundle adjustment held Duplex_A's frames
in (docs/generalization.md, "Duplex_A 250, frames 89-117").
"""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.registration.synthetic import Scene, poses_along, scan_sequence
from bimcap.registration.window_shift import WindowShiftOptions, window_shifts

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def demo() -> Scene:
    from bimcap.registration.synthetic import demo_scene

    return demo_scene(seed=0)


def problem_arrays(scene: Scene, truth: np.ndarray) -> dict[str, np.ndarray]:
    """A problem's arrays (the plan and the wall / column samples) of scans from ``truth``."""
    s = scan_sequence(truth, scene, seed=3, noise_m=0.01, clutter_fraction=0.03)
    return {"segments": scene.segments, "segment_class": scene.segment_class,
            "wall_frame": s.wall_frame, "wall_p_in_cam": s.wall_p_in_cam,
            "column_frame": s.column_frame, "column_p_in_cam": s.column_p_in_cam}


@pytest.fixture(scope="module")
def walk(demo: Scene) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """30 cameras walking east along the demo corridor (y = -0.3), 0.2 m apart."""
    truth = poses_along(np.array([[3.0, -0.3], [9.01, -0.3]]), 0.2)[:30]
    return truth, problem_arrays(demo, truth)


def test_a_placed_walk_is_not_moved(walk: tuple[np.ndarray, dict[str, np.ndarray]]) -> None:
    truth, arrays = walk
    res = window_shifts(arrays, truth, WindowShiftOptions(window_frames=10))
    assert len(res.windows) == 3
    assert res.moved == []
    np.testing.assert_array_equal(res.poses, truth)
    assert all(np.linalg.norm(w.shift_m) < 0.05 for w in res.windows)


@pytest.mark.parametrize("offset_m", [(0.0, 0.15), (0.0, -0.45), (0.3, 0.2)])
def test_a_window_held_off_the_plan_is_shifted_back(
        walk: tuple[np.ndarray, dict[str, np.ndarray]], offset_m: tuple[float, float]) -> None:
    truth, arrays = walk
    held = truth.copy()
    held[10:20, :2] += offset_m  # the middle window, its rotations and z right
    res = window_shifts(arrays, held, WindowShiftOptions(window_frames=10))
    assert res.moved == list(range(10, 20))
    moved = [w for w in res.windows if w.moved]
    assert len(moved) == 1 and moved[0].best_score > moved[0].score
    err = np.linalg.norm(res.poses[:, :2] - truth[:, :2], axis=1)
    assert err.max() < 0.025, err.max()
    np.testing.assert_array_equal(res.poses[:, 2:], held[:, 2:])


def test_the_shift_stays_in_its_search_range(
        walk: tuple[np.ndarray, dict[str, np.ndarray]]) -> None:
    truth, arrays = walk
    held = truth.copy()
    held[10:20, 1] += 0.3
    res = window_shifts(arrays, held, WindowShiftOptions(window_frames=10, xy_range_m=0.1))
    assert all(np.abs(w.shift_m).max() <= 0.1 + 1e-9 for w in res.windows)


def test_storeys_other_than_the_windows_are_left_out(
        demo: Scene, walk: tuple[np.ndarray, dict[str, np.ndarray]]) -> None:
    truth, arrays = walk
    # The same plan once more, shifted 0.15 m in y, one storey up: it must not pull the walk.
    up = dict(arrays)
    up["segments"] = np.concatenate([demo.segments, demo.segments + np.array([0, 0.15, 0, 0.15])])
    up["segment_class"] = np.concatenate([demo.segment_class, demo.segment_class])
    up["segment_z"] = np.concatenate([np.tile([0.0, 2.8], (len(demo.segments), 1)),
                                      np.tile([3.0, 5.8], (len(demo.segments), 1))])
    held = truth.copy()
    held[10:20, 1] += 0.15
    res = window_shifts(up, held, WindowShiftOptions(window_frames=10))
    assert res.moved == list(range(10, 20))
    assert np.abs(res.poses[10:20, 1] - truth[10:20, 1]).max() < 0.025
