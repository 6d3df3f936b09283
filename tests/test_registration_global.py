"""Global alignment of a trajectory given in a SLAM system's own frame (no initial guess).

Scans are ray-cast from known poses in extruded floor plans (:mod:`bimcap.registration.
synthetic`), the drift is the Exp 2 preset and the SLAM frame a seeded random rigid motion
(:func:`bimcap.sim.drift.to_slam_frame`), so the true ``world_from_slam`` is known exactly.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.geometry import Trajectory
from bimcap.geometry.poses import compose, invert
from bimcap.registration import FloorPlan
from bimcap.registration.errors import RegistrationInputError
from bimcap.registration.global_align import (
    AmbiguousAlignmentError,
    FrameYaw,
    GlobalAlignmentError,
    GlobalAlignOptions,
    PlanAlias,
    RangeVote,
    SeeThroughMargin,
    _alias_ambiguous,
    _frame_yaws,
    _Scan,
    _scan,
    _storey_maps,
    _storeys,
    _support_weight,
    _turned,
    alias_range_vote,
    global_align,
    initial_free_fraction,
    plan_ranges,
    range_agreement,
    see_through_fraction,
)
from bimcap.registration.icp import Correction2D
from bimcap.registration.synthetic import (
    Scene,
    demo_scene,
    demo_tour,
    merge,
    poses_along,
    scan_sequence,
    solids,
)
from bimcap.sim.drift import DriftParams, apply_drift, to_slam_frame

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def demo() -> Scene:
    return demo_scene(seed=0)


def _slam_case(gt: np.ndarray, scene: Scene, seed: int):
    """(samples, SlamFrame) of an Exp 2 drift of ``gt`` moved into a random SLAM frame."""
    drifted = apply_drift(Trajectory(np.arange(len(gt)) * 0.5, gt),
                          DriftParams.from_preset("exp2", seed=seed))
    samples = scan_sequence(gt, scene, seed=seed, clutter_fraction=0.05)
    return samples, to_slam_frame(drifted.init, seed)


def _placement_error(world_from_slam: np.ndarray, slam) -> tuple[float, float]:
    """Mean camera displacement (m) and yaw error (deg) of an estimated ``world_from_slam``
    against the truth, over the trajectory."""
    est = compose(world_from_slam, slam.trajectory.poses)
    true = compose(invert(slam.slam_from_world), slam.trajectory.poses)
    moved = float(np.linalg.norm(est[:, :3] - true[:, :3], axis=1).mean())
    rel = compose(world_from_slam, slam.slam_from_world)
    return moved, float(np.rad2deg(Rotation.from_quat(rel[3:]).magnitude()))


def test_a_unique_layout_is_found_from_a_slam_frame(demo: Scene) -> None:
    gt = poses_along(demo_tour(seed=0), 0.25)[224:284]
    samples, slam = _slam_case(gt, demo, seed=1)
    plan = demo.floor_plan()
    # The SLAM frame puts the cameras outside the building; the truth inside.
    assert initial_free_fraction(slam.trajectory.poses, plan) < 0.1
    assert initial_free_fraction(gt, plan) > 0.9
    res = global_align(slam.trajectory.poses, samples, plan)
    moved, yaw = _placement_error(res.world_from_slam, slam)
    # Within the coarse stage's reach (2 m / 20 deg) by far; the rest is the drift's.
    assert moved < 0.5 and yaw < 3.0, (moved, yaw)
    assert not res.ambiguous and res.ratio < 0.9
    assert len(res.hypotheses) >= 2 and res.hypotheses[0].score > res.hypotheses[1].score
    assert res.hypotheses[0].floor_z == 0.0
    np.testing.assert_allclose(res.poses, compose(res.world_from_slam, slam.trajectory.poses),
                               atol=1e-9)
    # z: the floor is matched, so the heights come back to within the drift.
    assert abs(np.median(res.poses[:, 2] - gt[:, 2])) < 0.15
    doc = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert doc["hypotheses"][0]["world_from_slam"] == list(res.world_from_slam)
    assert res.timings["total"] > 0.0  # timed (the time itself is bench/bench_global.py's)


def _symmetric_rooms() -> Scene:
    """Two identical rooms side by side joined by a door, no column: the plan is symmetric under
    a 180 deg turn about its centre (and a mirror), so a walk inside it has two placements."""
    t = 0.2
    walls = [(-t, -t, 12.0 + t, 0.0), (-t, 5.0, 12.0 + t, 5.0 + t), (-t, 0.0, 0.0, 5.0),
             (12.0, 0.0, 12.0 + t, 5.0), (5.9, 0.0, 6.1, 2.0), (5.9, 3.0, 6.1, 5.0),
             (1.5, 1.0, 2.5, 1.2), (9.5, 3.8, 10.5, 4.0)]
    return merge(solids(walls))


def test_a_symmetric_layout_is_flagged_not_guessed() -> None:
    scene = _symmetric_rooms()
    gt = poses_along(np.array([[1.0, 2.5], [4.5, 2.5], [4.5, 4.0], [8.0, 4.0], [11.0, 1.0]]),
                     0.25)
    samples, slam = _slam_case(gt, scene, seed=4)
    with pytest.raises(AmbiguousAlignmentError) as info:
        global_align(slam.trajectory.poses, samples, scene.floor_plan())
    assert "ambiguous" in str(info.value) and "--accept-ambiguous" in str(info.value)
    res = info.value.result
    assert res is not None and res.ambiguous and res.ratio >= 0.9
    assert all(0.0 <= h.see_through < 0.5 for h in res.hypotheses)
    # The two placements are the truth and its 180 deg image, both reported with their scores.
    yaws = [_placement_error(h.world_from_slam, slam)[1] for h in res.hypotheses[:2]]
    assert min(yaws) < 5.0 and max(yaws) > 170.0, yaws
    accepted = global_align(slam.trajectory.poses, samples, scene.floor_plan(),
                            GlobalAlignOptions(accept_ambiguous=True))
    assert accepted.ambiguous and accepted.accepted_ambiguous
    assert accepted.to_dict()["accepted_ambiguous"] is True


def test_a_point_symmetric_plan_is_flagged_even_when_the_search_keeps_one_placement() -> None:
    """The ranking's own competitor may be missing (drift blurs it, the search keeps few peaks):
    the plan itself says where it repeats what the best placement saw, and the real scan is
    scored there. With one rescored placement per storey the ranking has no second-best, so
    without the alias check the walk is placed, unflagged, in one of two equal rooms."""
    scene = _symmetric_rooms()
    gt = poses_along(np.array([[1.0, 2.5], [4.5, 2.5], [4.5, 4.0], [8.0, 4.0], [11.0, 1.0]]),
                     0.25)
    samples, slam = _slam_case(gt, scene, seed=4)
    one = GlobalAlignOptions(rescore_top=1)
    blind = global_align(slam.trajectory.poses, samples, scene.floor_plan(),
                         replace(one, alias_check=False))
    assert not blind.ambiguous and blind.ratio == 0.0 and blind.alias is None
    with pytest.raises(AmbiguousAlignmentError, match="plan repeats") as info:
        global_align(slam.trajectory.poses, samples, scene.floor_plan(), one)
    res = info.value.result
    assert res is not None and res.ambiguous and res.ratio == 0.0
    alias = res.alias
    assert alias is not None and alias.score_ratio >= 0.9 and abs(alias.yaw_deg) > 170.0
    assert alias.match > 0.9 and alias.difference < 0.2
    # An exact repeat: near-exact, and the real scan fits there as a placement must.
    assert alias.difference <= one.alias_exact_difference and alias.fit_score >= one.min_score
    assert alias.scan_free_fraction >= one.min_free_fraction
    d = json.loads(json.dumps(res.to_dict()))["alias"]
    assert d["score_ratio"] == alias.score_ratio and d["fit_score"] == alias.fit_score


def test_a_near_exact_alias_is_flagged_whatever_the_ratio() -> None:
    """Where the plan repeats what the scan saw almost exactly (small ideal difference), the
    real scan's gap between the two placements is drift and noise: such an alias makes the
    result ambiguous whatever the ratio of the scores, when the real scan fits there as a
    placement must (fit, free share, see-through). A larger ideal difference leaves it to the
    ratio. (The end-to-end case is Duplex_A with 2 mm floor planes, below.)"""
    opt = GlobalAlignOptions()
    exact = PlanAlias(0.0, 180.0, 7.3, 0.97, 1.0, 0.05, 0.04, 0.6, 0.72, 0.8, 0.95, 0.05)
    assert _alias_ambiguous(exact, opt)
    assert _alias_ambiguous(replace(exact, score_ratio=0.3), opt)
    # A perfect scan could tell them apart: the ratio decides.
    assert not _alias_ambiguous(replace(exact, difference=0.12), opt)
    assert _alias_ambiguous(replace(exact, difference=0.12, score_ratio=0.9), opt)
    # The scan does not fit there as a placement must: no competitor.
    assert not _alias_ambiguous(replace(exact, fit_score=0.6), opt)
    assert not _alias_ambiguous(replace(exact, scan_free_fraction=0.4), opt)
    assert not _alias_ambiguous(replace(exact, scan_see_through=0.2), opt)
    assert not _alias_ambiguous(exact, replace(opt, alias_exact_difference=0.0))


def test_plan_ranges_are_the_first_wall_along_the_ray() -> None:
    """The plan's range along a ray: the first segment crossed, up to ``beyond_m`` past the
    point; none: inf."""
    walls = np.array([[1.2, -1.0, 1.2, 1.0], [1.1, 2.0, 1.1, 4.0], [1.25, 2.0, 1.25, 4.0],
                      [2.0, 5.0, 2.0, 7.0]])
    cams = np.array([[0.0, 0.0], [0.0, 3.0], [0.0, 6.0], [0.0, 9.0]])
    pts = np.array([[1.0, 0.0], [1.0, 3.0], [1.0, 6.0], [1.0, 9.0]])
    r = plan_ranges(cams, pts, walls, beyond_m=0.3)
    assert np.allclose(r[:2], [1.2, 1.1]) and np.isinf(r[2:]).all()
    assert np.isclose(plan_ranges(cams[2:3], pts[2:3], walls, beyond_m=1.5)[0], 2.0)


def _box_and_wider_box() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 4 x 3 m room (best placement) and the same room 4.6 m wide (its alias), and a scan from
    twelve cameras: 60 points on the east wall (x = 4: where the two differ) and 60 on the north
    wall (y = 3: where they repeat) per frame. Returns cameras, points, frames, both plans."""
    best = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0], [4.0, 3.0, 0.0, 3.0],
                     [0.0, 3.0, 0.0, 0.0]])
    alias = best.copy()
    alias[0, 2] = alias[1, 0] = alias[1, 2] = alias[2, 0] = 4.6
    cams, pts, frames = [], [], []
    for k in range(12):
        cam = np.array([1.0 + 0.15 * k, 1.5])
        ys = np.linspace(0.2, 2.8, 60)
        xs = np.linspace(0.2, 3.8, 60)
        pts += [np.c_[np.full(60, 4.0), ys], np.c_[xs, np.full(60, 3.0)]]
        cams.append(np.tile(cam, (120, 1)))
        frames.append(np.full(120, k, np.int32))
    return np.concatenate(cams), np.concatenate(pts), np.concatenate(frames), best, alias


