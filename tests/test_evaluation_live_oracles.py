"""Trajectory metrics against evo computed live (no ../shared needed).

The reference numbers come from the real ``evo`` package (``pip install -e '.[test]'``) through its
Python API, exactly as ``evo_ape tum gt.tum est.tum [-a | -as]`` computes them: TUM files written
to ``tmp_path`` and read back by evo's own reader, association with ``sync.associate_trajectories``
(reference first), Umeyama alignment with ``PoseTrajectory3D.align``, then ``metrics.APE`` for the
translation part (metres) and the rotation angle (degrees). bimcap must agree to 1e-9 relative.

bimcap has no RPE, so only APE is compared. The map-metrics package (MME/MPV oracle) is not used
here: its only wheels (0.0.5, the newest) ship compiled modules for CPython 3.6 to 3.10 only.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.evaluation.alignment import umeyama_alignment
from bimcap.evaluation.metrics import AlignMode, ErrorStats, evaluate_trajectory
from bimcap.geometry.trajectory import Trajectory, read_tum, write_tum

_REASON = "evo is not installed (it is in the [test] extra: pip install -e '.[test]')"
evo_geometry = pytest.importorskip("evo.core.geometry", reason=_REASON)
evo_metrics = pytest.importorskip("evo.core.metrics", reason=_REASON)
evo_sync = pytest.importorskip("evo.core.sync", reason=_REASON)
evo_file = pytest.importorskip("evo.tools.file_interface", reason=_REASON)

#: Association tolerance, seconds (evo's default ``--t_max_diff``).
MAX_DT = 0.01
#: Relative agreement demanded of every statistic.
REL = 1e-9
SEEDS = [0, 1, 2, 3, 4, 5]
STATS = ("rmse", "mean", "median", "std", "min", "max")


@dataclass(frozen=True)
class Case:
    """One random ground truth / estimate pair written as TUM files.

    Attributes
    ----------
    gt_path, est_path: the TUM files (``world_from_cam``, ``tx ty tz qx qy qz qw``).
    scale: the scale of the global offset applied to the estimate (1.0: an SE(3) offset).
    """

    gt_path: Path
    est_path: Path
    scale: float


def _random_walk(rng: np.random.Generator, n: int) -> tuple[np.ndarray, Rotation]:
    """A smooth camera walk: (n, 3) positions in metres and n world_from_cam rotations."""
    steps = rng.normal(0.0, 1.0, (n, 3)) * [0.25, 0.25, 0.05] + [0.2, 0.05, 0.0]
    p_in_world = np.cumsum(steps, axis=0) + rng.uniform(-5.0, 5.0, 3)
    increments = Rotation.from_rotvec(rng.normal(0.0, 0.08, (n, 3)))
    rot = [Rotation.from_rotvec(rng.uniform(-np.pi, np.pi, 3))]
    for k in range(1, n):
        rot.append(rot[-1] * increments[k])
    return p_in_world, Rotation.concatenate(rot)


def _make_case(tmp_path: Path, seed: int) -> Case:
    """Ground truth walk and an estimate = gt + drift + noise, seen through a global offset.

    The estimate's world is ``est_world = s (R_o gt_world + t_o)`` (a Sim(3) offset on odd seeds,
    SE(3) on even ones). Its timestamps jitter by up to 4 ms, some poses are missing on one side
    (the estimate on even seeds, the ground truth on odd ones, so evo's "shorter trajectory first"
    rule is exercised both ways) and a few estimate poses lie outside the ground truth's time span.
    """
    rng = np.random.default_rng(seed)
    n = 150 + 10 * seed
    t_gt = np.arange(n, dtype=np.float64) * 0.1 + 100.0
    p_gt, r_gt = _random_walk(rng, n)

    # drift grows with time; noise is white: ~2 cm and ~0.5° per frame
    frac = np.arange(n)[:, None] / n
    p_est = p_gt + frac * rng.normal(0.0, 0.5, 3) + rng.normal(0.0, 0.02, (n, 3))
    rot_drift = Rotation.from_rotvec(frac * rng.normal(0.0, 0.1, 3))
    rot_noise = Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(0.5), (n, 3)))
    r_est = rot_drift * r_gt * rot_noise

    scale = 1.0 if seed % 2 == 0 else float(rng.uniform(0.5, 2.0))
    r_offset = Rotation.from_rotvec(rng.normal(0.0, 0.6, 3))
    t_offset = rng.uniform(-3.0, 3.0, 3)
    p_est = scale * (r_offset.apply(p_est) + t_offset)
    r_est = r_offset * r_est

    t_est = t_gt + rng.uniform(-0.004, 0.004, n)
    gt = np.hstack([p_gt, r_gt.as_quat()])
    est = np.hstack([p_est, r_est.as_quat()])
    drop = rng.random(n) < 0.15
    keep_gt = ~drop if seed % 2 else np.ones(n, dtype=bool)
    keep_est = ~drop if seed % 2 == 0 else np.ones(n, dtype=bool)
    # estimate poses a second before and after the ground truth: never matched
    three = 0.1 * np.arange(3)
    t_extra = np.concatenate([t_gt[0] - 1.0 + three, t_gt[-1] + 1.0 + three])
    est_extra = np.vstack([est[:3], est[-3:]])
    t_est_all = np.concatenate([t_est[keep_est], t_extra])
    order = np.argsort(t_est_all)

    gt_path, est_path = tmp_path / f"gt_{seed}.tum", tmp_path / f"est_{seed}.tum"
    write_tum(gt_path, Trajectory(t_gt[keep_gt], gt[keep_gt]))
    write_tum(est_path, Trajectory(t_est_all[order], np.vstack([est[keep_est], est_extra])[order]))
    return Case(gt_path, est_path, scale)


def _evo_ape(case: Case, mode: AlignMode) -> dict[str, Any]:
    """What ``evo_ape tum gt est [-a | -as] --t_max_diff 0.01`` computes, via evo's API."""
    traj_ref = evo_file.read_tum_trajectory_file(case.gt_path)
    traj_est = evo_file.read_tum_trajectory_file(case.est_path)
    traj_ref, traj_est = evo_sync.associate_trajectories(traj_ref, traj_est, max_diff=MAX_DT)
    traj_est = copy.deepcopy(traj_est)
    alignment = None
    if mode is not AlignMode.NONE:
        alignment = traj_est.align(traj_ref, correct_scale=mode is AlignMode.SIM3)
    out: dict[str, Any] = {"ref": traj_ref, "alignment": alignment}
    for key, relation in (
        ("trans", evo_metrics.PoseRelation.translation_part),
        ("rot", evo_metrics.PoseRelation.rotation_angle_deg),
    ):
        ape = evo_metrics.APE(relation)
        ape.process_data((traj_ref, traj_est))
        out[key] = ape
    return out


