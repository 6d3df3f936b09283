"""End-to-end tests of the coarse registration stage on synthetic scans of real floor plans.

The plans are the demo building's exact plan section (``bimcap.sim``: a 15 m corridor with
doors, rooms, columns) and a 180°-symmetric room between two corridors; the scans are ray-cast
from known poses (:mod:`bimcap.registration.synthetic`), so the truth is exact.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from bimcap.registration import CoarseOptions, coarse_register
from bimcap.registration.synthetic import (
    Scene,
    displace,
    level_pose,
    pose_errors,
    poses_along,
    scan_sequence,
    symmetric_scene,
)

#: The window stage alone (the per-frame orientation stage is on by default).
WINDOWS = CoarseOptions(frame_orientation=False)

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def demo() -> Scene:
    from bimcap.registration.synthetic import demo_scene

    return demo_scene(seed=0)


def corridor_walk(n: int = 10, x0: float = 4.0) -> np.ndarray:
    """(n, 7) cameras walking east along the demo corridor (y = -0.3), 0.25 m apart."""
    return poses_along(np.array([[x0, -0.3], [x0 + 0.25 * n + 0.01, -0.3]]), 0.25)[:n]


def drift(gt: np.ndarray, t_m: float, yaw_deg: float, dz: float = 0.1,
          tilt_deg: tuple[float, float] = (1.0, -1.0)) -> np.ndarray:
    """The issue's displacement: ``t_m`` metres (diagonal) and ``yaw_deg`` about the window's
    centre, plus a little z and tilt that the floor/ceiling must take out."""
    direction = np.array([0.6, -0.8])
    return displace(gt, np.deg2rad(yaw_deg), np.r_[t_m * direction, dz], gt[:, :3].mean(0),
                    (np.deg2rad(tilt_deg[0]), np.deg2rad(tilt_deg[1])))


def test_window_displaced_1p5m_15deg_in_corridor_returns(demo: Scene) -> None:
    gt = corridor_walk(10)
    samples = scan_sequence(gt, demo, seed=1, clutter_fraction=0.03)
    init = drift(gt, 1.5, 15.0)
    t0, r0 = pose_errors(init, gt)
    assert t0.min() > 1.0 and r0.min() > 14.0  # the start really is far off
    res = coarse_register(init, samples, demo.floor_plan(), WINDOWS)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err.max() < 0.05, t_err
    assert r_err.max() < 0.5, r_err
    assert res.accepted.all()
    assert (res.frame_inlier_ratio > 0.8).all()
    assert abs(res.windows[0].dz_m + 0.1) < 0.02  # the floor took the z error out


def test_single_frame_displaced_1p5m_15deg_returns(demo: Scene) -> None:
    gt = level_pose(6.0, -0.3, 0.0)[None]
    samples = scan_sequence(gt, demo, seed=2, clutter_fraction=0.03)
    init = displace(gt, np.deg2rad(-15.0), np.array([-0.9, 1.2, 0.0]), gt[0, :3])
    opts = CoarseOptions(window_frames=1, frame_orientation=False)
    res = coarse_register(init, samples, demo.floor_plan(), opts)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err[0] < 0.05 and r_err[0] < 0.5, (t_err, r_err)


def test_missing_wall_and_clutter_do_not_break_it(demo: Scene) -> None:
    # As built, the corridor's north wall between x = 5 and 9 is missing (the BIM still has
    # it): the camera sees into the rooms behind; 15 % of the wall points are clutter.
    as_built = demo.without((5.0, 1.1, 9.0, 1.45))
    assert len(as_built.segments) < len(demo.segments)
    gt = corridor_walk(12, x0=4.5)
    samples = scan_sequence(gt, as_built, seed=3, clutter_fraction=0.15)
    init = drift(gt, 1.2, -12.0)
    res = coarse_register(init, samples, demo.floor_plan(), WINDOWS)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err.max() < 0.05, t_err
    assert r_err.max() < 0.5, r_err


def test_displacement_outside_the_search_range_is_not_accepted(demo: Scene) -> None:
    # Negative control: 3.5 m is outside the ±2 m range, so the stage must not claim success.
    gt = corridor_walk(10)
    samples = scan_sequence(gt, demo, seed=4, clutter_fraction=0.03)
    init = displace(gt, 0.0, np.array([0.0, 3.5, 0.0]), gt[:, :3].mean(0))
    res = coarse_register(init, samples, demo.floor_plan(), WINDOWS)
    t_err, _ = pose_errors(res.poses, gt)
    assert t_err.min() > 1.0  # it could not fix it ...
    assert not res.accepted.any(), [w.reason for w in res.windows]  # ... and says so
    # Frames of rejected windows keep their initial pose when nothing was accepted.
    np.testing.assert_allclose(res.poses, init, atol=1e-9)


def test_true_pose_is_a_fixed_point(demo: Scene) -> None:
    gt = corridor_walk(20, x0=2.0)
    samples = scan_sequence(gt, demo, seed=5)
    res = coarse_register(gt, samples, demo.floor_plan(), WINDOWS)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err.max() < 0.01 and r_err.max() < 0.1, (t_err.max(), r_err.max())
    d = res.to_dict()
    assert d["n_frames"] == 20 and len(d["windows"]) == 2 and d["accepted_fraction"] == 1.0
    json.dumps(d, allow_nan=False)
    # Plain local ICP (no correlative search) leaves the true pose alone as well.
    icp_only = coarse_register(gt, samples, demo.floor_plan(),
                               CoarseOptions(use_correlative=False, use_continuity=False,
                                             frame_orientation=False))
    assert pose_errors(icp_only.poses, gt)[0].max() < 0.01
    json.dumps(icp_only.to_dict(), allow_nan=False)


def _symmetric_case(use_continuity: bool) -> tuple[np.ndarray, np.ndarray]:
    # The room's own data favour the flipped pose: the as-built room column stands at the
    # mirror image of the BIM's. The corridor column anchors the walk before the room.
    bim = symmetric_scene((2.2, 1.8))
    as_built = symmetric_scene((6.2, -1.8))
    path = np.array([[-2.0, 0.4], [-8.5, 0.4], [-8.5, -0.4], [1.0, -0.4], [1.0, 0.0], [4.0, 0.0],
                     [4.0, 1.5], [7.0, 1.5], [7.0, -1.5], [4.0, -1.5]])
    gt = poses_along(path, 0.3)
    samples = scan_sequence(gt, as_built, seed=3, clutter_fraction=0.03)
    init = displace(gt, np.deg2rad(5.0), np.array([0.4, -0.3, 0.0]), gt[:, :3].mean(0))
    opt = CoarseOptions(yaw_range_deg=180.0, yaw_step_deg=2.0, use_continuity=use_continuity,
                        frame_orientation=False)
    res = coarse_register(init, samples, bim.floor_plan(), opt)
    return pose_errors(res.poses, gt)


@pytest.mark.slow
def test_symmetric_room_does_not_flip_with_continuity() -> None:
    t_err, r_err = _symmetric_case(use_continuity=True)
    assert r_err.max() < 0.5, r_err
    assert t_err.max() < 0.05, t_err


@pytest.mark.slow
def test_symmetric_room_flips_without_continuity() -> None:
    # Negative control: the same data without the continuity chain take the flipped room.
    _, r_err = _symmetric_case(use_continuity=False)
    assert r_err.max() > 150.0


def test_rigid_motion_of_the_whole_world_changes_nothing(demo: Scene) -> None:
    # Invariant: turn the building, the truth and the drift by 30° and move them by (7, -3):
    # the stage must converge just as well (the view bins follow the plan's wall direction).
    from bimcap.geometry.poses import compose

    yaw, shift = np.deg2rad(30.0), np.array([7.0, -3.0])
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    moved = Scene(np.c_[demo.segments[:, :2] @ rot.T + shift, demo.segments[:, 2:] @ rot.T + shift],
                  demo.segment_class, demo.floor_z, demo.ceiling_z)
    world = np.r_[shift, 0.0, 0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)]
    gt = compose(world, corridor_walk(10))
    samples = scan_sequence(gt, moved, seed=6, clutter_fraction=0.03)
    init = drift(gt, 1.5, 15.0)
    res = coarse_register(init, samples, moved.floor_plan(), WINDOWS)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err.max() < 0.05 and r_err.max() < 0.5, (t_err.max(), r_err.max())


@pytest.mark.slow
def test_smoothly_growing_drift_like_exp1(demo: Scene) -> None:
    # Odometry with a 3 % scale error and a constant yaw rate: 0 at the start, ~1 m and ~11°
    # after 60 frames. Window corrections + per-frame ICP must take it out.
    from scipy.spatial.transform import Rotation

    from bimcap.geometry.poses import compose, invert
    from bimcap.registration.synthetic import demo_tour

    gt = poses_along(demo_tour(seed=0), 0.25)[100:160]
    step_err = np.r_[0.0, 0.0, 0.0, Rotation.from_euler("y", np.deg2rad(11.0) / len(gt)).as_quat()]
    rel = compose(invert(gt[:-1]), gt[1:])
    rel[:, :3] *= 1.03
    init = [gt[0]]
    for r in rel:
        init.append(compose(init[-1], compose(r, step_err)))
    init_arr = np.array(init)
    t0, r0 = pose_errors(init_arr, gt)
    assert t0.max() > 0.8 and r0.max() > 10.0
    res = coarse_register(init_arr, scan_sequence(gt, demo, seed=7, clutter_fraction=0.05),
                          demo.floor_plan(), WINDOWS)
    t_err, r_err = pose_errors(res.poses, gt)
    assert t_err.max() < 0.05, t_err
    assert np.median(r_err) < 0.2 and np.percentile(r_err, 90) < 0.5, r_err


def _two_storey_case(demo: Scene, use_segment_z: bool) -> np.ndarray:
    from bimcap.registration import FloorPlan

    # Upstairs the same layout stands 0.6 m further east; the walk is upstairs and starts
    # 0.6 m west of its truth, i.e. exactly where it would be right on the ground floor.
    shift = np.array([0.6, 0.0, 0.6, 0.0])
    upper = Scene(demo.segments + shift, demo.segment_class, 3.1, 5.9)
    seg_z = np.r_[np.tile([0.0, 2.9], (len(demo.segments), 1)),
                  np.tile([3.1, 6.0], (len(upper.segments), 1))]
    plan = FloorPlan(np.r_[demo.segments, upper.segments],
                     np.r_[demo.segment_class, upper.segment_class],
                     seg_z if use_segment_z else None, np.array([0.0, 3.1]), np.array([2.8, 5.9]))
    gt = poses_along(np.array([[3.0, -0.3], [6.0, -0.3]]), 0.25, height=4.6)[:10]
    samples = scan_sequence(gt, upper, seed=8, clutter_fraction=0.03)
    init = displace(gt, 0.0, np.array([-0.6, 0.0, 0.2]), gt[:, :3].mean(0))
    res = coarse_register(init, samples, plan, WINDOWS)
    assert res.windows[0].dz_m == pytest.approx(-0.2, abs=0.02)  # floor at 3.1 m found
    return pose_errors(res.poses, gt)[0]


def test_storey_is_chosen_by_the_floor_height(demo: Scene) -> None:
    assert _two_storey_case(demo, use_segment_z=True).max() < 0.05


def test_without_storey_bands_the_wrong_storey_can_win(demo: Scene) -> None:
    # Negative control: with every segment on every storey the ground-floor plan fits the
    # initial pose perfectly and nothing moves it.
    assert _two_storey_case(demo, use_segment_z=False).min() > 0.5


def per_frame_drift(gt: np.ndarray, seed: int, yaw_deg: float, tilt_deg: float,
                    step_m: float, offset_m: np.ndarray) -> np.ndarray:
    """Real-world drift: an independent yaw and tilt per frame about its own camera (N(0, σ)
    degrees) and a translation random walk (steps N(0, step_m) per axis in x, y) on top of a
    constant ``offset_m`` (3,)."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(0.0, step_m, (len(gt), 2)), axis=0)
    out = []
    for i, pose in enumerate(gt):
        tilt = np.deg2rad(rng.normal(0.0, tilt_deg, 2))
        out.append(displace(pose[None], np.deg2rad(rng.normal(0.0, yaw_deg)),
                            np.r_[walk[i], 0.0] + offset_m, pose[:3], (tilt[0], tilt[1]))[0])
    return np.array(out)


