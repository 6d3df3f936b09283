"""Keypoint depth look-up, tracks by connected components, the peers' match filters."""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.features import (
    DepthEdgePolicy,
    DepthLookupOptions,
    FeatureError,
    MatchFilterOptions,
    PairMatches,
    RequireDepth,
    assemble_match_observations,
    build_tracks,
    consistent_track_observations,
    frame_gap_ok,
    lookup_depth,
    triangulate_tracks,
    unsupported_depths,
)
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import invert, transform_points

CAM = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)
IDENTITY = np.array([0.0, 0, 0, 0, 0, 0, 1])


def _pair(a: int, b: int, idx: list[list[int]]) -> PairMatches:
    return PairMatches(a, b, np.asarray(idx, np.int32).reshape(-1, 2), len(idx), "test")


# --------------------------------------------------------------------------- depth look-up
def test_bilinear_depth_on_a_ramp() -> None:
    """depth = 2 + 0.01·u + 0.02·v is bilinear, so interpolation is exact."""
    v, u = np.mgrid[0:48, 0:64]
    depth = (2.0 + 0.01 * u + 0.02 * v).astype(np.float32)
    uv = np.array([[10.25, 7.5], [0.0, 0.0], [62.9, 46.9], [30.0, 20.0]])
    got = lookup_depth(depth, uv)
    want = 2.0 + 0.01 * uv[:, 0] + 0.02 * uv[:, 1]
    assert np.allclose(got, want, atol=1e-6)


def test_depth_edges_and_holes() -> None:
    depth = np.full((48, 64), 2.0, np.float32)
    depth[:, 32:] = 5.0  # a depth edge between columns 31 and 32
    depth[10, 10] = 0.0  # a hole
    uv = np.array([[31.5, 20.0], [31.2, 20.0], [10.3, 10.2], [20.0, 20.0], [-3.0, 5.0],
                   [70.0, 5.0]])
    got = lookup_depth(depth, uv)
    assert got.tolist() == [0.0, 0.0, 0.0, 2.0, 0.0, 0.0]
    near = lookup_depth(depth, uv, DepthLookupOptions(edge_policy=DepthEdgePolicy.NEAREST))
    # nearest of (31.5 → 32) is the far side, (31.2 → 31) the near side; the hole's nearest is
    # the hole itself (10, 10) → still 0.
    assert near.tolist() == [5.0, 2.0, 0.0, 2.0, 0.0, 0.0]


