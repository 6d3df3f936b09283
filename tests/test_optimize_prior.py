"""The pose prior: F alone holds x, y and yaw; options, summary and PAPER weighting."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _solver_helpers import core
from bimcap.optimize import SolverInputError, SolverOptions, solve
from bimcap.optimize.synthetic import SyntheticProblem, make_synthetic_problem


@pytest.fixture(scope="module")
def synthetic() -> SyntheticProblem:
    core()
    return make_synthetic_problem(
        num_frames=40, seed=11, drift_translation_sigma=0.03, drift_yaw_sigma_deg=0.4
    )


def _plan_change(after: np.ndarray, before: np.ndarray) -> tuple[float, float]:
    """Largest xy change (m) and rotation about the world z (degrees) between (N, 7) pose sets."""
    xy = float(np.linalg.norm(after[:, :2] - before[:, :2], axis=1).max())
    rotvec = (Rotation.from_quat(after[:, 3:])
              * Rotation.from_quat(before[:, 3:]).inv()).as_rotvec()
    return xy, float(np.degrees(np.abs(rotvec[:, 2])).max())


def test_prior_holds_what_the_floor_does_not_see(synthetic: SyntheticProblem) -> None:
    p = synthetic.problem
    options = SolverOptions().with_terms("F")
    assert options.prior.enabled  # with_terms leaves the prior on
    options.odometry.enabled = False  # this test is about the prior alone
    result = solve(p, options)
    xy, yaw = _plan_change(result.poses, p.poses)
    assert xy < 0.01 and yaw < 0.1
    # F still does its job: the height comes near the truth where a frame sees enough floor (as
    # close as without the prior: the worst frame is 4 cm off either way).
    seen = np.bincount(p.floor_frame, minlength=len(p.poses)) >= 20
    dz0 = np.abs(p.poses[seen, 2] - synthetic.gt_poses[seen, 2]).max()
    dz = np.abs(result.poses[seen, 2] - synthetic.gt_poses[seen, 2]).max()
    assert dz0 > 0.1 and dz < 0.05
    prior = result.summary.term("prior")
    # One block per free pose that F reached: frame 0 is fixed, frames without floor points stay
    # out.
    reached = np.unique(p.floor_frame)
    assert prior.active and prior.num_residual_blocks == np.count_nonzero(reached != 0) == 34
    assert result.summary.num_free_poses == prior.num_residual_blocks
    assert prior.num_residuals == 6 * prior.num_residual_blocks
    assert prior.final_cost > 0 and prior.final_paper_objective == 0.0

    # Negative control: without the prior and with one Ceres row per residual (ambient
    # Jacobians times Ceres' Plus Jacobian), Levenberg-Marquardt turns the unobserved yaw.
    options.prior.enabled = False
    options.compress_batches = False
    bare = solve(p, options)
    assert not bare.summary.term("prior").active
    assert _plan_change(bare.poses, p.poses)[1] > 1.0
    # (Compressed, the default, a level floor's yaw column is exactly zero in the tangent space,
    # but frames with 6 floor points or fewer stay rows: 0.45° here. solver_test has the case.)


def test_paper_weighting_never_adds_the_prior(synthetic: SyntheticProblem) -> None:
    options = SolverOptions.paper().with_terms("F+Ce")
    assert options.prior.enabled
    s = solve(synthetic.problem, options).summary
    prior = s.term("prior")
    assert not prior.active and prior.num_residual_blocks == 0 and prior.final_cost == 0.0
    # The Ceres cost is then exactly half the peers' objective.
    assert s.final_cost == pytest.approx(0.5 * s.final_paper_objective, rel=1e-12)


def test_prior_cost_matches_the_formula(synthetic: SyntheticProblem) -> None:
    """½ Σ ‖r‖² with r = [(t - t0) / σt ; 2 vec(q0⁻¹ q) / σr], recomputed from the result."""
    p = synthetic.problem
    options = SolverOptions().with_terms("F+W")
    options.prior.sigma = 0.5
    options.prior.params["sigma_r_deg"] = 5.0
    result = solve(p, options)
    free = np.ones(len(p.poses), bool)
    free[0] = False
    t = (result.poses[free, :3] - p.poses[free, :3]) / 0.5
    delta = (Rotation.from_quat(p.poses[free, 3:]).inv()
             * Rotation.from_quat(result.poses[free, 3:])).as_quat()
    delta *= np.where(delta[:, 3:] < 0, -1.0, 1.0)  # w >= 0
    rot = 2.0 * delta[:, :3] / np.radians(5.0)
    expected = 0.5 * (np.sum(t**2) + np.sum(rot**2))
    assert result.summary.term("prior").final_cost == pytest.approx(expected, rel=1e-9)


def test_prior_options_round_trip_and_checks() -> None:
    o = SolverOptions()
    assert (o.prior.sigma, o.prior.params["sigma_r_deg"], o.prior.paper_weight) == (2.0, 20.0, 0.0)
    o.prior.sigma = 0.25
    o.prior.params["sigma_r_deg"] = 7.5
    flat = o.to_flat()
    assert flat["prior.sigma"] == "0.25" and flat["prior.sigma_r_deg"] == "7.5"
    assert SolverOptions.from_flat(flat) == o
    assert sorted(flat) == sorted(core().option_keys())
    assert SolverOptions().term("prior") is not None
    with pytest.raises(SolverInputError) as err:
        SolverOptions.from_flat({"prior.paper_weight": "0.1"})
    assert err.value.field == "prior.paper_weight"
    with pytest.raises(SolverInputError) as err:
        SolverOptions.from_flat({"prior.sigma_r_deg": "0"})
    assert err.value.field == "prior.sigma_r_deg"
    # A file written before the key was renamed is still read.
    assert SolverOptions.from_flat({"prior_sigma_r_deg": "7.5"}).prior.params["sigma_r_deg"] == 7.5
    with pytest.raises(AttributeError, match="prior_sigma_r_deg"):
        o.prior_sigma_r_deg = 5.0  # type: ignore[attr-defined]  # never set silently
    # The core applies the same rule.
    with pytest.raises(Exception, match=re.escape("prior.paper_weight")):
        core().solve(make_synthetic_problem(num_frames=5, seed=0).problem.arrays(),
                     {**SolverOptions().to_flat(), "prior.paper_weight": "1"})