def test_frame_orientation_takes_out_independent_per_frame_rotations(demo: Scene) -> None:
    gt = corridor_walk(12, x0=3.0)
    samples = scan_sequence(gt, demo, seed=5, clutter_fraction=0.03)
    init = per_frame_drift(gt, 3, 8.0, 4.0, 0.05, np.array([0.8, 0.4, 0.1]))
    t0, r0 = pose_errors(init, gt)
    assert np.median(r0) > 4.0 and t0.min() > 0.6
    res = coarse_register(init, samples, demo.floor_plan(),
                          CoarseOptions(frame_orientation=True))
    fl = res.frame_level
    assert fl is not None and fl.drift_m > 0.35 and fl.yaw_ok.mean() > 0.8
    assert res.near_probe_drift_m is None  # the probe saw the drift: the full pass ran
    t_err, r_err = pose_errors(res.poses, gt)
    assert np.median(r_err) < 0.5, r_err
    assert t_err.max() < 0.3, t_err  # the deadband leaves up to 0.3 m to the windows and BA
    # The window stage alone cannot fit frames whose rotations disagree.
    base = coarse_register(init, samples, demo.floor_plan(),
                           CoarseOptions(frame_orientation=False))
    assert np.median(pose_errors(base.poses, gt)[1]) > 2.0


