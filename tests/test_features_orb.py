"""The ORB backend: binary descriptors, Hamming matching, and the front end's matches against the
ground truth of the ray-cast room."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _frontend_scene import SceneSequence, default_poses
from bimcap.features import (
    FeatureError,
    MatchOptions,
    SiftBackend,
    SiftOptions,
    extract_sift,
    match_descriptors,
)
from bimcap.frontend import (
    FrontendConfig,
    FrontendResult,
    GroundTruthDepthProvider,
    GroundTruthLabelProvider,
    run_frontend,
)
from bimcap.geometry.poses import transform_points

ORB = SiftOptions(backend=SiftBackend.ORB)


def _noise(seed: int = 0, shape: tuple[int, int] = (300, 400), sigma: float = 2.5) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    big = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.float32), (0, 0), sigma)
    return cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def test_orb_features_follow_a_known_shift() -> None:
    """b's pixel (u, v) shows a's pixel (u + 11, v + 7): matched keypoints are 11, 7 apart."""
    big = _noise()
    a = np.ascontiguousarray(big[:200, :280])
    b = np.ascontiguousarray(big[7:207, 11:291])
    fa, fb = extract_sift(a, ORB), extract_sift(b, ORB)
    assert fa.descriptors.shape == (len(fa), 32) and fa.descriptors.dtype == np.uint8
    assert fa.uv.shape == (len(fa), 2) and len(fa.scale) == len(fa.orientation) == len(fa)
    m = match_descriptors(fa.descriptors, fb.descriptors)
    assert len(m) > 100
    err = fa.uv[m[:, 0]] - fb.uv[m[:, 1]] - [11, 7]
    # Corners are whole pixels of their pyramid level (1.2^level pixels here), without a bias.
    assert (np.linalg.norm(err, axis=1) < 2.0).mean() > 0.95
    assert np.abs(np.median(err, axis=0)).max() < 0.05
    assert np.abs(err.mean(axis=0)).max() < 0.15


def test_hamming_matcher_equals_opencv_brute_force() -> None:
    """OpenCV's ``BFMatcher(NORM_HAMMING)`` two nearest neighbours each way, with the same ratio,
    distance and mutual tests, is the oracle (ties at the best fail the ratio test either way)."""
    import cv2

    big = _noise(2)
    fa = extract_sift(np.ascontiguousarray(big[:200, :280]), ORB)
    fb = extract_sift(np.ascontiguousarray(big[5:205, 9:289]), ORB)
    opts = MatchOptions()

    def knn(q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        res = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(q, t, k=2)
        best = np.array([m[0].trainIdx for m in res])
        ok = np.array([m[0].distance <= opts.max_hamming
                       and m[0].distance < opts.max_ratio * m[1].distance for m in res])
        return best, ok

    best_ab, ok_ab = knn(fa.descriptors, fb.descriptors)
    best_ba, ok_ba = knn(fb.descriptors, fa.descriptors)
    ia = np.flatnonzero(ok_ab)
    ia = ia[ok_ba[best_ab[ia]] & (best_ba[best_ab[ia]] == ia)]
    expected = np.stack([ia, best_ab[ia]], axis=1)
    got = match_descriptors(fa.descriptors, fb.descriptors, opts)
    assert len(got) > 100
    np.testing.assert_array_equal(got, expected)


def test_subpixel_corners_follow_a_fractional_shift() -> None:
    """b's pixel (u, v) shows a's (u + 10.4, v + 6.7): FAST's whole pixels are 0.4 / 0.3 px off
    in the median; the Harris peak takes the error to under half of that, without a bias."""
    import cv2

    big = _noise(4)
    a = np.ascontiguousarray(big[:200, :280])
    b = cv2.warpAffine(big, np.float32([[1, 0, -10.4], [0, 1, -6.7]]), (280, 200),
                       flags=cv2.INTER_CUBIC)
    errors = {}
    for subpixel in (False, True):
        opts = SiftOptions(backend=SiftBackend.ORB, orb_num_levels=1, orb_subpixel=subpixel)
        fa, fb = extract_sift(a, opts), extract_sift(b, opts)
        m = match_descriptors(fa.descriptors, fb.descriptors)
        assert len(m) > 100
        errors[subpixel] = fa.uv[m[:, 0]] - fb.uv[m[:, 1]] - [10.4, 6.7]
    assert np.median(np.linalg.norm(errors[False], axis=1)) > 0.5
    assert np.median(np.linalg.norm(errors[True], axis=1)) < 0.4
    assert np.abs(np.median(errors[True], axis=0)).max() < 0.1


def test_orb_keypoints_spread_over_the_grid() -> None:
    """A budget of 2 a cell: no cell keeps more than 2, and every textured cell keeps some."""
    img = _noise(1, shape=(240, 320))
    opts = SiftOptions(backend=SiftBackend.ORB, orb_max_num_features=2 * 4 * 3,
                       orb_grid_cols=4, orb_grid_rows=3)
    f = extract_sift(img, opts)
    cell = (f.uv[:, 1] // 80).astype(int) * 4 + (f.uv[:, 0] // 80).astype(int)
    counts = np.bincount(cell, minlength=12)
    assert counts.max() <= 2
    assert (counts > 0).sum() >= 10  # corner cells lose FAST's 31-pixel border


def test_hamming_ratio_and_cross_check_by_hand() -> None:
    """Bits flipped by hand: a clear query matches, one halfway between two does not, one too
    far (over max_hamming) does not, and a non-mutual best is dropped."""
    rng = np.random.default_rng(3)
    bits = rng.integers(0, 2, size=(4, 256), dtype=np.uint8)
    db = np.packbits(bits, axis=1)

    def flipped(row: np.ndarray, idx: np.ndarray) -> np.ndarray:
        out = row.copy()
        out[idx] ^= 1
        return out

    clear = flipped(bits[0], np.arange(10))  # 10 bits from 0, ~128 from the others
    # 2 and 3 differ in ~128 bits; take half of them from each: equally far from both.
    diff = np.flatnonzero(bits[2] != bits[3])
    ambiguous = flipped(bits[2], diff[: len(diff) // 2])
    far = flipped(bits[1], np.arange(0, 140, 2))  # 70 bits from 1 > max_hamming 64
    q = np.packbits(np.stack([clear, ambiguous, far]), axis=1)
    assert match_descriptors(q, db).tolist() == [[0, 0]]
    assert match_descriptors(q, db, MatchOptions(max_hamming=80)).tolist() == [[0, 0], [2, 1]]
    # Two queries close to row 0: the second's best is 0, but 0's best is the first: dropped.
    q2 = np.packbits(np.stack([clear, flipped(bits[0], np.arange(20, 40))]), axis=1)
    assert match_descriptors(q2, db).tolist() == [[0, 0]]
    assert match_descriptors(q2, db, MatchOptions(cross_check=False)).tolist() == [[0, 0],
                                                                                   [1, 0]]


def test_sift_and_orb_descriptors_do_not_mix() -> None:
    blank = extract_sift(np.full((120, 160), 90, np.uint8), ORB)
    assert blank.descriptors.shape == (0, 32)  # an ORB frame without corners is still ORB
    assert len(match_descriptors(blank.descriptors, np.zeros((5, 32), np.uint8))) == 0
    with pytest.raises(FeatureError, match="different kinds"):
        match_descriptors(np.zeros((5, 128), np.uint8), np.zeros((5, 32), np.uint8))
    with pytest.raises(FeatureError, match="uint8"):
        match_descriptors(np.zeros((5, 64), np.uint8), np.zeros((5, 64), np.uint8))
    with pytest.raises(FeatureError, match="orb_grid_cols"):
        SiftOptions(backend=SiftBackend.ORB, orb_grid_cols=0)
    with pytest.raises(FeatureError, match="max_hamming"):
        MatchOptions(max_hamming=300)


def test_orb_front_end_matches_agree_with_ground_truth(tmp_path: Path) -> None:
    """The whole front end on ORB: both back-projections of each verified match land on the same
    world point under the true poses, as with SIFT (tests/test_frontend_runner.py)."""
    seq = SceneSequence.write(tmp_path / "seq", poses=default_poses(4))

    def run(cfg: FrontendConfig) -> FrontendResult:
        return run_frontend(seq, cfg, seq.gt, GroundTruthDepthProvider(),
                            GroundTruthLabelProvider(), workers=1, progress=False,
                            cache_dir=tmp_path / "cache")

    sift = run(FrontendConfig(window=2))
    cfg = FrontendConfig(sift=SiftOptions(backend=SiftBackend.ORB, orb_max_num_features=1000),
                         window=2)
    res = run(cfg)
    assert res.run.features_computed == 4  # SIFT's cached features are not ORB's
    assert len(sift.match_frames) > 0
    m = res.match_frames
    assert len(m) > 300
    pa = transform_points(seq.gt[m[:, 0]],
                          res.camera.backproject(res.match_uv[:, :2], res.match_depth[:, 0],
                                                 distorted=False))
    pb = transform_points(seq.gt[m[:, 1]],
                          res.camera.backproject(res.match_uv[:, 2:], res.match_depth[:, 1],
                                                 distorted=False))
    err = np.linalg.norm(pa - pb, axis=1)
    assert np.median(err) < 0.03
    assert np.percentile(err, 95) < 0.06
    # The cache holds ORB's arrays and gives the same matches back.
    again = run(cfg)
    assert again.run.features_computed == 0 and again.run.pairs_computed == 0
    np.testing.assert_array_equal(again.match_uv, res.match_uv)
