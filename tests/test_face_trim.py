"""The camera's wall samples off their face (bimcap.pipeline.face_trim): a window frame or a
counter backsplash 3 cm in front of one wall is labelled wall by the geometric segmenter, and the
Cauchy loss at the 2 cm noise scale gives those samples their full pull, one way in every frame
(Duplex_A's fixed point, docs/generalization.md). Dropped per frame and segment against the
group's median, they no longer move the poses."""

from __future__ import annotations

import numpy as np
import pytest

from _solver_helpers import core
from bimcap.errors import InputError
from bimcap.geometry import invert, transform_points
from bimcap.optimize import SolverOptions, solve
from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors
from bimcap.pipeline.face_trim import FaceTrimOptions, off_face_samples, signed_segment_distance
from bimcap.registration.plan_maps import free_normals

FRAME_DEPTH_M = 0.03  # a window frame's face in front of the wall's


@pytest.fixture(scope="module")
def room_with_frames():
    """The synthetic room, wall samples at 2 mm noise (the refined pixels'), plus for every
    frame a third of its south-wall samples again 3 cm in front of that wall."""
    core()
    sp = make_synthetic_problem(num_frames=20, seed=3, point_noise=0.002,
                                drift_translation_sigma=0.0, drift_yaw_sigma_deg=0.0,
                                drift_pitch_sigma_deg=0.0, fix_first=False)
    p, gt = sp.problem, sp.gt_poses
    rng = np.random.default_rng(7)
    frame = np.asarray(p.wall_frame)
    p_world = transform_points(gt[frame], np.asarray(p.wall_p_in_cam))
    south = np.abs(p_world[:, 1]) < 0.01
    pick = south & (rng.random(len(frame)) < 1 / 3)
    assert pick.sum() > 50
    fittings = p_world[pick] + [0.0, FRAME_DEPTH_M, 0.0]
    cam_from_world = invert(gt[frame[pick]])
    fittings_in_cam = transform_points(cam_from_world, fittings)
    all_frame = np.r_[frame, frame[pick]]
    order = np.argsort(all_frame, kind="stable")
    is_fitting = np.r_[np.zeros(len(frame), bool), np.ones(int(pick.sum()), bool)][order]
    q = p.replace(wall_frame=all_frame[order].astype(np.int32),
                  wall_p_in_cam=np.r_[np.asarray(p.wall_p_in_cam), fittings_in_cam][order],
                  segment_normal=free_normals(p.segments, p.segment_class))
    return sp, q, is_fitting


def _options() -> SolverOptions:
    opts = SolverOptions().with_terms("F+W+Ce")
    opts.terms["wall"].sigma = 0.02  # the scan's noise scale of the refine's last solve
    return opts


def test_fittings_in_front_of_a_wall_pull_and_are_dropped(room_with_frames) -> None:
    sp, q, is_fitting = room_with_frames
    first = solve(q, _options())
    err_all, _ = pose_errors(first.poses, sp.gt_poses)
    mean_y = float(np.mean(first.poses[:, 1] - sp.gt_poses[:, 1]))
    # negative control: the Cauchy loss at 2 cm keeps the 3 cm fittings' pull: the wall looks
    # nearer, the cameras move towards it (-y)
    assert err_all > 0.002 and mean_y < -0.002
    trim = off_face_samples(q.wall_frame, q.wall_p_in_cam, first.wall_segment, first.poses,
                            q.segments, q.segment_normal, np.ones(len(is_fitting), bool))
    assert trim.spread_m < 0.004 and 0.01 <= trim.gate_m < 0.02
    assert (~trim.keep[is_fitting]).mean() > 0.95, "the fittings are dropped"
    assert trim.keep[~is_fitting].mean() > 0.99, "the wall's own samples are kept"
    kept = q.replace(wall_frame=np.asarray(q.wall_frame)[trim.keep],
                     wall_p_in_cam=np.asarray(q.wall_p_in_cam)[trim.keep])
    clean = q.replace(wall_frame=np.asarray(q.wall_frame)[~is_fitting],
                      wall_p_in_cam=np.asarray(q.wall_p_in_cam)[~is_fitting])
    err_clean, _ = pose_errors(solve(clean, _options()).poses, sp.gt_poses)
    after = solve(kept, _options()).poses
    err_kept, _ = pose_errors(after, sp.gt_poses)
    assert err_kept < err_clean + 0.0003 and err_kept < err_all / 2
    assert abs(float(np.mean(after[:, 1] - sp.gt_poses[:, 1]))) < 0.0008