def test_frame_orientation_near_input_keeps_positions(demo: Scene) -> None:
    gt = corridor_walk(10, x0=3.0)
    samples = scan_sequence(gt, demo, seed=6, clutter_fraction=0.03)
    init = per_frame_drift(gt, 4, 6.0, 3.0, 0.02, np.array([0.1, 0.05, 0.0]))
    plan = demo.floor_plan()
    full = CoarseOptions(frame_orientation=True, near_probe_frames=0)
    res = coarse_register(init, samples, plan, full)
    assert res.frame_level is not None and res.frame_level.drift_m < 0.35
    assert res.near_probe_drift_m is None
    assert np.array_equal(res.poses, init)  # within the bundle adjustment's reach: unchanged
    # The probe on 4 of the 10 frames sees the same small drift and hands the input back
    # without the pass over every frame.
    probed = coarse_register(init, samples, plan,
                             replace(full, near_probe_frames=4, near_probe_min_tracked=3))
    assert probed.frame_level is None
    assert probed.near_probe_drift_m is not None and probed.near_probe_drift_m < 0.15
    assert np.array_equal(probed.poses, init)
    assert not probed.accepted.any()
    res = coarse_register(init, samples, plan,
                          CoarseOptions(frame_orientation=True, frame_rotate_when_near=True))
    # Only rotations about the cameras: positions unchanged, windows skipped.
    assert np.allclose(res.poses[:, :3], init[:, :3], atol=1e-9)
    assert not res.accepted.any()
    assert all(w.reason == "input already near the plan" for w in res.windows)
    assert np.median(pose_errors(res.poses, gt)[1]) < 0.5
    json.dumps(res.to_dict())


