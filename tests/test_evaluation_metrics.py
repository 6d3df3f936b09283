"""Trajectory metrics: evo oracle (none/SE(3)/Sim(3)), yaw/pitch/roll, invariants, association."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.evaluation.alignment import umeyama_alignment
from bimcap.evaluation.errors import EvaluationError
from bimcap.evaluation.metrics import (
    AlignMode,
    associate,
    evaluate_trajectory,
    trajectory_metrics,
)
from bimcap.geometry.poses import compose
from bimcap.geometry.trajectory import Trajectory, read_tum


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.normal(0.0, 0.3, (n, 3)), axis=0)
    q = Rotation.random(n, random_state=seed).as_quat()
    return np.hstack([t, q])


@pytest.fixture(scope="module")
def oracle(oracles_dir: Path) -> tuple[Trajectory, Trajectory, dict]:
    d = oracles_dir / "trajectory"
    expected = json.loads((d / "trajectory_expected.json").read_text())["cases"]
    return read_tum(d / "est.tum"), read_tum(d / "gt.tum"), expected


@pytest.mark.needs_shared
@pytest.mark.parametrize("mode", ["none", "se3", "sim3"])
def test_ate_equals_evo(oracle: tuple[Trajectory, Trajectory, dict], mode: str) -> None:
    est, gt, expected = oracle
    m = evaluate_trajectory(est, gt, AlignMode(mode))
    x = expected[mode]
    assert m.n_matched == 120
    assert m.ate_pos_m.rmse == pytest.approx(x["trans_rmse_m"], abs=1e-9, rel=0)
    assert m.ate_pos_m.mean == pytest.approx(x["trans_mean_m"], abs=1e-9, rel=0)
    assert m.ate_rot_deg.rmse == pytest.approx(x["rot_rmse_deg"], abs=1e-9, rel=0)
    assert m.ate_rot_deg.mean == pytest.approx(x["rot_mean_deg"], abs=1e-9, rel=0)
    # the alignment must change something, and Sim(3) must differ from SE(3)
    if mode == "none":
        assert m.alignment is None
    else:
        assert m.ate_pos_m.rmse < expected["none"]["trans_rmse_m"] - 0.1
        assert m.alignment is not None
        assert (m.alignment.scale == 1.0) == (mode == "se3")


@pytest.mark.needs_shared
def test_yaw_pitch_roll_equal_oracle(oracle: tuple[Trajectory, Trajectory, dict]) -> None:
    est, gt, expected = oracle
    m = evaluate_trajectory(est, gt)
    x = expected["none"]
    assert m.yaw_rmse_deg == pytest.approx(x["yaw_rmse_deg"], abs=1e-9, rel=0)
    assert m.pitch_rmse_deg == pytest.approx(x["pitch_rmse_deg"], abs=1e-9, rel=0)
    assert m.roll_rmse_deg == pytest.approx(x["roll_rmse_deg"], abs=1e-9, rel=0)
    assert "ZYX" in str(m.to_dict()["ypr_convention"])
    table = m.format_table()
    assert "ATE_pos" in table and "as_euler('ZYX')" in table


def test_identical_trajectories_give_zero() -> None:
    poses = _random_poses(30, 1)
    m = trajectory_metrics(poses, poses)
    assert m.ate_pos_m.rmse == 0.0
    assert m.ate_rot_deg.rmse < 1e-6
    assert max(m.yaw_rmse_deg, m.pitch_rmse_deg, m.roll_rmse_deg) < 1e-6


def test_constant_offset_gives_that_ate() -> None:
    gt = _random_poses(40, 2)
    est = gt.copy()
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    est[:, :3] += 0.1 * direction
    m = trajectory_metrics(est, gt)
    assert m.ate_pos_m.rmse == pytest.approx(0.1, abs=1e-12)
    assert m.ate_pos_m.mean == pytest.approx(0.1, abs=1e-12)
    assert m.ate_pos_m.max == pytest.approx(0.1, abs=1e-12)
    assert m.ate_rot_deg.rmse == pytest.approx(0.0, abs=1e-6)


def test_pure_yaw_error() -> None:
    gt = _random_poses(50, 3)
    r_gt = Rotation.from_quat(gt[:, 3:])
    est = gt.copy()
    est[:, 3:] = (Rotation.from_euler("z", 5.0, degrees=True) * r_gt).as_quat()
    m = trajectory_metrics(est, gt)
    assert m.yaw_rmse_deg == pytest.approx(5.0, abs=1e-9)
    assert m.pitch_rmse_deg == pytest.approx(0.0, abs=1e-9)
    assert m.roll_rmse_deg == pytest.approx(0.0, abs=1e-9)
    assert m.ate_rot_deg.rmse == pytest.approx(5.0, abs=1e-9)
    assert m.ate_pos_m.rmse == 0.0


def test_pure_pitch_error_is_not_yaw() -> None:
    gt = _random_poses(20, 4)
    est = gt.copy()
    est[:, 3:] = (
        Rotation.from_euler("y", 2.0, degrees=True) * Rotation.from_quat(gt[:, 3:])
    ).as_quat()
    m = trajectory_metrics(est, gt)
    assert m.pitch_rmse_deg == pytest.approx(2.0, abs=1e-9)
    assert m.yaw_rmse_deg == pytest.approx(0.0, abs=1e-9)


def test_rigid_motion_of_both_leaves_unaligned_ate_unchanged() -> None:
    gt = _random_poses(60, 5)
    est = compose(gt, _random_poses(60, 6) * [0.05, 0.05, 0.05, 0.1, 0.1, 0.1, 1.0])
    est[:, 3:] /= np.linalg.norm(est[:, 3:], axis=1, keepdims=True)
    motion = np.array([3.0, -1.0, 0.5, *Rotation.from_rotvec([0.3, -0.2, 1.0]).as_quat()])
    m0 = trajectory_metrics(est, gt)
    m1 = trajectory_metrics(compose(motion, est), compose(motion, gt))
    assert m0.ate_pos_m.rmse > 0.01
    assert m1.ate_pos_m.rmse == pytest.approx(m0.ate_pos_m.rmse, abs=1e-12)
    assert m1.ate_rot_deg.rmse == pytest.approx(m0.ate_rot_deg.rmse, abs=1e-9)


@pytest.mark.parametrize("mode", [AlignMode.SE3, AlignMode.SIM3])
def test_alignment_undoes_a_known_transform(mode: AlignMode) -> None:
    gt = _random_poses(25, 7)
    motion = np.array([1.0, 2.0, 3.0, *Rotation.from_rotvec([0.1, 0.2, -0.4]).as_quat()])
    est = compose(motion, gt)
    scale = 1.0 if mode is AlignMode.SE3 else 0.8
    est[:, :3] *= scale
    m = trajectory_metrics(est, gt, mode)
    assert m.ate_pos_m.rmse < 1e-9
    assert m.ate_rot_deg.rmse < 1e-6
    assert m.alignment is not None and m.alignment.scale == pytest.approx(1.0 / scale, abs=1e-12)
    assert trajectory_metrics(est, gt).ate_pos_m.rmse > 1.0


def test_umeyama_rejects_degenerate_points() -> None:
    x = np.zeros((5, 3))
    with pytest.raises(EvaluationError, match="degenerate"):
        umeyama_alignment(x, x)


def test_associate_exact_nearest_and_none() -> None:
    t_gt = np.arange(10, dtype=float)
    i_est, i_gt = associate(np.array([2.0, 4.004, 7.5]), t_gt, max_dt=0.01)
    assert i_est.tolist() == [0, 1] and i_gt.tolist() == [2, 4]
    i_est, i_gt = associate(t_gt + 0.002, t_gt[3:6], max_dt=0.01)  # longer estimate
    assert i_est.tolist() == [3, 4, 5] and i_gt.tolist() == [0, 1, 2]
    with pytest.raises(EvaluationError, match="no timestamps match"):
        associate(t_gt + 100.0, t_gt)


def test_evaluate_trajectory_uses_matched_subset() -> None:
    poses = _random_poses(10, 8)
    gt = Trajectory(np.arange(10.0), poses)
    est = Trajectory(np.arange(2.0, 6.0), poses[2:6])
    m = evaluate_trajectory(est, gt)
    assert (m.n_matched, m.n_est, m.n_gt) == (4, 4, 10)
    assert m.ate_pos_m.rmse == 0.0
    assert m.frame_errors is not None and m.frame_errors.timestamps.tolist() == [2.0, 3.0, 4.0, 5.0]
    json.dumps(m.to_dict(), allow_nan=False)
