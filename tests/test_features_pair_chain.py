"""A repeated texture on a wall: the pair that matched the copy is dropped by the chain check.

The mechanism (gen-small-s3, hard setting): a camera walks along one wall whose finish repeats.
Two frames that see different pieces of the wall match each other's copy of the texture; the
matches lie on one plane, so the two-view verification keeps them (a plane maps onto its
shifted copy by a homography), and they ask the solve for a relative pose one texture period
off. The consecutive frames' pairs, which see the same piece, contradict it.
"""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.features import MatchFilterOptions, PairMatches
from bimcap.features.matching import MatchOptions, Verification, verify_matches
from bimcap.features.pair_chain import (
    PairChainOptions,
    chain_inconsistent_pairs,
    pair_pose,
    reprojection_px,
)
from bimcap.frontend.runner import FrontendConfig, _assemble
from bimcap.geometry.camera import Camera

CAM = Camera(516, 386, 880.0, 880.0, 258.0, 193.0)
STEP_M = 0.4  #: the camera moves this far along the wall per frame
PERIOD_M = 1.4  #: the texture repeats every this many metres along the wall
WALL_Z_M = 1.2  #: the wall is the plane z = 1.2 m of every camera (it only translates along x)
FRAMES = 6


def _cam_x(frame: int) -> float:
    """World x of the camera centre (world = frame 0's camera)."""
    return STEP_M * frame


def _project(p_world: np.ndarray, frame: int) -> np.ndarray:
    p = p_world - np.array([_cam_x(frame), 0.0, 0.0])
    return np.column_stack([CAM.fx * p[:, 0] / p[:, 2] + CAM.cx,
                            CAM.fy * p[:, 1] / p[:, 2] + CAM.cy])


def _visible(uv: np.ndarray) -> np.ndarray:
    return (uv[:, 0] >= 0) & (uv[:, 0] < CAM.width) & (uv[:, 1] >= 0) & (uv[:, 1] < CAM.height)


def _scene(seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray], list[PairMatches]]:
    """Keypoints of FRAMES frames on the wall (a 0.7 m wide view, 0.3 m shared by consecutive
    frames) and their pairs within a window of 3: wall points seen by both (right), and pair
    (1, 4), which see no common piece of the wall, matched frame 1's points to the copy of their
    texture one period further along (wrong, 1.4 m off)."""
    rng = np.random.default_rng(seed)
    n = 1500
    world = np.column_stack([rng.uniform(-0.5, _cam_x(FRAMES - 1) + 0.5, n),
                             rng.uniform(-0.25, 0.25, n), np.full(n, WALL_Z_M)])
    uvs: list[np.ndarray] = []
    depths: list[np.ndarray] = []
    for f in range(FRAMES):
        uv = _project(world, f)
        inside = _visible(uv)
        uvs.append(np.where(inside[:, None], uv, -1.0))
        depths.append(np.where(inside, WALL_Z_M + rng.normal(0, 0.01, n), 0.0))
    pairs: list[PairMatches] = []
    for a in range(FRAMES):
        for b in range(a + 1, min(FRAMES, a + 4)):
            both = np.flatnonzero((depths[a] > 0) & (depths[b] > 0))
            if len(both) and (a, b) != (1, 4):
                pairs.append(PairMatches(a, b, np.column_stack([both, both]).astype(np.int32),
                                         len(both), "test"))
    # The copy: frame 4 sees, one period along, the texture around frame 1's points.
    seen = np.flatnonzero(depths[1] > 0)
    copy_uv = _project(world[seen] + np.array([PERIOD_M, 0.0, 0.0]), 4)
    ok = _visible(copy_uv)
    seen, copy_uv = seen[ok], copy_uv[ok]
    start = len(uvs[4])
    uvs[4] = np.concatenate([uvs[4], copy_uv])
    depths[4] = np.concatenate([depths[4], np.full(len(copy_uv), WALL_Z_M)])
    wrong = np.column_stack([seen, start + np.arange(len(seen))]).astype(np.int32)
    pairs.append(PairMatches(1, 4, wrong, len(wrong), "test"))
    pairs.sort(key=lambda p: (p.frame_a, p.frame_b))
    return uvs, depths, pairs


