"""The pose prior on the paper's ablation rows (not a test; run by hand).

    PYTHONPATH=python python bench/bench_pose_prior.py [--frames 40] [--seed 11]

For each term set, ROBUST weighting with and without the pose prior on the synthetic problem of
:mod:`bimcap.optimize.synthetic`: the largest change of the input poses in xy (m) and about the
world z (degrees; the z part of the rotation vector), and the pose RMSE against the truth before
and after. Without the prior, directions a term set leaves unobserved drift (F alone: yaw).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from bimcap.optimize import PlaneMode, SolverOptions, solve
from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors

ROWS = ("F", "Ce", "F+Ce", "W+Co", "G+F+Ce+W+Co")


def _plan_change(after: np.ndarray, before: np.ndarray) -> tuple[float, float]:
    xy = float(np.linalg.norm(after[:, :2] - before[:, :2], axis=1).max())
    rotvec = (Rotation.from_quat(after[:, 3:])
              * Rotation.from_quat(before[:, 3:]).inv()).as_rotvec()
    return xy, float(np.degrees(np.abs(rotvec[:, 2])).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args()
    syn = make_synthetic_problem(num_frames=args.frames, seed=args.seed,
                                 drift_translation_sigma=0.03, drift_yaw_sigma_deg=0.4)
    p = syn.problem
    t0, r0 = pose_errors(p.poses, syn.gt_poses)
    print(f"input: RMSE {t0:.3f} m / {r0:.2f} deg")
    print(f"{'terms':12} {'planes':6} {'prior':5} {'max dxy m':>10} {'max dyaw deg':>13} "
          f"{'RMSE m':>8} {'RMSE deg':>9} {'s':>6}")
    for terms in ROWS:
        for plane_mode in (PlaneMode.BIM, PlaneMode.FACAP):
            for prior in (False, True):
                options = SolverOptions(plane_mode=plane_mode).with_terms(terms)
                options.prior.enabled = prior
                result = solve(p, options, check=False)
                xy, yaw = _plan_change(result.poses, p.poses)
                t, r = pose_errors(result.poses, syn.gt_poses)
                print(f"{terms:12} {plane_mode.value:6} {'on' if prior else 'off':5} "
                      f"{xy:10.4f} {yaw:13.4f} "
                      f"{t:8.3f} {r:9.2f} {result.summary.time_s:6.2f}")


if __name__ == "__main__":
    main()