def _assert_stats_equal(ours: ErrorStats, ape: Any, what: str) -> None:
    theirs = ape.get_all_statistics()
    for name in STATS:
        assert getattr(ours, name) == pytest.approx(theirs[name], rel=REL, abs=0.0), (
            f"{what} {name}: bimcap {getattr(ours, name)!r} vs evo {theirs[name]!r}"
        )


@pytest.mark.parametrize("mode", list(AlignMode))
@pytest.mark.parametrize("seed", SEEDS)
def test_ape_equals_live_evo(tmp_path: Path, seed: int, mode: AlignMode) -> None:
    case = _make_case(tmp_path, seed)
    evo = _evo_ape(case, mode)
    m = evaluate_trajectory(read_tum(case.est_path), read_tum(case.gt_path), mode, MAX_DT)

    # the same pairs: count and ground-truth stamps of the matched poses
    assert m.n_matched == evo["ref"].num_poses
    assert m.frame_errors is not None
    np.testing.assert_array_equal(m.frame_errors.timestamps, evo["ref"].timestamps)
    assert 0.8 * min(m.n_est, m.n_gt) < m.n_matched <= min(m.n_est, m.n_gt)

    _assert_stats_equal(m.ate_pos_m, evo["trans"], f"seed {seed} {mode.value} APE trans [m]")
    _assert_stats_equal(m.ate_rot_deg, evo["rot"], f"seed {seed} {mode.value} APE rot [deg]")
    # per frame: relative 1e-9, with 1e-12 (m or deg) for errors that happen to be near zero
    np.testing.assert_allclose(m.frame_errors.trans_m, evo["trans"].error, rtol=REL, atol=1e-12)
    np.testing.assert_allclose(m.frame_errors.rot_deg, evo["rot"].error, rtol=REL, atol=1e-12)

    if mode is AlignMode.NONE:
        assert m.alignment is None
        # the global offset dominates the unaligned error
        assert m.ate_pos_m.rmse > 0.3
    else:
        r_a, t_a, s = evo["alignment"]
        assert m.alignment is not None
        np.testing.assert_allclose(m.alignment.rotation, r_a, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(m.alignment.translation, t_a, rtol=REL, atol=1e-12)
        assert m.alignment.scale == pytest.approx(s, rel=REL, abs=0.0)
        if mode is AlignMode.SIM3:
            # the alignment recovers the offset's scale up to what the drift distorts
            assert m.alignment.scale == pytest.approx(1.0 / case.scale, rel=0.2)
        else:
            assert m.alignment.scale == 1.0


@pytest.mark.parametrize("with_scale", [False, True])
@pytest.mark.parametrize("seed", SEEDS)
def test_umeyama_equals_live_evo(seed: int, with_scale: bool) -> None:
    rng = np.random.default_rng(100 + seed)
    x = rng.normal(0.0, 3.0, (40, 3))
    if seed % 3 == 0:
        x[:, 2] *= 1e-3  # nearly planar
    # a reflection on odd seeds: evo's det(U) det(V) fix must agree too
    mirror = np.diag([1.0, 1.0, -1.0 if seed % 2 else 1.0])
    y = 1.7 * Rotation.random(random_state=seed).apply(x @ mirror) + rng.normal(0.0, 0.1, (40, 3))
    ours = umeyama_alignment(x, y, with_scale=with_scale)
    r, t, c = evo_geometry.umeyama_alignment(x.T, y.T, with_scale)
    np.testing.assert_allclose(ours.rotation, r, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(ours.translation, t, rtol=REL, atol=1e-12)
    assert ours.scale == pytest.approx(c, rel=REL, abs=0.0)