def test_the_alias_vote_counts_only_the_rays_where_the_plan_differs() -> None:
    """The discriminating-ray vote (:func:`alias_range_vote`): the east wall's rays (the plans
    differ by 0.6 m there) vote for the plan whose range they meet; the north wall's (the plans
    repeat) say nothing. An exact repeat has no discriminating ray: no vote, so no decision;
    a vote for the alias never decides for the best."""
    cams, pts, frames, best, alias = _box_and_wider_box()
    opt = GlobalAlignOptions()
    vote = alias_range_vote(cams, pts, cams, pts, frames, best, alias)
    # 720 east-wall rays; the two nearest the corner meet the alias's north wall within 0.3 m.
    assert vote.points == 1440 and 710 <= vote.rays <= 720
    assert vote.for_best == vote.rays and vote.for_alias == 0
    assert vote.frames == vote.frames_for_best == 12 and vote.share_low > 0.99
    assert vote.decides(opt)
    assert not vote.decides(replace(opt, alias_vote_min_votes=721))
    assert not vote.decides(replace(opt, alias_vote_min_frames=13))
    # The scan saw the wider room: every discriminating ray backs the alias.
    wrong = alias_range_vote(cams, pts, cams, pts, frames, alias, best)
    assert (wrong.for_best, wrong.for_alias, wrong.share_low) == (0, vote.rays, 0.0)
    assert not wrong.decides(opt)
    # An exact repeat: nothing discriminates.
    same = alias_range_vote(cams, pts, cams, pts, frames, best, best.copy())
    assert (same.rays, same.for_best, same.for_alias) == (0, 0, 0) and not same.decides(opt)
    # Points half-way between the two walls meet both within the tolerance: no vote.
    mid = pts.copy()
    mid[np.isclose(pts[:, 0], 4.0), 0] = 4.3
    half = alias_range_vote(cams, mid, cams, mid, frames, best, alias)
    assert half.rays >= 700 and half.for_best == half.for_alias == 0


def test_a_decisive_vote_lifts_only_the_near_exact_flag() -> None:
    """With ``alias_vote`` on (the default), a near-exact alias that the real ranges tell from
    the best placement (enough votes from enough frames, a lopsided share) makes the result
    ambiguous neither by the near-exact rule nor by its ratio; an undecided vote, no vote, or
    the option off keeps the flag, and an alias the plan tells apart keeps the ratio rule."""
    exact = PlanAlias(0.0, 180.0, 7.3, 0.97, 1.0, 0.05, 0.04, 0.6, 0.72, 0.8, 0.95, 0.05)
    on = GlobalAlignOptions()
    assert on.alias_vote
    decisive = RangeVote(4000, 400, 380, 10, 20, 19, 0.95)
    assert not _alias_ambiguous(replace(exact, vote=decisive), on)
    assert not _alias_ambiguous(replace(exact, vote=decisive, score_ratio=0.95), on)
    assert _alias_ambiguous(replace(exact, vote=decisive), replace(on, alias_vote=False))
    assert _alias_ambiguous(exact, on)
    assert _alias_ambiguous(replace(exact, vote=replace(decisive, share_low=0.6)), on)
    assert _alias_ambiguous(replace(exact, vote=replace(decisive, frames=9)), on)
    assert _alias_ambiguous(replace(exact, vote=replace(decisive, for_best=90, for_alias=5)),
                            on)
    # The plan tells them apart (no vote is cast there): the ratio decides, as before.
    apart = replace(exact, difference=0.12, score_ratio=0.92, vote=decisive)
    assert _alias_ambiguous(apart, on)
    d = json.loads(json.dumps(replace(exact, vote=decisive).to_dict()))
    assert d["vote"]["for_best"] == 380


