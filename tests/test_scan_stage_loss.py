"""The last solve (from converged poses, at the scan's 2 cm noise scale) gives BIM samples far off
their face no pull: Tukey's biweight, not Cauchy, whose influence decays only as σ²/r.

Furniture, door leaves and fittings 5-30 cm in front of a wall are sampled like the wall (the
simulator's clutter; the Duplex model from the ground truth moved 0.3 cm in y with Cauchy).
Here a third of each frame's wall samples sit 12 cm off along +x: from the truth, the poses must
stay where they are (the samples are otherwise noise-free).
"""

from __future__ import annotations

import copy

import numpy as np

from _solver_helpers import core
from bimcap.geometry.poses import quat_to_rotmat
from bimcap.optimize import solve
from bimcap.optimize.options import Loss
from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors
from bimcap.pipeline.config import RefineConfig
from bimcap.pipeline.refine import SCAN_TUKEY_SCALE, scan_stage_options, solver_options


def _with_clutter(offset_m: float = 0.12, share: float = 1 / 3):
    core()
    sp = make_synthetic_problem(num_frames=20, seed=3, drift_translation_sigma=0.0,
                                drift_yaw_sigma_deg=0.0, drift_pitch_sigma_deg=0.0,
                                point_noise=0.0, pixel_noise=0.0, depth_noise=0.0,
                                fix_first=False)
    p, gt = sp.problem, sp.gt_poses
    frame, p_cam = np.asarray(p.wall_frame), np.asarray(p.wall_p_in_cam).copy()
    rng = np.random.default_rng(0)
    moved = rng.random(len(frame)) < share
    for i in np.flatnonzero(moved):
        rot = quat_to_rotmat(gt[frame[i], 3:])
        p_cam[i] += rot.T @ np.array([offset_m, 0.0, 0.0])  # the point 12 cm off along +x
    return sp, p.replace(poses=gt.copy(), wall_p_in_cam=p_cam)


def test_last_solve_uses_tukey() -> None:
    opts = scan_stage_options(solver_options(RefineConfig()), RefineConfig())
    for key in ("wall", "column", "floor", "ceiling"):
        assert opts.terms[key].loss is Loss.TUKEY
        assert opts.terms[key].loss_scale == SCAN_TUKEY_SCALE
    assert scan_stage_options(solver_options(RefineConfig()), RefineConfig(
        scan_sigma_m=None)).terms["wall"].loss is Loss.CAUCHY


def test_clutter_off_the_wall_does_not_move_the_fixed_point() -> None:
    sp, p = _with_clutter()
    cfg = RefineConfig()
    tukey = scan_stage_options(solver_options(cfg), cfg)
    cauchy = copy.deepcopy(tukey)
    for key in ("wall", "column", "floor", "ceiling"):
        cauchy.terms[key].loss, cauchy.terms[key].loss_scale = Loss.CAUCHY, 1.0
    err_cauchy, _ = pose_errors(solve(p, cauchy).poses, sp.gt_poses)
    err_tukey, _ = pose_errors(solve(p, tukey).poses, sp.gt_poses)
    # noise-free otherwise: without the clutter both stay at the truth exactly
    assert err_cauchy > 0.0015, "negative control: with Cauchy the clutter pulls"
    assert err_tukey < 0.3 * err_cauchy