def test_frame_options_are_validated() -> None:
    from bimcap.registration.errors import RegistrationInputError

    with pytest.raises(RegistrationInputError, match="frame_gate_m"):
        CoarseOptions(frame_gate_m=-1.0)
    with pytest.raises(RegistrationInputError, match="frame_yaw_range_deg"):
        CoarseOptions(frame_yaw_range_deg=200.0)



@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bimcap.bim.errors.MissingFloorWarning")
@pytest.mark.filterwarnings("ignore::bimcap.bim.errors.MissingCeilingWarning")
def test_true_pose_is_a_fixed_point_in_a_real_duplex(ifc_dir, tmp_path) -> None:
    """The real Duplex model (two mirrored flats: many places score like the truth), simulated:
    from the ground truth the coarse stage must hand the poses back. It moved frames by 0.9–1.9 m
    to aliases while the input itself was not among the per-frame tracking's hypotheses."""
    from dataclasses import replace

    from bimcap.dataset import read_sequence
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import _coarse, prepare
    from bimcap.sim.lidar import LidarConfig
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate
    from bimcap.sim.walk import WalkConfig

    ifc = ifc_dir / "Duplex_A_20110907.ifc"
    if not ifc.is_file():
        pytest.skip(f"{ifc} not found")
    cfg = SimulatorConfig(camera=CONSLAM_CAMERA.scaled(0.25), frames=60, fps=2.0,
                          lidar=LidarConfig(), walk=WalkConfig(pitch_deg=-12.0), workers=0)
    simulate(ifc, tmp_path / "seq", cfg, seed=1)
    seq = read_sequence(tmp_path / "seq")
    gt = seq.trajectory("gt")
    prep = prepare(seq, ifc, gt, replace(RefineConfig(), workers=2), tmp_path / "run", quiet=True)
    poses, _ = _coarse(prep, gt.poses.copy())
    moved = np.linalg.norm(poses[:, :3] - gt.poses[:, :3], axis=1)
    assert moved.max() < 0.05, np.round(moved, 2)