def _rooms_of_two_widths(door_x: float) -> Scene:
    """:func:`_symmetric_rooms` with the wall between the rooms (and its door) at ``door_x``
    instead of 6 m: 6.12 m makes the west room 6.02 m wide and the east one 5.78 m, so the 180
    deg image of a walk in the west room fits the east room to within 0.24 m."""
    t = 0.2
    walls = [(-t, -t, 12.0 + t, 0.0), (-t, 5.0, 12.0 + t, 5.0 + t), (-t, 0.0, 0.0, 5.0),
             (12.0, 0.0, 12.0 + t, 5.0), (door_x - 0.1, 0.0, door_x + 0.1, 2.0),
             (door_x - 0.1, 3.0, door_x + 0.1, 5.0), (1.5, 1.0, 2.5, 1.2), (9.5, 3.8, 10.5, 4.0)]
    return merge(solids(walls))


def test_stray_returns_do_not_outweigh_a_wall_seen_by_every_frame() -> None:
    """The correlative search's template holds one point per cell: a metre of wall seen by
    every frame (20 points a cell) and a scatter of stray returns (one a cell: noise, clutter,
    a range cut short) 2 m away. With every occupied cell counted alike, the 40 stray cells laid
    on the wall outscore the 10 cells of the wall that was seen (Duplex_A's small rooms: 94 % of
    the points but 23 % of the cells on walls, the right placement never a search peak); each
    cell weighted by its support (``template_support``), the wall's placement wins."""
    from bimcap.labels import Label
    from bimcap.registration._coarse_steps import _subsample, cell_support
    from bimcap.registration.correlative import score_volume
    from bimcap.registration.plan_maps import PlanMaps

    wall = np.array([[0.0, 0.0, 4.0, 0.0]])
    maps = PlanMaps.build(wall, np.array([Label.WALL], np.int32), (0.0, -1.0, 4.0, 3.0), 3.0,
                          1, 0.2, 0.3, 0.05, 0.1, 3.0)
    seen = np.repeat(np.c_[np.arange(0.05, 1.0, 0.1), np.zeros(10)], 20, axis=0)
    stray = np.c_[np.arange(0.05, 4.0, 0.1), np.full(40, 2.0)]
    xy = np.concatenate([seen, stray])
    cls = np.full(len(xy), Label.WALL, np.int32)
    np.testing.assert_array_equal(cell_support(xy, cls, 0.1), np.r_[np.full(200, 20),
                                                                     np.ones(40, np.int64)])
    occ = _subsample(xy, cls, 0.1, 10**6, np.random.default_rng(0))
    assert len(occ) == 50
    view = np.zeros_like(xy)  # one layer: ray directions do not matter here
    yaws = np.zeros(1)

    def best_dy(opt: GlobalAlignOptions) -> float:
        vol, res, n = score_volume(xy[occ], cls[occ], view[occ], maps, np.array([2.0, 1.0]),
                                   yaws, 2.5, p_weight=_support_weight(xy, cls, occ, opt))
        _, j, _ = np.unravel_index(vol.argmax(), vol.shape)
        return (j - n) * res

    assert _support_weight(xy, cls, occ, GlobalAlignOptions(template_support=1)) is None
    assert best_dy(GlobalAlignOptions(template_support=1)) == pytest.approx(-2.0)  # the strays
    assert best_dy(GlobalAlignOptions()) == pytest.approx(0.0)  # the wall that was seen
    with pytest.raises(RegistrationInputError, match="template_support"):
        GlobalAlignOptions(template_support=0)


def test_see_through_fraction_counts_rays_that_cross_a_wall() -> None:
    wall = np.array([[2.0, -5.0, 2.0, 5.0]])
    cams = np.zeros((4, 2))
    # Beyond the wall (seen through it), on it, short of it, beyond it but within the margin.
    pts = np.array([[4.0, 0.0], [2.0, 1.0], [1.0, -1.0], [2.2, 0.0]])
    frac, crossed = see_through_fraction(cams, pts, wall, margin_m=0.3)
    assert crossed.tolist() == [True, False, False, False] and frac == 0.25
    frac, crossed = see_through_fraction(cams, pts, wall, margin_m=0.1)
    assert crossed.tolist() == [True, False, False, True]
    assert see_through_fraction(cams, pts, np.zeros((0, 4)))[0] == 0.0


def test_range_agreement_counts_points_neither_through_nor_short_of_a_wall() -> None:
    wall = np.array([[2.0, -5.0, 2.0, 5.0]])
    cams = np.zeros((6, 2))
    # On the wall, 0.2 m beyond it, 0.2 m short of it (within 0.3 m: agree); 0.5 m beyond it
    # (seen through), 0.5 m short of it (in the plan's free space), and a ray that meets no
    # wall at all.
    pts = np.array([[2.0, 1.0], [2.2, 0.0], [1.8, -1.0], [2.5, 0.0], [1.5, 0.5], [-2.0, 0.0]])
    frac, agree = range_agreement(cams, pts, wall, tol_m=0.3)
    assert agree.tolist() == [True, True, True, False, False, False] and frac == 0.5
    assert range_agreement(cams, pts, wall, tol_m=0.6)[1].tolist() == [True] * 5 + [False]
    # The first wall along the ray decides: a point on a second wall behind the first is seen
    # through the first.
    two = np.array([[2.0, -5.0, 2.0, 5.0], [3.0, -5.0, 3.0, 5.0]])
    assert range_agreement(cams[:2], np.array([[3.0, 0.0], [2.0, 0.0]]), two)[1].tolist() == [
        False, True]
    assert range_agreement(cams, pts, np.zeros((0, 4)))[0] == 0.0


def test_generated_runs_flagged_by_a_close_second_are_placed_with_the_range_agreement(
        monkeypatch) -> None:
    """``bench/bench_global.py``'s ``long`` seed 3 (a corridor of jittered room widths): the
    right placement was best but its second scored 0.92 of it (flagged); the second's points
    lie short of its walls or through them, which the nearest-wall fit (each frame free to
    shift 0.2 m) and the see-through share (a 0.3 m margin from the wall) do not count. With
    the range agreement the run is placed right and unflagged (ratio 0.72)."""
    import bimcap.registration as registration

    bench = _bench_global(monkeypatch)
    world = bench._world("long")
    row = bench.run_registration(world, 3, 60)
    assert row["outcome"] == "placed" and row["right"] and row["ratio"] < 0.85, row
    assert row["agreement"] > 0.7
    # Without it (``range_power`` 0), the same run is flagged.
    monkeypatch.setattr(registration, "global_align", lambda poses, samples, plan: global_align(
        poses, samples, plan, GlobalAlignOptions(range_power=0.0)))
    old = bench.run_registration(world, 3, 60)
    assert old["outcome"] == "ambiguous" and old["right"] and old["ratio"] >= 0.9, old
    assert old["agreement"] == 1.0


def test_a_near_exact_alias_told_apart_by_the_rays_is_placed(monkeypatch) -> None:
    """``bench/bench_global.py``'s ``long`` seed 4 (a corridor of rooms of jittered widths): the
    plan one bay along repeats what the walk saw within an ideal difference of 0.09, so the
    near-exact rule flagged the right placement whatever the ratio (0.88). The rays where the
    two plans differ by more than 0.3 m (a room's width, a door) back the best placement
    (about 290 votes to 23 on this machine, from 30+ frames): placed right, unflagged. Without
    the vote (``alias_vote`` off) it is flagged again."""
    import bimcap.registration as registration

    bench = _bench_global(monkeypatch)
    world = bench._world("long")
    row = bench.run_registration(world, 4, 60)
    assert row["outcome"] == "placed" and row["right"], row
    assert row["alias_difference"] <= 0.1 and row["vote_best"] >= 100
    assert row["vote_best"] > 5 * row["vote_alias"] and row["vote_frames"] >= 10
    monkeypatch.setattr(registration, "global_align", lambda poses, samples, plan: global_align(
        poses, samples, plan, GlobalAlignOptions(alias_vote=False)))
    old = bench.run_registration(world, 4, 60)
    assert old["outcome"] == "ambiguous" and old["right"], old
    assert old["alias_difference"] <= 0.1 and np.isnan(old["vote_best"])