def _wall_returns(seed: int, noise_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A wall 3–3.4 m away seen by a 200 × 150 image: (truth (H, W) z-depth, measured (H, W):
    1500 returns at random pixels with ``noise_m`` of range noise, 0 elsewhere)."""
    rng = np.random.default_rng(seed)
    _, u = np.mgrid[0:150, 0:200]
    truth = 3.0 + 0.002 * u
    measured = np.zeros_like(truth)
    at = rng.choice(truth.size, 1500, replace=False)
    measured.flat[at] = truth.flat[at] + rng.normal(0.0, noise_m, at.size)
    return truth, measured


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_depth_map_that_left_its_returns_gives_its_keypoints_no_depth(seed: int) -> None:
    """gen-small-s3 hard frame 56 (docs/generalization.md): a plane fitted across a corner put a
    strip of wall 5–10 cm off under 8 cm returns; each pixel looked plausible (the 2 × 2 check
    passes it) and G's matches there pulled the frame 1.7° off. The returns around such a
    keypoint disagree with the map on average: its depth goes; on a map that follows the
    returns (the right plane, an interpolating completion) hardly any does."""
    from bimcap.fusion import complete_depth

    truth, measured = _wall_returns(seed, 0.08)
    off = truth.copy()
    off[:, :60] += 0.08 + 0.08 * np.arange(60) / 59  # 8–16 cm off, a ramp (a turned plane)
    gv, gu = np.mgrid[4:146:6, 4:196:6]
    uv = np.stack([gu.ravel(), gv.ravel()], 1).astype(np.float64) + 0.3
    inside, outside = uv[:, 0] < 60 - 12, uv[:, 0] > 60 + 12
    # the 2 × 2 look-up keeps every depth of the patch that is off
    assert (lookup_depth(off.astype(np.float32), uv)[inside] > 0).all()
    flagged = unsupported_depths(off, measured, uv, 0.08)
    assert flagged[inside].mean() > 0.9
    assert flagged[outside].mean() < 0.02
    assert unsupported_depths(truth, measured, uv, 0.08).mean() < 0.02
    completed = complete_depth(measured.astype(np.float32))  # passes through its returns
    assert not unsupported_depths(completed, measured, uv, 0.08).any()
    assert not unsupported_depths(off, measured, uv, 0.08,
                                  DepthLookupOptions(max_support_z=None)).any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_returns_are_the_kd_trees(seed: int) -> None:
    """The k returns nearest each keypoint (compiled, row by row) are scipy's cKDTree's, in its
    order, on returns in LiDAR-like rings and at random, queries anywhere (also outside the
    image); and the whole test gives the cKDTree version's flags bit for bit."""
    from scipy.spatial import cKDTree

    from bimcap import _core

    rng = np.random.default_rng(seed)
    h, w = 150, 200
    mask = np.zeros((h, w), bool)
    for r in range(6):  # curved rings, a return every ~2 px, and scattered returns
        u = np.arange(0, w, 2) + rng.integers(0, 2, w // 2)
        v = np.clip(np.rint(12 + 25 * r + 8 * np.sin(u / 40.0 + r)), 0, h - 1).astype(int)
        mask[v, np.clip(u, 0, w - 1)] = True
    mask.flat[rng.choice(h * w, 300, replace=False)] = True
    v, u = np.nonzero(mask)
    row_start = np.concatenate([[0], np.cumsum(np.bincount(v, minlength=h))]).astype(np.int64)
    q = np.concatenate([rng.uniform([0, 0], [w - 1, h - 1], (500, 2)),
                        rng.uniform([-30, -30], [w + 30, h + 30], (50, 2))])
    tree = cKDTree(np.stack([u, v], 1).astype(np.float64))
    for k in (1, 16, 40):
        got = _core.nearest_pixels(row_start, u.astype(np.int64), q, k)
        ref = np.asarray(tree.query(q, k=k)[1]).reshape(len(q), k)
        np.testing.assert_array_equal(got, ref)

    # unsupported_depths before the compiled search (cKDTree), on the same maps
    truth, measured = _wall_returns(seed, 0.08)
    off = truth.copy()
    off[:, :60] += 0.05 + 0.1 * rng.random((150, 60))
    uv = rng.uniform([0, 0], [199, 149], (400, 2))
    vv, uu = np.nonzero((measured > 0) & (off > 0))
    diff = measured[vv, uu] - off[vv, uu]
    _, idx = cKDTree(np.stack([uu, vv], 1).astype(np.float64)).query(uv, k=16)
    bias = diff[idx].mean(axis=1)
    expected = np.abs(bias) > 3.0 * 0.08 / np.sqrt(16)
    np.testing.assert_array_equal(unsupported_depths(off, measured, uv, 0.08), expected)


def test_unsupported_depths_rejects_bad_input() -> None:
    with pytest.raises(FeatureError, match="same"):
        unsupported_depths(np.ones((4, 5)), np.ones((5, 4)), np.zeros((1, 2)), 0.08)
    with pytest.raises(FeatureError, match="support_returns"):
        DepthLookupOptions(support_returns=0)
    with pytest.raises(FeatureError, match="max_support_z"):
        DepthLookupOptions(max_support_z=0.0)


def test_small_relative_spread_is_interpolated() -> None:
    depth = np.full((48, 64), 4.0, np.float32)
    depth[:, 32:] = 4.1  # 2.5 % step: below the 5 % default spread, interpolated
    got = lookup_depth(depth, np.array([[31.5, 3.0]]))
    assert got[0] == pytest.approx(4.05, abs=1e-6)
    strict = lookup_depth(depth, np.array([[31.5, 3.0]]),
                          DepthLookupOptions(max_relative_spread=0.01))
    assert strict[0] == 0.0


# --------------------------------------------------------------------------- tracks
def test_tracks_are_connected_components() -> None:
    # frame 0: 3 keypoints, frame 1: 3, frame 2: 2
    pairs = [
        _pair(0, 1, [[0, 0], [1, 2]]),
        _pair(1, 2, [[0, 1], [2, 0]]),
        _pair(0, 2, [[2, 0]]),  # joins 0:2 into the track of 0:1-1:2-2:0
    ]
    t = build_tracks([3, 3, 2], pairs)
    groups = {}
    for f, p, k in zip(t.obs_frame, t.obs_point, t.obs_keypoint, strict=True):
        groups.setdefault(int(p), set()).add((int(f), int(k)))
    assert set(map(frozenset, groups.values())) == {
        frozenset({(0, 0), (1, 0), (2, 1)}),
        # (0,1)-(1,2)-(2,0)-(0,2): keypoints 1 and 2 of frame 0 in one track → dropped
    }
    assert t.num_points == 1
    assert t.obs_frame.dtype == t.obs_point.dtype == np.int32


def test_track_min_length_and_empty() -> None:
    pairs = [_pair(0, 1, [[0, 0]]), _pair(1, 2, [[1, 0]]), _pair(0, 2, [])]
    t = build_tracks([1, 2, 1], pairs, min_length=2)
    assert t.num_points == 2
    t3 = build_tracks([1, 2, 1], pairs, min_length=3)
    assert t3.num_points == 0 and t3.obs_frame.shape == (0,)
    assert build_tracks([5, 5], []).num_points == 0
    with pytest.raises(FeatureError):
        build_tracks([1, 1], [_pair(0, 3, [[0, 0]])])


def test_triangulate_without_depth_recovers_the_point() -> None:
    """Two views of (0.3, -0.2, 4.0) with no depth: DLT gives it back; with depth, the mean."""
    p_world = np.array([0.3, -0.2, 4.0])
    poses = np.array([IDENTITY, [0.5, 0.0, 0.0, 0, 0, 0, 1]])
    uv = np.stack([CAM.project(transform_points(invert(pose), p_world[None]))[0][0]
                   for pose in poses])
    pts, valid = triangulate_tracks(
        np.array([0, 1], np.int32), np.array([0, 0], np.int32), uv, np.zeros(2), CAM, poses
    )
    assert valid.all() and np.allclose(pts[0], p_world, atol=1e-9)
    depth = np.array([4.0, 4.0])
    pts, valid = triangulate_tracks(
        np.array([0, 1], np.int32), np.array([0, 0], np.int32), uv, depth, CAM, poses
    )
    assert np.allclose(pts[0], p_world, atol=1e-9)


# --------------------------------------------------------------------------- the peers' filters
def test_frame_gap_is_unsigned() -> None:
    """The peers compared ``j − i >= k`` signed: (5, 2) with k = 3 would be dropped."""
    assert frame_gap_ok(np.array([5, 2, 4]), np.array([2, 5, 5]), 3).tolist() == [True, True, False]


def _two_frame_setup() -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Frame 1 is 1 m to the right of frame 0; keypoint k of both sees the same world point,
    except keypoint 1 of frame 1, which sees a point 0.5 m behind."""
    poses = np.array([IDENTITY, [1.0, 0.0, 0.0, 0, 0, 0, 1]])
    pts = np.array([[0.2, 0.1, 3.0], [0.6, -0.1, 2.5]])
    pts_b = pts.copy()
    pts_b[1, 2] += 0.5
    uv0, _ = CAM.project(transform_points(invert(poses[0]), pts))
    uv1, _ = CAM.project(transform_points(invert(poses[1]), pts_b))
    d0 = transform_points(invert(poses[0]), pts)[:, 2]
    d1 = transform_points(invert(poses[1]), pts_b)[:, 2]
    return [uv0, uv1], [d0, d1], poses


def test_distance_filter() -> None:
    uvs, depths, poses = _two_frame_setup()
    pairs = [_pair(0, 1, [[0, 0], [1, 1]])]
    obs = assemble_match_observations(pairs, uvs, depths, CAM, poses, MatchFilterOptions())
    assert obs.match_frames.tolist() == [[0, 1]]
    assert np.allclose(obs.match_uv[0], np.concatenate([uvs[0][0], uvs[1][0]]))
    assert np.allclose(obs.match_depth[0], [depths[0][0], depths[1][0]])
    loose = assemble_match_observations(
        pairs, uvs, depths, CAM, poses, MatchFilterOptions(max_initial_distance_m=0.6)
    )
    assert len(loose.match_frames) == 2
    off = assemble_match_observations(
        pairs, uvs, depths, CAM, poses, MatchFilterOptions(max_initial_distance_m=None)
    )
    assert len(off.match_frames) == 2
    assert off.match_frames.dtype == np.int32 and off.match_uv.shape == (2, 4)


def test_gap_and_depth_requirements() -> None:
    uvs, depths, poses = _two_frame_setup()
    uvs = [*uvs, uvs[1]]
    depths = [depths[0], depths[1], np.array([0.0, depths[1][1]])]
    poses = np.concatenate([poses, poses[1:]])
    pairs = [_pair(0, 1, [[0, 0]]), _pair(0, 2, [[0, 0]]), _pair(1, 2, [[1, 1]])]
    none_filter = MatchFilterOptions(max_initial_distance_m=None, require_depth=RequireDepth.NONE)
    assert len(assemble_match_observations(pairs, uvs, depths, CAM, poses,
                                           none_filter).match_frames) == 3
    both = MatchFilterOptions(max_initial_distance_m=None)
    got = assemble_match_observations(pairs, uvs, depths, CAM, poses, both)
    assert got.match_frames.tolist() == [[0, 1], [1, 2]]  # frame 2's keypoint 0 has no depth
    gap2 = MatchFilterOptions(min_frame_gap=2, max_initial_distance_m=None,
                              require_depth=RequireDepth.ANY)
    got = assemble_match_observations(pairs, uvs, depths, CAM, poses, gap2)
    assert got.match_frames.tolist() == [[0, 2]]
    assert got.match_depth[0, 1] == 0.0
    with pytest.raises(FeatureError):
        MatchFilterOptions(min_frame_gap=0)


def test_track_observation_consistency() -> None:
    """Three views of one point; the third view's depth is 1 m off: only it is flagged."""
    p_world = np.array([0.3, -0.2, 4.0])
    poses = np.array([IDENTITY, [0.3, 0.0, 0.0, 0, 0, 0, 1], [0.6, 0.0, 0.0, 0, 0, 0, 1]])
    p_cam = np.stack([transform_points(invert(pose), p_world[None])[0] for pose in poses])
    uv, _ = CAM.project(p_cam)
    depth = p_cam[:, 2].copy()
    depth[2] += 1.0
    frames = np.array([0, 1, 2], np.int32)
    point = np.zeros(3, np.int32)
    keep = consistent_track_observations(frames, point, uv, depth, CAM, poses, 0.4)
    assert keep.tolist() == [True, True, False]
    depth[2] = 0.0  # no depth: nothing to test, kept
    assert consistent_track_observations(frames, point, uv, depth, CAM, poses, 0.4).all()
