"""The global alignment's threads (``GlobalAlignOptions.num_threads``) and its exact rewrites:
the same bits with any number of threads, and the per-frame fit's batched shifts equal to the
loop of one lookup per shift."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from bimcap.registration.correlative import map_threads, score_volume
from bimcap.registration.errors import RegistrationInputError
from bimcap.registration.global_align import (
    GlobalAlignOptions,
    _frame_fit,
    _free_volume,
    _scan,
    _storey_maps,
    _storeys,
    global_align,
    resolved_threads,
)
from bimcap.registration.icp import Correction2D, rot2
from bimcap.registration.synthetic import demo_scene, demo_tour, poses_along, scan_sequence
from bimcap.sim.drift import DriftParams, apply_drift, to_slam_frame

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def case():
    """A 60-frame Exp 2 walk through the demo scene in a random SLAM frame: (poses, samples,
    plan, storey maps, the scan's wall points)."""
    from bimcap.geometry import Trajectory

    scene = demo_scene(seed=0)
    gt = poses_along(demo_tour(seed=0), 0.25)[224:284]
    drifted = apply_drift(Trajectory(np.arange(len(gt)) * 0.5, gt),
                          DriftParams.from_preset("exp2", seed=1))
    samples = scan_sequence(gt, scene, seed=1, clutter_fraction=0.05)
    slam = to_slam_frame(drifted.init, 1)
    plan = scene.floor_plan()
    opt = GlobalAlignOptions()
    sm = _storey_maps(_storeys(plan, opt.plan_cut_height_m)[0], plan, opt)
    return slam.trajectory.poses, samples, plan, sm, gt


def _points(gt, samples):
    """World wall/column points (M, 2), classes (M,), rays (M, 2), frames (M,) and cameras
    (N, 2) of the true poses (about 3000 points, every frame's share)."""
    scan = _scan(gt, samples)
    k = max(1, len(scan.xy) // 3000)  # every k-th point: about as many as a search scores
    return (scan.xy[::k], scan.cls[::k], scan.view[::k], scan.frame[::k],
            scan.cams[:, :2].copy())


def test_map_threads_keeps_the_order() -> None:
    assert map_threads(lambda x: x * x, range(50), 3) == [x * x for x in range(50)]
    assert map_threads(lambda x: -x, [4], 2) == [-4]
    assert map_threads(lambda x: x, [], 2) == []


def test_the_score_and_free_volumes_are_the_same_bits_with_two_threads(case) -> None:
    _, samples, _, sm, gt = case
    xy, cls, view, _, cams = _points(gt, samples)
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(2.0))
    weight = np.linspace(0.2, 1.0, len(xy))
    one = score_volume(xy, cls, view, sm.maps, sm.centre, yaws, sm.half, p_weight=weight,
                       y_range_m=sm.half_y, num_threads=1)[0]
    for threads in (2, 3):
        many = score_volume(xy, cls, view, sm.maps, sm.centre, yaws, sm.half, p_weight=weight,
                            y_range_m=sm.half_y, num_threads=threads)[0]
        assert many.tobytes() == one.tobytes()
    assert one.max() > 0.1  # not an empty volume
    # Without weights (the binary templates), and one point per yaw block (the smallest blocks).
    a = score_volume(xy[:40], cls[:40], view[:40], sm.maps, sm.centre, yaws, 3.0)[0]
    b = score_volume(xy[:40], cls[:40], view[:40], sm.maps, sm.centre, yaws, 3.0,
                     num_threads=2)[0]
    assert a.tobytes() == b.tobytes()
    m = (one.shape[1] - 1) // 2
    n = (one.shape[2] - 1) // 2
    origin = sm.maps.coarse[0].origin_xy
    res = sm.maps.coarse[0].resolution_m
    f1 = _free_volume(cams, sm.free_map, origin, res, sm.centre, yaws, n, m)
    f2 = _free_volume(cams, sm.free_map, origin, res, sm.centre, yaws, n, m, 2)
    assert f1.tobytes() == f2.tobytes() and f1.max() > 0.5


def _frame_fit_per_shift(corr, p_xy, p_cls, p_view, p_frame, cams_xy, maps, opt):
    """The per-frame fit's best scores, turns and shifts with one lookup per shift (the loop
    that :func:`_frame_fit` batched)."""
    n = len(cams_xy)
    q = corr.apply(p_xy)
    cam = corr.apply(cams_xy)[p_frame]
    view = p_view @ rot2(corr.yaw).T
    count = np.bincount(p_frame, minlength=n).astype(np.float64)
    best, best_still = np.full(n, -1.0), np.full(n, -1.0)
    turn, best_turn, best_shift = np.zeros(n), np.zeros(n), np.zeros((n, 2))
    step = opt.frame_yaw_step_deg
    deltas = np.deg2rad(np.arange(-opt.frame_yaw_deg, opt.frame_yaw_deg + 0.5 * step, step))
    deltas = deltas[np.argsort(np.abs(deltas), kind="stable")]
    s = opt.frame_shift_m
    shifts = [np.zeros(2)] + ([np.array([dx, dy]) for dx in (-s, 0.0, s) for dy in (-s, 0.0, s)
                               if dx or dy] if s > 0 else [])
    for d in deltas:
        r = rot2(float(d))
        qd = (q - cam) @ r.T + cam
        layer = maps.layer_of(p_cls, view @ r.T)
        for sh in shifts:
            sc = maps.fine_score_at(qd + sh, layer)
            mean = np.bincount(p_frame, weights=sc, minlength=n) / np.maximum(count, 1.0)
            better = mean > best
            best[better], best_turn[better], best_shift[better] = mean[better], d, sh
            if not sh.any():
                better = mean > best_still
                best_still[better], turn[better] = mean[better], d
    has = count > 0
    return (float(np.maximum(best[has], 0.0).mean()), float(best_turn[has].mean()),
            best_shift[has].mean(0), turn)


@pytest.mark.parametrize("shift_m", [0.0, 0.2])
def test_the_frame_fit_with_its_shifts_batched_is_the_loop_bit_for_bit(case, shift_m) -> None:
    _, samples, _, sm, gt = case
    xy, cls, view, frame, cams = _points(gt, samples)
    opt = GlobalAlignOptions(frame_shift_m=shift_m)
    # A placement a little off (a turn and a shift to take out), and a frame without points.
    corr = Correction2D(np.deg2rad(1.5), np.array([0.15, -0.1]), cams.mean(0))
    keep = frame != 7
    args = (corr, xy[keep], cls[keep], view[keep], frame[keep], cams, sm.maps, opt)
    fit, q_turned, cam, turn, shift = _frame_fit(*args)
    ref_fit, ref_turn, ref_shift, ref_turns = _frame_fit_per_shift(*args)
    assert fit == ref_fit and turn == ref_turn and shift.tobytes() == ref_shift.tobytes()
    assert fit > 0.3
    # The points turned by each frame's best turn without a shift.
    c, s = np.cos(ref_turns)[frame[keep]], np.sin(ref_turns)[frame[keep]]
    rel = corr.apply(xy[keep]) - cam
    expect = cam + np.c_[c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]]
    assert q_turned.tobytes() == expect.tobytes()


def test_global_align_is_the_same_with_one_and_two_threads(case) -> None:
    poses, samples, plan, _, _ = case
    one = global_align(poses, samples, plan, GlobalAlignOptions(num_threads=1))
    two = global_align(poses, samples, plan, GlobalAlignOptions(num_threads=2))
    assert one.world_from_slam.tobytes() == two.world_from_slam.tobytes()
    assert one.ratio == two.ratio and one.ambiguous == two.ambiguous
    assert ([h.to_dict() for h in one.hypotheses] == [h.to_dict() for h in two.hypotheses])


def _child_threads(out) -> None:
    out.put(resolved_threads(0))


def test_all_cores_except_in_a_pool_worker() -> None:
    assert resolved_threads(3) == 3 and resolved_threads(1) == 1
    assert resolved_threads(0) >= 1
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    p = ctx.Process(target=_child_threads, args=(out,))
    p.start()
    got = out.get(timeout=60)
    p.join(60)
    assert got == 1  # a worker process: one thread (the pool has the cores)
    with pytest.raises(RegistrationInputError, match="num_threads"):
        GlobalAlignOptions(num_threads=-1)