def test_a_see_through_margin_from_the_wall_ignores_grazing_rays() -> None:
    """A ray that grazes a wall at a shallow angle crosses it far from both its ends for a point
    a few centimetres behind the wall's face (drift; AC20-FZK-Haus seed 3 counted 22 % of its
    points at the right placement and was refused): with the margin measured from the wall
    (``SeeThroughMargin.WALL``, the default) it does not count, a point well behind the wall
    still does."""
    wall = np.array([[-1.0, 1.0, 10.0, 1.0]])
    cams = np.array([[0.0, 0.5], [0.0, 0.5], [0.0, 0.0], [0.0, 0.0]])
    # Grazing, 5 cm behind the face; grazing, 0.5 m behind; head-on 0.5 m behind; head-on
    # 5 cm behind.
    pts = np.array([[4.0, 1.05], [6.0, 1.5], [0.0, 1.5], [0.0, 1.05]])
    _, along = see_through_fraction(cams, pts, wall, margin_m=0.3)
    assert along.tolist() == [True, True, True, False]
    _, behind = see_through_fraction(cams, pts, wall, margin_m=0.3,
                                     margin_from=SeeThroughMargin.WALL)
    assert behind.tolist() == [False, True, True, False]
    # the camera within the margin of the wall: not counted either
    _, near_cam = see_through_fraction(np.array([[0.0, 0.8]]), np.array([[0.0, 3.0]]), wall,
                                       margin_m=0.3, margin_from="wall")
    assert not near_cam.any()
    assert GlobalAlignOptions().see_through_margin_from is SeeThroughMargin.WALL
    assert GlobalAlignOptions(see_through_margin_from="ray_ends").to_dict()[
        "see_through_margin_from"] == "ray_ends"
    with pytest.raises(RegistrationInputError, match="see_through_margin_from"):
        GlobalAlignOptions(see_through_margin_from="sideways")


def _attic_plan(demo: Scene) -> tuple[FloorPlan, Scene]:
    """The demo building (floor 0, ceiling 2.8) under a pitched roof: an attic at 3.1 m whose
    plan section holds only its two gable walls (each with a window, at different places), and
    no ceiling above it (as AC20-FZK-Haus)."""
    lo = demo.segments.reshape(-1, 2).min(0)
    hi = demo.segments.reshape(-1, 2).max(0)
    t = 0.3
    gables = solids([(lo[0], lo[1], lo[0] + t, lo[1] + 3.0),
                     (lo[0], lo[1] + 4.2, lo[0] + t, hi[1]),
                     (hi[0] - t, lo[1], hi[0], lo[1] + 1.5),
                     (hi[0] - t, lo[1] + 2.7, hi[0], hi[1])])
    attic = Scene(gables.segments, gables.segment_class, 3.1, 5.6)
    seg_z = np.r_[np.tile([0.0, 2.9], (len(demo.segments), 1)),
                  np.tile([3.1, 6.0], (len(attic.segments), 1))]
    plan = FloorPlan(np.r_[demo.segments, attic.segments],
                     np.r_[demo.segment_class, attic.segment_class], seg_z,
                     np.array([0.0, 3.1]), np.array([2.8]))
    return plan, attic


def test_an_attic_under_a_pitched_roof_is_enclosed_by_the_storey_below(demo: Scene) -> None:
    """An attic whose plan section is only its two gable walls: horizontal rays from its middle
    hit nothing of its own section, so no camera there was in free space and every attic walk
    was refused (AC20-FZK-Haus: 13 of its 20 bench runs). Under a pitched roof (no ceiling
    above) the storey below's walls, which carry the roof, enclose it too (its shell)."""
    from bimcap.registration.global_align import _storeys

    plan, attic = _attic_plan(demo)
    ground, top = _storeys(plan, 1.0)
    assert ground.shell is None and top.ceiling_z is None
    assert set(top.shell_rows) == set(ground.rows) | set(top.rows)
    lo = demo.segments.reshape(-1, 2).min(0)
    hi = demo.segments.reshape(-1, 2).max(0)
    mid = 0.5 * (lo + hi)
    cams = np.c_[np.linspace(lo[0] + 2.0, hi[0] - 2.0, 20), np.full(20, mid[1] + 0.2),
                 np.full(20, 4.6), np.zeros((20, 3)), np.ones(20)]
    assert initial_free_fraction(cams, plan) == 1.0
    gt = poses_along(np.array([[lo[0] + 3.0, mid[1] - 1.0], [hi[0] - 3.0, mid[1] - 1.0],
                               [hi[0] - 3.0, mid[1] + 1.0], [lo[0] + 3.0, mid[1] + 1.0],
                               [lo[0] + 3.0, mid[1] - 1.0]]), 0.25, height=4.6)[:60]
    samples, slam = _slam_case(gt, attic, seed=1)
    # Two gables with a window each are nearly each other's 180 deg image: flagged or not, the
    # best placement must be the attic's right one (before: refused, the best on the ground
    # floor fitting badly).
    res = global_align(slam.trajectory.poses, samples, plan,
                       GlobalAlignOptions(accept_ambiguous=True))
    assert res.hypotheses[0].floor_z == pytest.approx(3.1)
    moved, yaw = _placement_error(res.world_from_slam, slam)
    assert moved < 1.0 and yaw < 10.0, (moved, yaw)


def test_rooms_of_different_widths_are_told_apart_by_what_is_seen_through_walls() -> None:
    """A walk in the wider of two rooms that are each other's 180 deg image up to 0.24 m of
    width: the positive score alone (each frame may shift 0.2 m) rates the narrower room's
    placement at 97 % of the right one and refuses; in the narrower room the sensor's rays
    pass through its walls, and the negative evidence places the walk right. Truly symmetric
    rooms stay flagged (``test_a_symmetric_layout_is_flagged_not_guessed``)."""
    scene = _rooms_of_two_widths(6.12)
    gt = poses_along(np.array([[1.0, 2.5], [4.5, 2.5], [4.5, 4.0], [1.0, 4.0], [1.0, 1.5],
                               [4.0, 1.5]]), 0.25)
    samples, slam = _slam_case(gt, scene, seed=0)
    with pytest.raises(AmbiguousAlignmentError) as info:
        global_align(slam.trajectory.poses, samples, scene.floor_plan(),
                     GlobalAlignOptions(see_through_power=0.0, range_power=0.0))
    old = info.value.result
    assert old is not None and old.ratio >= 0.9
    assert _placement_error(old.hypotheses[0].world_from_slam, slam)[1] < 5.0
    assert _placement_error(old.hypotheses[1].world_from_slam, slam)[1] > 170.0
    res = global_align(slam.trajectory.poses, samples, scene.floor_plan())
    moved, yaw = _placement_error(res.world_from_slam, slam)
    assert moved < 0.5 and yaw < 3.0, (moved, yaw)
    assert not res.ambiguous and res.ratio < 0.9  # 0.856 (margin from the wall; was < 0.85)
    right, alias = res.hypotheses[0], res.hypotheses[1]
    assert _placement_error(alias.world_from_slam, slam)[1] > 170.0
    assert alias.see_through > right.see_through + 0.03
    assert right.score == pytest.approx(
        right.fit_score * right.free_fraction * (1 - right.see_through) ** 3
        * right.range_agreement ** 3)
    assert alias.range_agreement < right.range_agreement