def test_pose_error_drops_the_same_samples(room_with_frames) -> None:
    """The face is looked for within the gate of where the pose puts it: a frame 3 mm off drops
    the same samples; a frame 5 cm off finds no face there, its groups are centred on their
    medians, and the same samples are dropped too."""
    _, q, is_fitting = room_with_frames
    first = solve(q, _options())
    cand = np.ones(len(is_fitting), bool)
    args = (q.wall_frame, q.wall_p_in_cam, first.wall_segment)
    a = off_face_samples(*args, first.poses, q.segments, q.segment_normal, cand)
    near, far = first.poses.copy(), first.poses.copy()
    near[:, :2] += [0.002, -0.002]
    far[:, :2] += [0.05, -0.05]
    b = off_face_samples(*args, near, q.segments, q.segment_normal, cand)
    c = off_face_samples(*args, far, q.segments, q.segment_normal, cand)
    assert a.dropped > 50 and (a.keep == b.keep).mean() > 0.995
    assert (a.keep == c.keep).mean() > 0.995


def test_only_candidates_are_dropped_and_shapes_are_checked(room_with_frames) -> None:
    _, q, is_fitting = room_with_frames
    first = solve(q, _options())
    none = off_face_samples(q.wall_frame, q.wall_p_in_cam, first.wall_segment, first.poses,
                            q.segments, q.segment_normal, np.zeros(len(is_fitting), bool))
    assert none.keep.all() and none.dropped == 0
    with pytest.raises(InputError, match="same samples"):
        off_face_samples(q.wall_frame, q.wall_p_in_cam, first.wall_segment[:-1], first.poses,
                         q.segments, q.segment_normal, np.ones(len(is_fitting), bool))
    with pytest.raises(InputError, match="must be > 0"):
        FaceTrimOptions(sigmas=0.0)


def test_signed_distance_is_positive_on_the_free_side() -> None:
    seg = np.array([[0.0, 0.0, 4.0, 0.0]])
    normal = np.array([[0.0, 1.0]])
    p = np.array([[1.0, 0.02, 1.0], [2.0, -0.01, 1.0], [5.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    d = signed_segment_distance(p, seg, normal, np.array([0, 0, 0, -1]))
    assert d[:3] == pytest.approx([0.02, -0.01, 1.0])
    assert np.isnan(d[3])


def test_a_thick_face_is_kept_whole() -> None:
    """A curtain wall's mullions and glazing spread 1–8 cm in front of its segment (SampleHouse4):
    no one thin face, so none of its samples is dropped; a thin wall's fittings in the same run
    are."""
    rng = np.random.default_rng(0)
    seg = np.array([[0.0, 0.0, 6.0, 0.0]])
    normal = np.array([[0.0, 1.0]])
    poses = np.tile([0.0, 3.0, 1.5, 0.0, 0.0, 0.0, 1.0], (6, 1))  # identity rotation
    frames, points = [], []
    for f in range(6):
        x = rng.uniform(0.5, 5.5, 200)
        if f < 5:  # a thin wall, a fifth of it a fitting 3 cm in front
            y = rng.normal(0.0, 0.002, 200) + np.where(np.arange(200) < 40, 0.03, 0.0)
        else:  # a curtain wall
            y = rng.uniform(-0.01, 0.06, 200)
        frames.append(np.full(200, f))
        points.append(np.stack([x, y - 3.0, rng.uniform(0.2, 2.5, 200) - 1.5], axis=1))
    frame = np.concatenate(frames)
    trim = off_face_samples(frame, np.concatenate(points), np.zeros(len(frame), np.int32),
                            poses, seg, normal, np.ones(len(frame), bool))
    assert trim.keep[frame == 5].all()
    fitting = np.tile(np.arange(200) < 40, 6) & (frame < 5)
    assert (~trim.keep[fitting]).all() and trim.keep[(frame < 5) & ~fitting].mean() > 0.99