def _with_tracked_translation(monkeypatch: pytest.MonkeyPatch, offset_xy: np.ndarray,
                              frames: slice = slice(None)) -> None:
    """Make stage 0's tracked translation that of the truth plus ``offset_xy`` (2,) metres on
    ``frames`` (default every frame: what the per-frame track reports when its frames lock
    onto an alias)."""
    from dataclasses import replace

    from bimcap.registration import coarse

    real = coarse._level_frames

    def aliased(*args: object, **kwargs: object) -> object:
        fl = real(*args, **kwargs)
        t3 = fl.translation.copy()
        t3[frames, :2] += offset_xy
        return replace(fl, translation=t3,
                       drift_m=float(np.median(np.linalg.norm(t3, axis=1))))

    monkeypatch.setattr(coarse, "_level_frames", aliased)


def test_tracked_translation_to_an_alias_is_dropped_when_no_window_confirms_it(
        demo: Scene, monkeypatch: pytest.MonkeyPatch) -> None:
    # The per-frame track is a proposal of single frames: in a building with mirrored or
    # repeated rooms each frame may fit an alias. Here it reports every frame 2.6 m north of
    # where it is (inside the rooms beside the corridor): no window registers there, so the
    # translation must not be applied; the frames keep their input positions (0.1 m off),
    # from which the bundle adjustment converges.
    gt = corridor_walk(12, x0=3.0)
    samples = scan_sequence(gt, demo, seed=5, clutter_fraction=0.03)
    init = per_frame_drift(gt, 3, 6.0, 3.0, 0.01, np.array([0.08, -0.06, 0.0]))
    _with_tracked_translation(monkeypatch, np.array([0.0, 2.6]))
    res = coarse_register(init, samples, demo.floor_plan(), CoarseOptions())
    assert res.frame_level is not None and res.frame_level.drift_m > 2.0
    t_err, _ = pose_errors(res.poses, gt)
    assert t_err.max() < 0.3, t_err
    assert res.translation_dropped
    assert res.to_dict()["translation_dropped"] is True


def test_tracked_translation_a_window_confirms_is_kept(demo: Scene) -> None:
    # Control: the true drift (0.8 m) is tracked and the windows confirm it.
    gt = corridor_walk(12, x0=3.0)
    samples = scan_sequence(gt, demo, seed=5, clutter_fraction=0.03)
    init = per_frame_drift(gt, 3, 8.0, 4.0, 0.05, np.array([0.8, 0.4, 0.1]))
    res = coarse_register(init, samples, demo.floor_plan(), CoarseOptions())
    assert not res.translation_dropped and res.accepted.any()
    assert pose_errors(res.poses, gt)[0].max() < 0.3


