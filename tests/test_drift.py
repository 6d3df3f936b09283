"""Drift generator: statistics, determinism, composition, calibration of the presets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.geometry import Trajectory
from bimcap.sim.drift import (
    PRESETS,
    DriftError,
    DriftModel,
    DriftParams,
    apply_drift,
)


def walking_trajectory(n: int, seed: int = 0) -> Trajectory:
    """A handheld-like path: ~1 m/s at 2 Hz, smooth yaw, camera looking along the motion."""
    rng = np.random.default_rng(seed)
    yaw = np.cumsum(rng.normal(0.0, 0.08, n))
    step = 0.5
    xy = np.cumsum(np.stack([np.cos(yaw), np.sin(yaw)], 1) * step, axis=0)
    z = 1.5 + 0.02 * np.sin(np.arange(n) * 0.7)
    # Camera optical frame: z forward (along the yaw direction), x right, y down.
    cam_to_body = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float))
    rot = Rotation.from_euler("z", yaw[:, None]) * cam_to_body
    poses = np.concatenate([xy, z[:, None], rot.as_quat()], axis=1)
    return Trajectory(np.arange(n) * 0.5, poses)


def _rmse_pos(a: Trajectory, b: Trajectory) -> float:
    return float(np.sqrt(np.mean(np.sum((a.poses[:, :3] - b.poses[:, :3]) ** 2, axis=1))))


def _rmse_rot_deg(a: Trajectory, b: Trajectory) -> float:
    """Independent ATE_rot via rotation matrices: angle from the trace of R_aᵀ R_b."""
    ra = Rotation.from_quat(a.poses[:, 3:]).as_matrix()
    rb = Rotation.from_quat(b.poses[:, 3:]).as_matrix()
    tr = np.einsum("nji,nji->n", ra, rb)
    theta = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
    return float(np.degrees(np.sqrt(np.mean(theta**2))))


def test_paper_mode_statistics_match_sigmas() -> None:
    gt = walking_trajectory(5000)
    params = DriftParams(sigma_t=0.05, sigma_pitch_deg=2.0, sigma_yaw_deg=3.0, seed=11)
    res = apply_drift(gt, params)
    assert res.scale_t == 1.0 and res.scale_rot == 1.0
    walk = res.init.poses[:, :3] - gt.poses[:, :3]
    np.testing.assert_allclose(walk, res.offsets.translation, atol=1e-12)
    steps = np.diff(np.vstack([np.zeros(3), walk]), axis=0)  # ΔT_1 ~ N(0, σ²) is the first step
    assert np.all(np.abs(steps.std(axis=0) / 0.05 - 1.0) < 0.1)
    assert np.all(np.abs(steps.mean(axis=0)) < 4 * 0.05 / np.sqrt(5000))
    # Rotation offsets are independent per frame, not a walk.
    assert abs(res.offsets.pitch_deg.std() / 2.0 - 1.0) < 0.1
    assert abs(res.offsets.yaw_deg.std() / 3.0 - 1.0) < 0.1
    assert abs(np.corrcoef(res.offsets.yaw_deg[1:], res.offsets.yaw_deg[:-1])[0, 1]) < 0.05


def test_rotation_composition_is_world_yaw_times_gt_times_camera_pitch() -> None:
    gt = walking_trajectory(20)
    res = apply_drift(gt, DriftParams(sigma_pitch_deg=5.0, sigma_yaw_deg=5.0, seed=3))
    for i in (0, 7, 19):
        r_gt = Rotation.from_quat(gt.poses[i, 3:]).as_matrix()
        a = np.radians(res.offsets.yaw_deg[i])
        b = np.radians(res.offsets.pitch_deg[i])
        rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
        expected = rz @ r_gt @ rx
        got = Rotation.from_quat(res.init.poses[i, 3:]).as_matrix()
        np.testing.assert_allclose(got, expected, atol=1e-12)
    # The camera's optical axis (z) tilts up/down by pitch only: its height component changes
    # by the pitch, while a pure yaw leaves the height component unchanged.
    yaw_only = apply_drift(gt, DriftParams(sigma_yaw_deg=5.0, seed=3))
    z_axis_gt = Rotation.from_quat(gt.poses[:, 3:]).apply([0, 0, 1])
    z_axis = Rotation.from_quat(yaw_only.init.poses[:, 3:]).apply([0, 0, 1])
    np.testing.assert_allclose(z_axis[:, 2], z_axis_gt[:, 2], atol=1e-12)


def test_same_seed_identical_other_seed_different() -> None:
    gt = walking_trajectory(100)
    p = DriftParams.from_preset("exp1", seed=5)
    a, b = apply_drift(gt, p), apply_drift(gt, p)
    np.testing.assert_array_equal(a.init.poses, b.init.poses)
    c = apply_drift(gt, DriftParams.from_preset("exp1", seed=6))
    assert not np.allclose(a.init.poses, c.init.poses)
    np.testing.assert_array_equal(a.init.timestamps, gt.timestamps)


def test_drift_z_false_keeps_height() -> None:
    gt = walking_trajectory(50)
    res = apply_drift(gt, DriftParams(sigma_t=0.1, seed=1, drift_z=False))
    np.testing.assert_array_equal(res.init.poses[:, 2], gt.poses[:, 2])
    assert np.abs(res.init.poses[:, :2] - gt.poses[:, :2]).max() > 0.1


@pytest.mark.parametrize("name", ["exp1", "exp2", "exp3"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_presets_hit_their_targets(name: str, seed: int) -> None:
    gt = walking_trajectory(150, seed=seed)
    res = apply_drift(gt, DriftParams.from_preset(name, seed=seed))
    preset = PRESETS[name]
    # Checked with an independent ATE implementation (matrix trace), not the module's helper.
    assert _rmse_pos(res.init, gt) == pytest.approx(preset.target_ate_pos_m, abs=1e-9)
    assert _rmse_rot_deg(res.init, gt) == pytest.approx(preset.target_ate_rot_deg, abs=1e-6)
    assert res.ate_pos == pytest.approx(preset.target_ate_pos_m, abs=1e-9)
    assert res.ate_rot == pytest.approx(preset.target_ate_rot_deg, abs=1e-9)
    # The nominal sigmas are calibrated for ~150 frames: the scale fit is a modest correction.
    if preset.sigma_t > 0:
        assert 0.3 < res.scale_t < 3.0
    assert 0.7 < res.scale_rot < 1.4
    d = res.to_dict()
    assert d["preset"] == name and d["seed"] == seed and d["mode"] == "paper"
    assert d["ate_pos_m"] == res.ate_pos and d["effective_sigma_t"] == preset.sigma_t * res.scale_t


def test_slam_like_is_smooth_and_bends_with_yaw() -> None:
    gt = walking_trajectory(400)
    params = DriftParams(sigma_t=0.01, sigma_yaw_deg=0.3, seed=4, mode=DriftModel.SLAM_LIKE)
    res = apply_drift(gt, params)
    yaw = res.offsets.yaw_deg
    steps = np.diff(yaw)
    # Smooth: consecutive yaw increments are strongly correlated; offsets accumulate.
    assert np.corrcoef(steps[1:], steps[:-1])[0, 1] > 0.7
    assert abs(np.diff(np.concatenate([[0.0], yaw])).std() / 0.3 - 1.0) < 0.25
    # Odometry-like: with no translation noise the position error comes from yaw bending only
    # and is path-length dependent.
    bend = apply_drift(gt, DriftParams(sigma_yaw_deg=0.3, seed=4, mode=DriftModel.SLAM_LIKE))
    err = np.linalg.norm(bend.init.poses[:, :3] - gt.poses[:, :3], axis=1)
    assert err[0] == 0.0 and err[-1] > 0.5
    # Targets work in this mode as well.
    cal = apply_drift(
        gt,
        DriftParams(
            sigma_t=0.01,
            sigma_yaw_deg=0.3,
            seed=4,
            mode=DriftModel.SLAM_LIKE,
            target_ate_pos_m=10.0,
            target_ate_rot_deg=5.0,
        ),
    )
    assert cal.ate_pos == pytest.approx(10.0, abs=1e-9)
    assert cal.ate_rot == pytest.approx(5.0, abs=1e-9)


def test_unreachable_and_invalid_parameters() -> None:
    gt = walking_trajectory(200)
    with pytest.raises(DriftError, match="cannot be reached"):
        apply_drift(
            gt,
            DriftParams(sigma_yaw_deg=2.0, seed=0, mode=DriftModel.SLAM_LIKE, target_ate_pos_m=0.0),
        )
    with pytest.raises(DriftError) as info:
        DriftParams(sigma_t=-1.0)
    assert info.value.field == "sigma_t"
    with pytest.raises(DriftError, match="sigma_t > 0"):
        DriftParams(target_ate_pos_m=1.0)
    with pytest.raises(DriftError, match="unknown preset"):
        DriftParams.from_preset("exp9")
    with pytest.raises(ValueError, match="not a valid DriftModel"):
        DriftParams(mode="sideways")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- the command line
def _tiny_sequence(root: Path, n: int = 30) -> Path:
    from bimcap.dataset import SequenceWriter
    from bimcap.geometry import Camera

    gt = walking_trajectory(n)
    cam = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)
    with SequenceWriter(root, cam, [0, 0, 0, 0, 0, 0, 1]) as w:
        for t in gt.timestamps:
            w.add_frame(t, np.zeros((6, 8, 3), np.uint8), np.zeros((0, 4), np.float32))
        w.add_trajectory("gt", gt)
    return root


def test_cli_drift_writes_init_and_json_and_protects_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from bimcap.cli import main
    from bimcap.dataset import read_sequence

    root = _tiny_sequence(tmp_path / "seq")
    gt_bytes = (root / "poses" / "gt.tum").read_bytes()
    assert main(["drift", str(root), "--preset", "exp2", "--seed", "3"]) == 0
    seq = read_sequence(root)
    assert seq.poses["init"] == "poses/init.tum"
    info = json.loads((root / "poses" / "init.drift.json").read_text())
    assert info["preset"] == "exp2" and info["seed"] == 3 and info["mode"] == "paper"
    assert info["ate_pos_m"] == pytest.approx(0.303, abs=1e-9)
    assert info["ate_rot_deg"] == pytest.approx(8.82, abs=1e-9)
    expected = apply_drift(seq.trajectory("gt"), DriftParams.from_preset("exp2", seed=3))
    np.testing.assert_allclose(seq.trajectory("init").poses, expected.init.poses, atol=1e-12)
    assert (root / "poses" / "gt.tum").read_bytes() == gt_bytes
    # A second run refuses to overwrite init.tum without --force, then replaces it with --force.
    assert main(["drift", str(root), "--preset", "exp2", "--seed", "4"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["drift", str(root), "--preset", "exp1", "--seed", "4", "--force"]) == 0
    assert json.loads((root / "poses" / "init.drift.json").read_text())["preset"] == "exp1"
    # gt is never a target, and -o writes elsewhere without touching the sequence.
    assert main(["drift", str(root), "--name", "gt", "--preset", "exp3"]) == 2
    assert main(["drift", str(root), "-o", str(root / "poses" / "gt.tum"), "--preset", "exp3"]) == 2
    assert (root / "poses" / "gt.tum").read_bytes() == gt_bytes
    out = tmp_path / "other" / "slam.tum"
    assert (
        main(
            [
                "drift",
                str(root),
                "-o",
                str(out),
                "--mode",
                "slam_like",
                "--sigma-t",
                "0.01",
                "--sigma-yaw-deg",
                "0.2",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    assert out.exists() and (tmp_path / "other" / "slam.drift.json").exists()
    assert "slam" not in read_sequence(root).poses


def test_slam_frame_is_a_seeded_rigid_motion_within_its_ranges() -> None:
    from bimcap.geometry.poses import compose, invert
    from bimcap.sim.drift import to_slam_frame

    gt = walking_trajectory(40)
    yaws, shifts = [], []
    for seed in range(60):
        sf = to_slam_frame(gt, seed)
        # The oracle: the stated transform maps the world poses onto the written ones.
        np.testing.assert_allclose(compose(sf.slam_from_world, gt.poses)[:, :3],
                                   sf.trajectory.poses[:, :3], atol=1e-9)
        back = compose(invert(sf.slam_from_world), sf.trajectory.poses)
        np.testing.assert_allclose(back[:, :3], gt.poses[:, :3], atol=1e-9)
        assert _rmse_rot_deg(Trajectory(gt.timestamps, back), gt) < 1e-6
        # Rigid: relative motion and gravity unchanged.
        d0 = np.linalg.norm(np.diff(gt.poses[:, :3], axis=0), axis=1)
        d1 = np.linalg.norm(np.diff(sf.trajectory.poses[:, :3], axis=0), axis=1)
        np.testing.assert_allclose(d0, d1, atol=1e-9)
        up = Rotation.from_quat(sf.slam_from_world[3:]).apply([0.0, 0.0, 1.0])
        np.testing.assert_allclose(up, [0.0, 0.0, 1.0], atol=1e-12)
        assert 0.0 <= sf.yaw_deg < 360.0
        assert np.all(np.abs(sf.translation_m[:2]) <= 50.0) and abs(sf.translation_m[2]) <= 5.0
        yaws.append(sf.yaw_deg)
        shifts.append(sf.translation_m)
    # Spread over the whole circle and the whole box, not a fixed offset.
    assert np.histogram(yaws, bins=4, range=(0, 360))[0].min() >= 5
    assert np.ptp(np.array(shifts)[:, :2]) > 60.0 and np.ptp(np.array(shifts)[:, 2]) > 5.0
    a, b = to_slam_frame(gt, 7), to_slam_frame(gt, 7)
    np.testing.assert_array_equal(a.trajectory.poses, b.trajectory.poses)
    assert not np.allclose(to_slam_frame(gt, 8).slam_from_world, a.slam_from_world)
    with pytest.raises(DriftError) as info:
        to_slam_frame(gt, 0, xy_range_m=-1.0)
    assert info.value.field == "slam_xy_range_m"


def test_cli_drift_slam_frame_writes_the_true_transform(tmp_path: Path) -> None:
    import json

    from bimcap.cli import main
    from bimcap.dataset import read_sequence
    from bimcap.geometry.poses import compose, invert

    root = _tiny_sequence(tmp_path / "seq")
    assert main(["drift", str(root), "--preset", "exp2", "--seed", "5", "--slam-frame"]) == 0
    seq = read_sequence(root)
    info = json.loads((root / "poses" / "init.drift.json").read_text())
    slam = info["slam_frame"]
    assert slam["seed"] == 5 and len(slam["slam_from_world"]) == 7
    init = seq.trajectory("init").poses
    expected = apply_drift(seq.trajectory("gt"), DriftParams.from_preset("exp2", seed=5))
    back = compose(np.array(slam["world_from_slam"]), init)
    np.testing.assert_allclose(back[:, :3], expected.init.poses[:, :3], atol=1e-5)
    np.testing.assert_allclose(compose(invert(np.array(slam["slam_from_world"])), init)[:, :3],
                               expected.init.poses[:, :3], atol=1e-5)
    # Far from the world: the drift alone is 0.3 m, the SLAM frame moves it metres away.
    assert np.linalg.norm(init[:, :3] - expected.init.poses[:, :3], axis=1).mean() > 1.0
    # Without --slam-frame there is no transform; the range flags need it.
    assert main(["drift", str(root), "--preset", "exp2", "--overwrite"]) == 0
    assert json.loads((root / "poses" / "init.drift.json").read_text())["slam_frame"] is None
    assert main(["drift", str(root), "--preset", "exp2", "--overwrite",
                 "--slam-xy-range", "3"]) == 2