def test_the_right_storey_is_picked(demo: Scene) -> None:
    # Ground floor: the symmetric rooms; upper floor (3.1 m): the demo building's plan.
    lower = _symmetric_rooms()
    upper = Scene(demo.segments, demo.segment_class, 3.1, 5.9)
    seg_z = np.r_[np.tile([0.0, 2.9], (len(lower.segments), 1)),
                  np.tile([3.1, 6.0], (len(upper.segments), 1))]
    plan = FloorPlan(np.r_[lower.segments, upper.segments],
                     np.r_[lower.segment_class, upper.segment_class], seg_z,
                     np.array([0.0, 3.1]), np.array([2.8, 5.9]))
    gt = poses_along(demo_tour(seed=0), 0.25, height=4.6)[60:110]
    samples, slam = _slam_case(gt, upper, seed=2)
    res = global_align(slam.trajectory.poses, samples, plan)
    assert res.hypotheses[0].floor_z == pytest.approx(3.1)
    assert [s["floor_z"] for s in res.storeys] == [0.0, 3.1]
    moved, yaw = _placement_error(res.world_from_slam, slam)
    assert moved < 0.5 and yaw < 3.0, (moved, yaw)
    assert abs(np.median(res.poses[:, 2] - gt[:, 2])) < 0.15


def test_identical_storeys_are_flagged_whatever_the_scores(demo: Scene) -> None:
    """Two storeys with the demo building's plan (3.1 m apart): the scan fits both the same, the
    SLAM frame gives no height, so the storey is unknown. Flagged because the other storey
    explains the placed scan exactly as well (twin_storeys), not through a score ratio that noise
    can push either way: even with a ratio threshold of 1 (scores never flag) it is ambiguous.
    With one wall the walk sees moved on the other storey, the storeys are told apart."""
    from bimcap.registration.global_align import _storeys, twin_storeys

    n = len(demo.segments)
    seg_z = np.r_[np.tile([0.0, 2.9], (n, 1)), np.tile([3.1, 6.0], (n, 1))]
    segments = np.r_[demo.segments, demo.segments[:, [2, 3, 0, 1]]]  # ends swapped: same walls
    plan = FloorPlan(segments, np.r_[demo.segment_class, demo.segment_class], seg_z,
                     np.array([0.0, 3.1]), np.array([2.8, 5.9]))
    gt = poses_along(demo_tour(seed=0), 0.25, height=4.6)[60:110]
    samples, slam = _slam_case(gt, Scene(demo.segments, demo.segment_class, 3.1, 5.9), seed=2)
    with pytest.raises(AmbiguousAlignmentError, match="identical twin") as info:
        global_align(slam.trajectory.poses, samples, plan,
                     GlobalAlignOptions(ambiguity_ratio=1.0))
    res = info.value.result
    assert res.ambiguous and len(res.twin_floors) == 1
    assert res.to_dict()["twin_floors"] == res.twin_floors
    taken = global_align(slam.trajectory.poses, samples, plan,
                         GlobalAlignOptions(ambiguity_ratio=1.0, accept_ambiguous=True))
    assert taken.accepted_ambiguous
    # the unit: points on the storeys' shared walls; one storey with a wall elsewhere
    sections = _storeys(plan, 1.0)
    wall = demo.segments[0]
    on_wall = wall[:2] + np.linspace(0.05, 0.95, 200)[:, None] * (wall[2:] - wall[:2])
    assert twin_storeys(on_wall, sections[0], sections, plan) == [1]
    moved = plan.segments.copy()
    moved[n] += np.array([0.0, 0.3, 0.0, 0.3]) if wall[0] != wall[2] else [0.3, 0.0, 0.3, 0.0]
    other = FloorPlan(moved, plan.segment_class, seg_z, plan.floor_heights,
                      plan.ceiling_heights)
    moved_sections = _storeys(other, 1.0)
    assert twin_storeys(on_wall, moved_sections[0], moved_sections, other) == []


def test_gravity_from_the_floor_levels_a_tilted_slam_frame(demo: Scene) -> None:
    gt = poses_along(demo_tour(seed=0), 0.25)[224:274]
    samples, slam = _slam_case(gt, demo, seed=3)
    tilt = np.r_[0.0, 0.0, 0.0, Rotation.from_euler("xy", [4.0, -3.0], degrees=True).as_quat()]
    tilted = compose(tilt, slam.trajectory.poses)
    # (Repeated rooms make 50 frames of this walk ambiguous; the best is right, see below.)
    accept = GlobalAlignOptions(accept_ambiguous=True)
    res = global_align(tilted, samples, demo.floor_plan(), accept)
    assert res.gravity_applied and res.gravity_tilt_deg == pytest.approx(5.0, abs=1.0)
    true = compose(invert(slam.slam_from_world), slam.trajectory.poses)
    assert np.linalg.norm(res.poses[:, :3] - true[:, :3], axis=1).mean() < 0.5
    # An IMU-level frame is left alone (the per-frame tilt noise averages to < 2 deg).
    level = global_align(slam.trajectory.poses, samples, demo.floor_plan(), accept)
    assert not level.gravity_applied


def _frames_short_of_their_walls(samples, every: int, scale: float):
    """``samples`` with the wall points of every ``every``-th frame pulled towards their camera
    (times ``scale``): those frames see walls where the plan has none (a wall missing or moved
    as built), short of the plan's, so they fit badly but see nothing through a wall."""
    bad = samples.wall_frame % every == 0
    p = samples.wall_p_in_cam.copy()
    p[bad] *= scale
    return replace(samples, wall_p_in_cam=p)


def test_a_placement_refused_for_a_few_badly_fitting_frames_is_placed_on_the_rest(
        demo: Scene) -> None:
    """A quarter of the frames see walls 60 % short of the plan's: the fit over every frame
    falls under the minimum (0.7 here), the same fit without the worst tenth of the frames does
    not, and nothing else comes near; the placement is taken, right. Where a second placement
    scores 39 % of the best, the same scan stays refused (pipeline seed 15: as-built
    deviations, fit 0.64 at 0.65, docs/global_align.md)."""
    walk = poses_along(demo_tour(seed=0), 0.25)
    opt = GlobalAlignOptions(min_score=0.7)
    samples, slam = _slam_case(walk[0:60], demo, seed=1)
    samples = _frames_short_of_their_walls(samples, 4, 0.4)
    with pytest.raises(GlobalAlignmentError, match="fits badly"):  # the fit alone
        global_align(slam.trajectory.poses, samples, demo.floor_plan(),
                     replace(opt, fit_trim_frames=0.0))
    res = global_align(slam.trajectory.poses, samples, demo.floor_plan(), opt)
    moved, yaw = _placement_error(res.world_from_slam, slam)
    assert moved < 0.5 and yaw < 3.0, (moved, yaw)
    tf = res.trimmed_fit
    assert tf is not None and tf.accepted and tf.frames_set_aside == 6
    assert res.hypotheses[0].fit_score < opt.min_score <= tf.trimmed
    assert res.ratio <= opt.fit_trim_max_ratio
    assert json.loads(json.dumps(res.to_dict()))["trimmed_fit"]["accepted"]
    # A competitor near (ratio above fit_trim_max_ratio): refused, the trimmed fit reported.
    samples, slam = _slam_case(walk[120:180], demo, seed=1)
    samples = _frames_short_of_their_walls(samples, 4, 0.4)
    with pytest.raises(GlobalAlignmentError) as info:
        global_align(slam.trajectory.poses, samples, demo.floor_plan(), opt)
    res = info.value.result
    assert res is not None and res.ratio > opt.fit_trim_max_ratio
    assert res.trimmed_fit is None or not res.trimmed_fit.accepted