def test_tracked_translation_stands_only_in_windows_that_confirm_it(
        demo: Scene, monkeypatch: pytest.MonkeyPatch) -> None:
    """Duplex_A 250 frames, Exp 2: stage 0 tracked runs of 15-20 frames 1.3-2.4 m off (a
    look-alike room) while the windows elsewhere confirmed the true drift. Here the middle
    window's frames are tracked 2.6 m north, into the rooms beside the corridor: that window is
    not accepted, and its frames must drop their own translation for the accepted windows'
    corrections, not keep the alias (the bundle adjustment holds a block placed there)."""
    gt = corridor_walk(30, x0=2.5)
    samples = scan_sequence(gt, demo, seed=5, clutter_fraction=0.03)
    init = per_frame_drift(gt, 3, 6.0, 3.0, 0.01, np.array([0.8, 0.4, 0.1]))
    _with_tracked_translation(monkeypatch, np.array([0.0, 2.6]), slice(10, 20))
    res = coarse_register(init, samples, demo.floor_plan(), CoarseOptions())
    assert res.accepted[:10].all() and res.accepted[20:].all() and not res.accepted[10:20].any()
    t_err, _ = pose_errors(res.poses, gt)
    assert t_err.max() < 0.3, t_err
    # without the rule the middle window's frames keep the alias
    off = coarse_register(init, samples, demo.floor_plan(),
                          CoarseOptions(frame_translation_per_window=False))
    assert pose_errors(off.poses, gt)[0][10:20].min() > 1.0


def test_a_window_is_not_put_in_a_storey_its_cameras_do_not_fit() -> None:
    """Duplex_A 250 frames, Exp 2, window 140-149: its only floor points came from two frames
    about 1 m low, their median (-1.02 m) lay nearer the 1.1 m crawl space's floor (-1.25 m)
    than the ground floor (0.016 m), and the window's walls were matched against the crawl
    space's plan: 1.6 m off, accepted. The cameras stood 1.5-1.9 m above those floor points
    (whatever their z error), above the crawl space's ceiling (-0.13 m): that storey cannot
    hold them."""
    from bimcap.registration._coarse_steps import _pick_floor, _pick_height
    from bimcap.registration.coarse import FloorPlan

    plan = FloorPlan(np.array([[0.0, 0.0, 1.0, 0.0]]), np.array([1]),
                     floor_heights=np.array([-1.25, 0.016, 3.12]),
                     ceiling_heights=np.array([-0.13, 1.2, 2.6, 5.7]))  # 1.2: a soffit
    floor_z, low_cams = np.full(20, -1.02), np.full(20, 0.5)
    assert _pick_height(plan.floor_heights, -1.02) == -1.25  # by height alone: the crawl space
    assert _pick_floor(plan, floor_z, low_cams, 0.5) == pytest.approx(0.016)
    # cameras 0.8 m above their floor points fit in the crawl space: nearest floor as before
    assert _pick_floor(plan, floor_z, np.full(20, -0.22), -0.22) == -1.25
    # the soffit at 1.2 m does not make the ground floor too low for a camera 1.5 m up
    assert _pick_floor(plan, np.full(5, 0.3), np.full(5, 1.8), 1.8) == pytest.approx(0.016)
    # no floor points: the highest floor at or below the cameras, as before
    assert _pick_floor(plan, np.zeros(0), np.zeros(0), 1.5) == pytest.approx(0.016)


# ------------------------------------------------------------------------------------------------
# Issue 14: a hand-back under 1 s. The faster code gives the previous code's arrays bit for bit
# (``tests/_coarse_reference.py``), and a hand-back gives the full pass's result.


def test_score_volume_is_the_previous_code_bit_for_bit(demo: Scene) -> None:
    import _coarse_reference as ref
    from bimcap.registration.coarse import _build_maps
    from bimcap.registration.correlative import score_volume

    plan = demo.floor_plan()
    maps = _build_maps(plan, np.ones(len(plan.segments), dtype=bool), CoarseOptions())
    rng = np.random.default_rng(3)
    pivot = np.array([6.0, -0.3])
    step = np.deg2rad(1.0)
    for m_pts, yaws, kwargs in (
            (1500, np.arange(-25, 26) * step, {}),
            (1500, np.arange(-25, 26) * step, {"column_weight": 0.5}),
            (1500, np.arange(-25, 26) * step, {"column_weight": 0.0}),
            (800, np.arange(-10, 11) * step, {"y_range_m": 1.0}),
            (20_000, np.arange(-np.pi, np.pi, np.deg2rad(5.0)), {}),  # several yaw blocks
            (300, np.arange(-5, 6) * step, {"p_weight": rng.uniform(0.1, 1.0, 300)}),
            (0, np.arange(-5, 6) * step, {})):
        p_xy = pivot + rng.uniform(-6.0, 6.0, (m_pts, 2))
        p_cls = rng.choice(np.array([1, 4], np.int32), m_pts, p=[0.8, 0.2]).astype(np.int32)
        view = p_xy - (pivot + rng.normal(0.0, 0.5, (m_pts, 2)))
        old = ref.score_volume_4206b3e(p_xy, p_cls, view, maps, pivot, yaws, 2.0, **kwargs)
        new = score_volume(p_xy, p_cls, view, maps, pivot, yaws, 2.0, **kwargs)
        assert old[1:] == new[1:]
        assert np.array_equal(old[0], new[0]), (m_pts, kwargs)