def _pair(pairs: list[PairMatches], a: int, b: int) -> PairMatches:
    return next(p for p in pairs if (p.frame_a, p.frame_b) == (a, b))


def test_the_copy_of_a_planar_texture_passes_the_two_view_verification() -> None:
    """Why the check is needed: the wrong pair's matches are one plane's homography, so COLMAP's
    verification keeps them all."""
    uvs, _, pairs = _scene()
    wrong = _pair(pairs, 1, 4)
    kept, _ = verify_matches(uvs[1], uvs[4], wrong.idx, CAM,
                             MatchOptions(verification=Verification.TWO_VIEW))
    assert len(kept) >= 0.9 * len(wrong.idx)


def test_pair_pose_recovers_the_relative_motion() -> None:
    uvs, depths, pairs = _scene()
    p = _pair(pairs, 2, 3)
    ia, ib = p.idx[:, 0], p.idx[:, 1]
    pose = pair_pose(uvs[2][ia], depths[2][ia], uvs[3][ib], CAM)
    assert pose is not None
    # Its own matches land where they were matched (a plane through a narrow view: the pose
    # itself may trade a slide along the wall for a turn, the pixels may not).
    assert np.median(reprojection_px(pose, uvs[2][ia], depths[2][ia], uvs[3][ib], CAM)) < 2.0
    wrong = _pair(pairs, 1, 4)
    ia, ib = wrong.idx[:, 0], wrong.idx[:, 1]
    pose = pair_pose(uvs[1][ia], depths[1][ia], uvs[4][ib], CAM)
    assert pose is not None  # the copy is self-consistent: one pose explains it
    assert np.median(reprojection_px(pose, uvs[1][ia], depths[1][ia], uvs[4][ib], CAM)) < 2.0


def test_the_pair_that_matched_the_copy_is_dropped_and_no_other() -> None:
    uvs, depths, pairs = _scene()
    check = chain_inconsistent_pairs(pairs, uvs, depths, CAM)
    assert check.dropped == [(1, 4)]
    # About one period along the wall seen from the wall's distance (1030 px; the chain's
    # poses extrapolate beyond the pieces of wall their pairs share).
    assert check.median_px[0] == pytest.approx(PERIOD_M * CAM.fx / WALL_Z_M, rel=0.25)
    assert check.posed == len(pairs)


def test_the_front_end_gives_the_solver_no_match_of_the_dropped_pair() -> None:
    """Default front end: frame 1 and 4 are not linked; the peers' front end (``pair_chain``
    None) links them with the copy's matches."""
    uvs, depths, pairs = _scene()
    frames = [{"uv": uv, "depth": d, "scan_p_in_cam": np.zeros((0, 3)),
               "scan_n_in_cam": np.zeros((0, 3)),
               **{f"{prefix}_p_in_cam": np.zeros((0, 3))
                  for prefix in ("floor", "ceiling", "wall", "column")}}
              for uv, d in zip(uvs, depths, strict=True)]
    init = np.zeros((FRAMES, 7))
    init[:, 0] = [_cam_x(f) for f in range(FRAMES)]
    init[:, 6] = 1.0

    def linked(cfg: FrontendConfig) -> set[tuple[int, int]]:
        out = _assemble(cfg, CAM, init, frames, pairs)
        return {tuple(int(v) for v in r) for r in np.unique(out.match_frames, axis=0)}

    keep_all = MatchFilterOptions(max_initial_distance_m=None)  # bimcap refine's default
    assert (1, 4) not in linked(FrontendConfig(filters=keep_all))
    assert (1, 4) in linked(FrontendConfig(filters=keep_all, pair_chain=None))
    assert {(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)} <= linked(FrontendConfig(filters=keep_all))


def test_options_serialise() -> None:
    assert PairChainOptions().to_dict()["max_median_px"] == 100.0
    assert FrontendConfig().to_dict()["pair_chain"] == PairChainOptions().to_dict()
    assert FrontendConfig(pair_chain=None).to_dict()["pair_chain"] is None