def test_a_wrong_bim_and_bad_input_are_errors(demo: Scene) -> None:
    gt = poses_along(demo_tour(seed=0), 0.25)[0:30]
    samples, slam = _slam_case(gt, demo, seed=5)
    tiny = Scene(np.array([[0.0, 0.0, 1.0, 0.0]]), np.array([1], np.int32))
    with pytest.raises(GlobalAlignmentError):
        global_align(slam.trajectory.poses, samples, tiny.floor_plan())
    with pytest.raises(RegistrationInputError) as info:
        global_align(slam.trajectory.poses[:, :6], samples, demo.floor_plan())
    assert info.value.field == "slam_from_cam"
    for name, value in (("ambiguity_ratio", 1.5), ("yaw_step_deg", 0.0), ("top_k", 0),
                        ("see_through_power", -1.0), ("see_through_margin_m", float("nan")),
                        ("fit_trim_frames", 1.5), ("fit_trim_max_ratio", -0.1)):
        with pytest.raises(RegistrationInputError) as info:
            GlobalAlignOptions(**{name: value})
        assert info.value.field == name


def test_refine_settings_flags_and_toml(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    import tomllib

    from bimcap.cli import main
    from bimcap.pipeline.config import ConfigError, GlobalAlignMode, RefineConfig

    assert RefineConfig().global_align is GlobalAlignMode.AUTO
    assert RefineConfig(global_align=True).global_align is GlobalAlignMode.ON  # type: ignore
    assert RefineConfig(global_align=False).global_align is GlobalAlignMode.OFF  # type: ignore
    with pytest.raises(ConfigError) as info:
        RefineConfig(global_align="sometimes")  # type: ignore[arg-type]
    assert info.value.field == "global_align"
    toml = tmp_path / "run.toml"
    toml.write_text('global_align = "on"\naccept_ambiguous = true\n')
    cfg = RefineConfig.from_toml(toml)
    assert cfg.global_align is GlobalAlignMode.ON and cfg.accept_ambiguous
    assert cfg.to_dict()["global_align"] == "on"
    # Flags reach the settings, and --print-config writes them back as TOML.
    assert main(["refine", "--print-config", "--global-align", "--accept-ambiguous"]) == 0
    printed = tomllib.loads(capsys.readouterr().out)
    assert printed["global_align"] == "on" and printed["accept_ambiguous"] is True
    assert main(["refine", "--print-config", "--no-global-align"]) == 0
    assert tomllib.loads(capsys.readouterr().out)["global_align"] == "off"
    assert main(["refine", "--print-config"]) == 0
    assert tomllib.loads(capsys.readouterr().out)["global_align"] == "auto"


@pytest.mark.slow
def test_refine_from_a_slam_frame_reaches_the_exp2_level(tmp_path, monkeypatch) -> None:
    """End to end on the demo building (60 frames at 1/8 resolution, measured 1.9 cm / 0.34 deg
    after 2.7 s of global alignment): ``bimcap drift --slam-frame`` writes a trajectory tens of
    metres and any yaw away; ``bimcap refine`` notices (auto), aligns, and refines to the level
    of an aligned start. With a strict ambiguity threshold the same run refuses and writes the
    ranked placements to result.json."""
    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    import functools

    import bimcap.registration as registration
    from bimcap.cli import main
    from bimcap.geometry import read_tum
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world

    opts = DemoOptions(preset="demo", frames=60, scale=0.125, fps=2.0)
    design, built = make_world(tmp_path, opts, quiet=True)
    seq = make_sequence(tmp_path, design, built, opts, quiet=True)
    slam = tmp_path / "slam.tum"
    assert main(["drift", str(seq), "--preset", "exp2", "--seed", "2", "--slam-frame", "-o",
                 str(slam)]) == 0
    truth = json.loads((tmp_path / "slam.drift.json").read_text())["slam_frame"]
    out = tmp_path / "run"
    args = ["refine", str(seq), "--ifc", str(design), "--init", str(slam), "-o", str(out),
            "--no-report", "-q", "--workers", "1"]
    # 1. Refused: every placement is "ambiguous" under a 0 threshold; exit 3, result.json
    # holds the ranked placements (the best is the truth) and no trajectory is written.
    strict = functools.partial(registration.GlobalAlignOptions, ambiguity_ratio=0.0)
    with monkeypatch.context() as m:
        m.setattr(registration, "GlobalAlignOptions", strict)
        assert main(args) == 3
    refused = json.loads((out / "result.json").read_text())
    assert refused["status"] == "refused" and not (out / "refined.tum").exists()
    hyps = refused["solve"]["global_align"]["hypotheses"]
    assert len(hyps) >= 2 and hyps[0]["score"] >= hyps[1]["score"]
    best = np.array(hyps[0]["world_from_slam"])
    assert np.linalg.norm(best[:2] - np.array(truth["world_from_slam"])[:2]) < 1.5
    # 2. Aligned and refined (auto mode: the SLAM frame lies outside the building).
    assert main(args) == 0
    result = json.loads((out / "result.json").read_text())
    ga = result["solve"]["global_align"]
    assert ga["mode"] == "auto" and ga["initial_free_fraction"] < 0.3 and not ga["ambiguous"]
    assert result["metrics_before"]["ate_pos_m"]["rmse"] > 5.0
    assert result["metrics_after"]["ate_pos_m"]["rmse"] < 0.03
    assert result["metrics_after"]["ate_rot_deg"]["rmse"] < 0.5
    gt = read_tum(seq / "poses" / "gt.tum")
    np.testing.assert_array_equal(read_tum(out / "refined.tum").timestamps, gt.timestamps)


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (an attic without a ceiling plane)
@pytest.mark.parametrize(("model", "seeds"), [("Duplex_A_20110907", (8, 14, 16, 19)),
                                              ("AC20-FZK-Haus", (11,))])
def test_real_models_are_never_silently_wrong(ifc_dir, monkeypatch, model: str,
                                              seeds: tuple[int, ...]) -> None:
    """The runs of ``bench/bench_global.py`` (Exp 2 drift, SLAM frame, 60 frames) that were
    placed wrong without a flag: Duplex_A is two point-symmetric units (drift ranked the wrong
    unit first: seeds 8, 14, 19, flagged now by the plan alias); the AC20-FZK-Haus attic's plan
    section holds only its two gable walls (seed 11 was placed on the ground floor, turned by
    90 deg, with a per-frame fit of 0.59 where every right placement of the bench fits >= 0.71;
    refused now under the 0.65 minimum). Each must now be right, flagged or refused. Duplex_A
    seed 16 (the wrong unit best, its alias at 0.91 of it without the range agreement, 0.79 with
    it) was placed wrong by the first version of the range agreement: an alias's ratio is now the
    larger of the two."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world(f"ifc-{model}", ifc_dir)
    for seed in seeds:
        row = bench.run_registration(world, seed, 60)
        assert row["outcome"] != "placed" or row["right"], row


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (an attic without a ceiling plane)
def test_fzk_runs_once_refused_are_answered(ifc_dir, monkeypatch) -> None:
    """``bench/bench_global.py`` on AC20-FZK-Haus ended 14 of 20 runs in errors. Seed 3 (ground
    floor) was placed right but refused: 22 % of its points counted as seen through walls, rays
    grazing the walls of 4 m rooms with drifted points a few centimetres behind the face (the
    margin is now measured from the wall). Seed 2 walks the attic, whose plan section is its
    two gable walls: no camera was in free space (the roof, resting on the ground floor's walls,
    now encloses it), so the best placement was on the ground floor and fitted 0.55. The attic's
    two gables repeat each other turned by 180 deg: flagged on the attic. Which of the two
    images comes first is not something the scan can decide (the right one did on the walk
    simulated when this test was written; the walk simulated by today's code puts the other
    gable first, 6.6 m off): the test asks for the flag and the storey, not the order."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world("ifc-AC20-FZK-Haus", ifc_dir)
    row = bench.run_registration(world, 3, 60)
    assert row["outcome"] == "placed" and row["right"], row
    row = bench.run_registration(world, 2, 60)
    assert row["outcome"] == "ambiguous" and row["right_storey"], row


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (an attic without a ceiling plane)
def test_a_floor_plane_change_of_millimetres_does_not_turn_duplex_silently_wrong(
        ifc_dir, monkeypatch) -> None:
    """Duplex_A with its floor planes merged within 2 mm instead of 2 cm
    (``PlaneOptions.height_tol_m``): bench_global's seed 14 scored its 180 deg alias (the other
    unit, ideal difference 0.04) at 0.875 of the best, under the 0.9 ratio threshold, and was
    placed 7.3 m / 179 deg off without a flag. The near-exact alias rule flags it."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world("ifc-Duplex_A_20110907", ifc_dir, height_tol_m=0.002)
    row = bench.run_registration(world, 14, 60)
    assert row["outcome"] != "placed" or row["right"], row


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (an attic without a ceiling plane)
def test_duplex_walks_that_fitted_nowhere_find_their_storey(ifc_dir, monkeypatch) -> None:
    """``bench/bench_global.py`` on Duplex_A refused seeds 4, 5, 9 and 19: the best placement on
    any storey fitted 0.44-0.61, on the basement's foundation walls or on the wrong unit, while
    the truth on the walk's own storey fits 0.83 (seed 4; 0.87 with no drift at all). The
    correlative search never had a peak there: the stray returns (5 % clutter) filled 77 % of
    the template's cells. With the cells weighted by their support each finds its storey and
    the two units (the plan's 180 deg repetition) flag it."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world("ifc-Duplex_A_20110907", ifc_dir)
    for seed in (4, 9):
        row = bench.run_registration(world, seed, 60)
        assert row["outcome"] == "ambiguous" and row["right_storey"] and row["fit"] > 0.75, row


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (storeys without a floor slab)
def test_office_walks_once_refused_are_placed(ifc_dir, monkeypatch) -> None:
    """``bench/bench_global.py`` refused every Office_A run of seeds 0-9 (50 x 36 m, three
    storeys): the best placement was another place fitting 0.30-0.67 (seed 0: 23 m off, fit
    0.53; seed 2: 42 m off, fit 0.59) while the truth fits 0.88 there. With the binary template
    the truth's cell ranked 1255th (seed 0) and 27205th (seed 2) in the search volume, so no
    peak was near it: the stray returns' cells outweighed the walls, as in Duplex_A. With the
    cells weighted by their support (``template_support`` 10, ``rescore_top`` 8) it ranks 2nd
    and 7th, and both walks are placed right, unflagged."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world("ifc-Office_A_20110811", ifc_dir)
    for seed in (0, 2):
        row = bench.run_registration(world, seed, 60)
        assert row["outcome"] == "placed" and row["right"] and row["right_storey"], row
        assert row["fit"] > 0.8, row


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.filterwarnings("ignore")  # the real models warn (storeys without a floor slab)
def test_an_office_walk_blurred_by_its_frames_yaw_errors_is_placed(ifc_dir, monkeypatch) -> None:
    """Office_A seed 12 was refused: its frames' yaw errors (7 deg RMS, independent per frame)
    blur the walk taken as one rigid scan (rigid fit 0.42 at the truth), no search peak lay near
    the truth, and the best, 18 m off, saw 18 % of its points through walls. Searched again
    with each frame turned by the yaw error its own walls tell (``FrameYaw.ON_REFUSAL``), it
    is placed right, unflagged; without, it is still refused (never silently wrong)."""
    bench = _bench_global(monkeypatch)
    world = bench._ifc_world("ifc-Office_A_20110811", ifc_dir)
    row = bench.run_registration(world, 12, 60)
    assert row["outcome"] == "placed" and row["right"] and row["right_storey"], row
    assert row["frames_turned"], row
    off = bench.run_registration(world, 12, 60, GlobalAlignOptions(frame_yaw="off"))  # type: ignore[arg-type]
    assert off["outcome"] == "error" and not off["frames_turned"], off


def _bench_global(monkeypatch):
    """``bench/bench_global.py`` as a module."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "bench_global.py"
    spec = importlib.util.spec_from_file_location("bench_global", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "bench_global", bench)  # its dataclasses look it up
    spec.loader.exec_module(bench)
    return bench


def test_the_pipeline_level_turns_every_run_into_a_row(monkeypatch) -> None:
    """``bench/bench_global.py --pipeline``: a refused or failed ``bimcap refine`` is a row with
    its outcome, never a traceback (pipeline seed 3 once crashed the bench); a diverged solve
    exits 3 like a refusal, only ``result.json``'s ``status`` tells them apart."""
    bench = _bench_global(monkeypatch)
    err = ("[bimcap] WARNING: ...\nbimcap refine: error: the solve diverged: frame(s) [0] of 60 "
           "lie more than 10 m outside the building\n")
    assert bench._error_line(err).startswith("the solve diverged")
    assert bench.pipeline_outcome(3, None, bench._error_line(err)) == "error"
    refused = {"status": "refused", "solve": {"global_align": {"ambiguous": False}}}
    assert bench.pipeline_outcome(3, refused, "global alignment: fits badly") == "refused"
    refused["solve"]["global_align"]["ambiguous"] = True
    assert bench.pipeline_outcome(3, refused, "") == "refused-ambiguous"
    done = {"solve": {"global_align": {"ratio": 0.1}}}
    assert bench.pipeline_outcome(0, done, "") == "placed"
    assert bench.pipeline_outcome(0, {"solve": {"global_align": {"fallback": "x"}}},
                                  "") == "fallback"
    assert bench.pipeline_outcome(0, {"solve": {}}, "") == "not-run"
    # Within: at the Exp 2 level, or at most 1 mm / 0.03 deg worse than the aligned start.
    assert bench.ends_within(3.62, 0.357, 3.61, 0.359)
    assert bench.ends_within(1.9, 0.2, 1.2, 0.1)
    assert not bench.ends_within(3.9, 0.3, 3.6, 0.3)
    assert not bench.ends_within(1.5, 0.5, 1.5, 0.4)
    row = {"seed": 3, "outcome": "refused", "slam_rc": 3, "slam_ate_cm": float("nan"),
           "slam_ate_deg": float("nan"), "aligned_ate_cm": 3.79, "aligned_ate_deg": 0.436,
           "within": False, "silently_wrong": False, "global_seconds": float("nan"),
           "slam_seconds": 30.0}
    table = bench.summarise_pipeline([row])
    assert "refused" in table and "0/1" in table and "1 flagged" in table
    # The trimmed fit (result.json's or the result's), NaN where it was not measured.
    assert bench._trimmed_columns({"trimmed": 0.68, "accepted": True}) == {
        "trimmed_fit": 0.68, "trimmed_accepted": True}
    assert not bench._trimmed_columns(None)["trimmed_accepted"]


def test_a_scan_of_another_building_is_refused(monkeypatch) -> None:
    """A wrong BIM (``bench_global.py --wrong-plan``): a walk through ``tiny`` (a corridor and
    two rooms) aligned against ``long``'s plan (a 24 m corridor, 9 rooms) is refused: on the
    scan as given the best fits badly, on the turned scan its second-best scores 62 % of it
    (docs/global_align.md, "A wrong building"). The bench's row names the gates it failed."""
    bench = _bench_global(monkeypatch)
    tiny, long_ = bench._world("tiny"), bench._world("long")
    row = bench.run_registration(tiny, 0, 60, plan_world=long_)
    assert row["outcome"] == "error" and not row["right"]
    assert (row["world"], row["plan"]) == ("tiny", "long") and "is this the right BIM" in row["why"]
    assert row["fit"] < GlobalAlignOptions().min_score
    assert bench.wrong_plan_refusals(row) == ["fit", "turned-ratio"]
    row["refused_by"] = ",".join(bench.wrong_plan_refusals(row))
    table = bench.summarise_wrong_plan([row])
    assert "1 runs, 0 placed" in table and "1 refused" in table
    # The gates, read from a row's numbers (a trimmed fit over the minimum held by its ratio).
    base = {"fit": 0.63, "trimmed_fit": 0.67, "trimmed_accepted": False, "free": 0.95,
            "see_through": 0.09, "window_accepted": False, "outcome": "error", "ratio": 0.8,
            "twins": 0, "frames_turned": False}
    assert bench.wrong_plan_refusals(base) == ["trim-ratio"]
    assert bench.wrong_plan_refusals({**base, "fit": 0.7, "see_through": 0.2}) == ["see"]
    assert bench.wrong_plan_refusals({**base, "fit": 0.7, "outcome": "placed",
                                      "ratio": 0.6}) == []
    # A storey of a building the plan holds is not a wrong building (stack = demo + long).
    assert bench.same_building("long", 0, "stack") and bench.same_building("stack", 0, "demo")
    assert bench.same_building("stack", 1, "long") and not bench.same_building("stack", 0, "long")
    assert not bench.same_building("tiny", 0, "demo")


@pytest.mark.xfail(strict=True, reason="open (issue 15): a scan of a building that is a part of "
                   "another fits there like a right placement (docs/global_align.md, 'A wrong "
                   "building')")
def test_a_building_that_is_a_part_of_another_is_not_placed_in_it(monkeypatch) -> None:
    """``tiny``'s corridor and two rooms, walked on seed 1, fit a part of ``demo``'s corridor:
    fit 0.67, free space 97 %, seen through walls 5 %, second-best at 70 %, every gate passed;
    it is placed 5.4 m from where it was walked, in another building. No statistic measured
    (fit, ratio, range agreement, the worst frames' fit) tells it from the registration
    bench's right placements (long seed 19: fit 0.73, ratio 0.46)."""
    bench = _bench_global(monkeypatch)
    row = bench.run_registration(bench._world("tiny"), 1, 60,
                                 plan_world=bench._world("demo"))
    assert row["outcome"] != "placed", row


def _yaw_noise(poses: np.ndarray, yaw_deg: np.ndarray) -> np.ndarray:
    """``poses`` (N, 7) with frame i turned about the vertical through its camera by
    ``yaw_deg[i]`` (the Exp 2 drift's per-frame yaw error)."""
    out = poses.copy()
    turn = Rotation.from_euler("z", yaw_deg[:, None], degrees=True)
    out[:, 3:] = (turn * Rotation.from_quat(poses[:, 3:])).as_quat()
    return out


def test_each_frames_yaw_error_is_read_from_its_walls_alone(demo: Scene) -> None:
    """The per-frame yaw errors of a walk, taken out by the scan's own wall directions: no plan,
    no placement. Every frame turned by up to 12 deg (independent per frame, the Exp 2 drift's
    kind). The frames that see enough straight wall (40 of 60 here; the others, facing a
    corner or a column, are left alone) come back to within a few degrees, and the whole
    scan's error shrinks from 7.2 to 4.3 deg RMS (the median frame's error is the whole scan's
    yaw, left to the search)."""
    gt = poses_along(demo_tour(seed=0), 0.25)[224:284]
    samples = scan_sequence(gt, demo, seed=3, clutter_fraction=0.05)
    noise = np.random.default_rng(5).uniform(-12.0, 12.0, len(gt))
    opt = GlobalAlignOptions()
    scan = _scan(_yaw_noise(gt, noise), samples, opt.frame_level_max_deg)
    est = np.rad2deg(_frame_yaws(scan, opt))
    noise -= np.median(noise)
    err = noise - est
    err -= np.median(err)
    turned = est != 0
    assert turned.sum() >= 30, est
    assert np.sqrt(np.mean(err ** 2)) < 0.7 * np.sqrt(np.mean(noise ** 2)), err
    assert np.median(np.abs(err[turned])) < 2.0, err[turned]
    # Turned back, the frames' walls line up again: at the true placement the rigid scan fits
    # the plan 0.77 (noisy 0.59, noiseless 0.90).
    plan_maps = _storey_maps(_storeys(demo.floor_plan(), opt.plan_cut_height_m)[0],
                             demo.floor_plan(), opt).maps
    ident = Correction2D(0.0, np.zeros(2), np.zeros(2))

    def rigid_fit(s: _Scan) -> float:
        keep = (s.z > 0.3) & (s.z < 2.2)
        layer = plan_maps.layer_of(s.cls[keep], s.view[keep])
        return float(plan_maps.fine_eval(ident.apply(s.xy[keep]), layer)[0].mean())

    clean = rigid_fit(_scan(gt, samples, opt.frame_level_max_deg))
    noisy, turned = rigid_fit(scan), rigid_fit(_turned(scan, _frame_yaws(scan, opt)))
    assert noisy + 0.1 < turned < clean, (clean, noisy, turned)


def test_the_frame_yaw_mode_is_checked_and_recorded(demo: Scene) -> None:
    with pytest.raises(RegistrationInputError, match="frame_yaw"):
        GlobalAlignOptions(frame_yaw="sometimes")  # type: ignore[arg-type]
    assert GlobalAlignOptions(frame_yaw="always").frame_yaw is FrameYaw.ALWAYS  # type: ignore[arg-type]
    gt = poses_along(demo_tour(seed=0), 0.25)[224:284]
    samples, slam = _slam_case(gt, demo, seed=1)
    plan = demo.floor_plan()
    # Placed at once: the default (on refusal only) is the scan as given, bit for bit.
    off = global_align(slam.trajectory.poses, samples, plan, GlobalAlignOptions(frame_yaw="off"))
    default = global_align(slam.trajectory.poses, samples, plan)
    assert not default.frames_turned and "frame_yaw" not in default.timings
    np.testing.assert_array_equal(default.world_from_slam, off.world_from_slam)
    turned = global_align(slam.trajectory.poses, samples, plan,
                          GlobalAlignOptions(frame_yaw="always"))  # type: ignore[arg-type]
    assert turned.frames_turned and turned.to_dict()["frames_turned"] is True
    assert turned.to_dict()["options"]["frame_yaw"] == "always"
    moved, yaw = _placement_error(turned.world_from_slam, slam)
    assert moved < 0.5 and yaw < 3.0, (moved, yaw)