def _near_walk(demo: Scene, n: int = 30) -> tuple[np.ndarray, object]:
    """``n`` frames along the demo corridor with small per-frame errors (within the bundle
    adjustment's reach) and their scans."""
    gt = corridor_walk(n, x0=2.5)
    samples = scan_sequence(gt, demo, seed=6, clutter_fraction=0.03)
    return per_frame_drift(gt, 4, 3.0, 2.0, 0.02, np.array([0.05, 0.03, 0.0])), samples


def test_stage0_is_the_previous_code_bit_for_bit(demo: Scene) -> None:
    import _coarse_reference as ref
    from bimcap.registration import coarse as stages

    init, samples = _near_walk(demo, 12)
    plan = demo.floor_plan()
    opt = CoarseOptions()
    maps_for = stages._storey_maps(plan, opt, {})
    new = stages._level_frames(init, samples, plan, maps_for, opt, np.random.default_rng(0))
    with ref.old_coarse():
        old = stages._level_frames(init, samples, plan, maps_for, opt, np.random.default_rng(0))
    assert new.t_ok.any() and new.yaw_ok.any()
    for name in ("world_from_world", "tilt_ok", "yaw_ok", "yaw_deg", "tilt_deg", "t_ok",
                 "score", "constraint", "translation"):
        assert np.array_equal(getattr(old, name), getattr(new, name)), name
    assert old.drift_m == new.drift_m


def _same_result(a: object, b: object) -> None:
    """Two :class:`CoarseResult` are the same bit for bit (but for the seconds they took)."""
    for name in ("poses", "frame_score", "frame_inlier_ratio", "accepted", "frame_window"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    strip = [{k: v for k, v in w.to_dict().items() if k != "seconds"} for w in a.windows]
    assert strip == [{k: v for k, v in w.to_dict().items() if k != "seconds"}
                     for w in b.windows]
    assert a.translation_dropped == b.translation_dropped


def test_a_hand_back_is_the_full_pass_result_bit_for_bit(demo: Scene) -> None:
    """With the defaults (the probe on 15 of 30 frames, its yaw step 2°), the probe hands the
    input back, and every array of the result is the full pass's: the poses (the input, not a
    round trip through matrices), each frame's fit and each window's levelling; the code of
    4206b3e (probe at 1°) gives the same."""
    import _coarse_reference as ref

    init, samples = _near_walk(demo)
    plan = demo.floor_plan()
    opt = CoarseOptions()
    full = coarse_register(init, samples, plan, replace(opt, near_probe_frames=0))
    assert full.frame_level is not None and full.frame_level.drift_m < opt.frame_gate_m
    probed = coarse_register(init, samples, plan, opt)
    assert probed.frame_level is None and probed.near_probe_drift_m is not None
    assert probed.near_probe_drift_m < opt.near_probe_m
    _same_result(full, probed)
    assert np.array_equal(probed.poses, init)
    with ref.old_coarse():
        was = coarse_register(init, samples, plan, replace(opt, near_probe_yaw_step_deg=1.0))
    assert was.near_probe_drift_m is not None
    _same_result(was, probed)
    assert abs(was.near_probe_drift_m - probed.near_probe_drift_m) < 0.05


def test_near_probe_yaw_step_is_validated() -> None:
    from bimcap.registration.errors import RegistrationInputError

    with pytest.raises(RegistrationInputError, match="near_probe_yaw_step_deg"):
        CoarseOptions(near_probe_yaw_step_deg=0.0)
