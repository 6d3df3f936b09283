"""The odometry term: a frame that no term sees follows its neighbours (ROBUST weighting only)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from _solver_helpers import core
from bimcap.optimize import Problem, SolverOptions, solve
from bimcap.optimize.synthetic import make_synthetic_problem


def _without_frame(problem: Problem, k: int) -> Problem:
    """The problem with every observation of frame ``k`` removed (its pose stays)."""
    a = dict(problem.arrays())
    keep = ~(a["match_frames"] == k).any(axis=1)
    for name in ("match_frames", "match_uv", "match_depth"):
        a[name] = a[name][keep]
    for prefix in ("floor", "ceiling", "wall", "column"):
        keep = a[f"{prefix}_frame"] != k
        for name in (f"{prefix}_frame", f"{prefix}_p_in_cam", f"{prefix}_plane"):
            if name in a and len(a[name]) == len(keep):
                a[name] = a[name][keep]
    return Problem.from_arrays(a)


def test_an_unseen_frame_follows_its_neighbours() -> None:
    core()
    syn = make_synthetic_problem(num_frames=30, seed=5, drift_translation_sigma=0.15,
                                 drift_yaw_sigma_deg=0.5)
    k = 15
    problem = _without_frame(syn.problem, k)
    gt, init = syn.gt_poses, problem.poses

    options = SolverOptions()
    options.odometry.enabled = False
    bare = solve(problem, options)
    # Negative control: nothing reaches frame k, so it keeps the drifted input pose.
    np.testing.assert_array_equal(bare.poses[k], init[k])
    assert not bare.summary.term("odometry").active

    with_odometry = solve(problem, SolverOptions())
    s = with_odometry.summary.term("odometry")
    assert s.active and s.num_residual_blocks == len(init) - 1
    assert s.final_paper_objective == 0.0
    err_init = np.linalg.norm(init[k, :3] - gt[k, :3])
    err_bare = np.linalg.norm(bare.poses[k, :3] - gt[k, :3])
    err = np.linalg.norm(with_odometry.poses[k, :3] - gt[k, :3])
    neighbours = np.linalg.norm(with_odometry.poses[[k - 1, k + 1], :3] - gt[[k - 1, k + 1], :3],
                                axis=1).max()
    assert err_init > 0.2 and err_bare == err_init
    # it moved with its neighbours: off by about the input's own step noise, not by the drift
    assert err < 0.5 * err_init
    assert neighbours < 0.05


def test_paper_weighting_never_adds_the_odometry() -> None:
    core()
    syn = make_synthetic_problem(num_frames=10, seed=1)
    result = solve(syn.problem, SolverOptions.paper().with_terms("G+F"))
    assert not result.summary.term("odometry").active
    o = SolverOptions()
    o.odometry.paper_weight = 1.0
    with pytest.raises(Exception, match=re.escape("odometry.paper_weight")):
        o.check()
