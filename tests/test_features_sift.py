"""SIFT extraction, descriptor matching and geometric verification on synthetic images."""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.features import (
    FeatureError,
    MatcherBackend,
    MatchOptions,
    SiftBackend,
    SiftOptions,
    Verification,
    extract_sift,
    match_descriptors,
    match_pair,
    sequential_pairs,
    verify_matches,
)
from bimcap.geometry.camera import Camera


def _blob_image(centres: list[tuple[float, float]],
                shape: tuple[int, int] = (200, 300)) -> np.ndarray:
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    img = np.full(shape, 30.0)
    for cu, cv in centres:
        img += 200.0 * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * 4.0**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def _noise(seed: int = 0, shape: tuple[int, int] = (300, 400), sigma: float = 2.5) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    big = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.float32), (0, 0), sigma)
    return cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


@pytest.fixture(scope="module")
def shifted_pair() -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Two crops of one noise image; b's pixel (u, v) shows a's pixel (u + 11, v + 7)."""
    big = _noise()
    du, dv = 11, 7
    a = np.ascontiguousarray(big[:200, :280])
    b = np.ascontiguousarray(big[dv : dv + 200, du : du + 280])
    return a, b, (du, dv)


@pytest.mark.parametrize(("backend", "tol"),
                         [(SiftBackend.PYCOLMAP, 0.05), (SiftBackend.OPENCV, 0.3)])
def test_keypoints_use_pixel_centre_convention(backend: SiftBackend, tol: float) -> None:
    """A Gaussian blob centred on pixel (100, 60) and one at (200.5, 140.25) are found there."""
    centres = [(100.0, 60.0), (200.5, 140.25)]
    feats = extract_sift(_blob_image(centres), SiftOptions(backend=backend))
    assert len(feats) >= 2
    for c in centres:
        d = np.linalg.norm(feats.uv - np.array(c), axis=1)
        assert d.min() < tol, (c, feats.uv)


def test_downscaled_extraction_maps_back_to_full_resolution() -> None:
    centres = [(100.0, 60.0), (300.5, 180.25)]
    img = _blob_image(centres, shape=(300, 400))
    # The small blobs need the upsampled octave once the image is halved.
    feats = extract_sift(img, SiftOptions(backend=SiftBackend.PYCOLMAP, max_image_size=200,
                                          first_octave=-1))
    for c in centres:
        d = np.linalg.norm(feats.uv - np.array(c), axis=1)
        assert d.min() < 0.15, (c, feats.uv)
    full = extract_sift(img, SiftOptions(backend=SiftBackend.PYCOLMAP, first_octave=-1))
    assert np.median(feats.scale) == pytest.approx(np.median(full.scale), rel=0.2)
    with pytest.raises(FeatureError):
        SiftOptions(max_image_size=4)


@pytest.mark.parametrize("backend", [SiftBackend.PYCOLMAP, SiftBackend.OPENCV])
def test_features_shapes_and_dtypes(shifted_pair: tuple, backend: SiftBackend) -> None:
    """Also OpenCV's SIFT at ``opencv_first_octave = 0``, ``peak_threshold = 0.004`` keeps at
    most ``max_num_features`` (OpenCV's own ``nfeatures`` gave 501 of 500 here: it keeps ties
    and adds a keypoint's second orientation)."""
    a, _, _ = shifted_pair
    opts = (SiftOptions(backend=backend, peak_threshold=0.02 / 3, max_num_features=500)
            if backend is SiftBackend.PYCOLMAP else
            SiftOptions(backend=backend, opencv_first_octave=0, peak_threshold=0.004,
                        max_num_features=500))
    f = extract_sift(np.stack([a, a, a], axis=-1), opts)
    assert 100 < len(f) <= 500
    assert f.uv.shape == (len(f), 2) and f.uv.dtype == np.float64
    assert f.descriptors.shape == (len(f), 128) and f.descriptors.dtype == np.uint8
    assert f.scale.shape == f.orientation.shape == (len(f),)
    # RootSIFT scaled by 512 (COLMAP's uint8 layout).
    norms = np.linalg.norm(f.descriptors.astype(np.float64), axis=1)
    assert np.allclose(norms, 512.0, rtol=0.02)


def test_bad_images_are_refused() -> None:
    with pytest.raises(FeatureError, match="8-bit"):
        extract_sift(np.zeros((20, 20), np.float32))
    with pytest.raises(FeatureError, match="shape"):
        extract_sift(np.zeros((20, 20, 4), np.uint8))
    with pytest.raises(FeatureError):
        SiftOptions(max_num_features=0)


def test_numpy_matcher_equals_pycolmap_matcher(shifted_pair: tuple) -> None:
    """Oracle: COLMAP's own brute-force matcher gives exactly the same match set."""
    a, b, _ = shifted_pair
    fa = extract_sift(a, SiftOptions(max_num_features=800))
    fb = extract_sift(b, SiftOptions(max_num_features=800))
    ours = match_descriptors(fa.descriptors, fb.descriptors)
    theirs = match_descriptors(
        fa.descriptors, fb.descriptors, MatchOptions(backend=MatcherBackend.PYCOLMAP)
    )
    assert len(ours) > 300
    assert set(map(tuple, ours.tolist())) == set(map(tuple, theirs.tolist()))


def test_matches_follow_the_known_shift(shifted_pair: tuple) -> None:
    a, b, (du, dv) = shifted_pair
    fa, fb = extract_sift(a), extract_sift(b)
    m = match_descriptors(fa.descriptors, fb.descriptors)
    disp = fa.uv[m[:, 0]] - fb.uv[m[:, 1]]
    good = np.linalg.norm(disp - [du, dv], axis=1) < 0.5
    assert good.mean() > 0.97


def test_ratio_and_cross_check_by_hand() -> None:
    """Hand-built descriptors: an ambiguous query fails the ratio test; a clear one passes."""
    rng = np.random.default_rng(3)

    def unit(v: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(v / np.linalg.norm(v) * 512), 0, 255).astype(np.uint8)

    base = [np.abs(rng.normal(size=128)) for _ in range(4)]
    db = np.stack([unit(x) for x in base])
    clear = unit(base[0] + 0.05 * np.abs(rng.normal(size=128)))
    ambiguous = unit(base[2] + base[3])  # equally close to 2 and 3
    m = match_descriptors(np.stack([clear, ambiguous]), db)
    assert m.tolist() == [[0, 0]]


def _two_view_points(n: int, seed: int) -> tuple[Camera, np.ndarray, np.ndarray]:
    """Pixels of n random 3-D points (2–6 m deep) in two pinhole views 0.3 m and 5° apart."""
    from scipy.spatial.transform import Rotation

    cam = Camera(640, 480, 500.0, 500.0, 319.5, 239.5)
    rng = np.random.default_rng(seed)
    p = np.stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)], axis=1)
    r = Rotation.from_euler("y", 5.0, degrees=True).as_matrix()
    p_b = p @ r.T + np.array([-0.3, 0.05, 0.02])
    uv_a, _ = cam.project(p)
    uv_b, _ = cam.project(p_b)
    ok = cam.in_image(uv_a) & cam.in_image(uv_b)
    return cam, uv_a[ok], uv_b[ok]


def _matches_with_outliers() -> tuple[Camera, np.ndarray, np.ndarray, np.ndarray, int]:
    """400 exact correspondences with parallax (0.3 px noise in the second view) plus 20 % random
    pairs: ``(camera, uv_a, uv_b, matches, number of random pairs)``, ``matches`` (M, 2) int32
    with the i-i pairs first."""
    cam, uv_a, uv_b = _two_view_points(400, seed=1)
    rng = np.random.default_rng(2)
    uv_b = uv_b + rng.normal(scale=0.3, size=uv_b.shape)
    n = len(uv_a)
    good = np.stack([np.arange(n), np.arange(n)], axis=1)
    bad = np.stack([rng.integers(0, n, n // 5), rng.integers(0, n, n // 5)], axis=1)
    bad = bad[bad[:, 0] != bad[:, 1]]
    return cam, uv_a, uv_b, np.concatenate([good, bad]).astype(np.int32), len(bad)


@pytest.mark.parametrize("trials", [None, 30, 1])
@pytest.mark.parametrize("ver", [Verification.TWO_VIEW, Verification.FUNDAMENTAL])
def test_verification_removes_outliers(ver: Verification, trials: int | None) -> None:
    """Exact correspondences with parallax plus 20 % random pairs: the random pairs go, also
    with fewer RANSAC trials at the least (the confidence test still runs enough of them)."""
    cam, uv_a, uv_b, matches, n_bad = _matches_with_outliers()
    n = len(uv_a)
    inl, model = verify_matches(uv_a, uv_b, matches, cam,
                                MatchOptions(verification=ver, ransac_min_trials=trials))
    is_good = inl[:, 0] == inl[:, 1]
    assert model in ("CALIBRATED", "FUNDAMENTAL")
    assert is_good.sum() > 0.97 * n
    # An outlier survives only if it happens to lie within 2 px of its epipolar line.
    assert (~is_good).sum() <= 0.05 * n_bad
    inl, model = verify_matches(uv_a, uv_b, matches, cam,
                                MatchOptions(verification=Verification.NONE))
    assert len(inl) == len(matches) and model == "none"


def test_ransac_min_trials_option() -> None:
    """None (pycolmap's count) stays out of the options' dict, which keys the front end's cache;
    a count is in it (the default, 10, too), and one outside [1, 10000] is refused."""
    assert "ransac_min_trials" not in MatchOptions(ransac_min_trials=None).to_dict()
    assert MatchOptions().ransac_min_trials == 10
    assert MatchOptions().to_dict()["ransac_min_trials"] == 10
    assert MatchOptions(ransac_min_trials=30).to_dict()["ransac_min_trials"] == 30
    assert MatchOptions(ransac_min_trials=30).to_dict() != MatchOptions().to_dict()
    for bad in (0, 10001):  # pycolmap refuses more than its max_num_trials (10000)
        with pytest.raises(FeatureError, match="ransac_min_trials"):
            MatchOptions(ransac_min_trials=bad)
    MatchOptions(ransac_min_trials=10000)


def test_previous_verification_default_stays_reachable(shifted_pair: tuple) -> None:
    """``[matching] ransac_min_trials = 100`` (the default before 2026-11-27) verifies exactly as
    pycolmap's own count (None), which it is for the two-view geometry; the new default gives
    other cache keys, so pairs verified with 100 trials are never read back as 10's."""
    from bimcap.frontend.cache import frame_cache_key
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import match_options

    a, b, _ = shifted_pair
    cam = Camera(280, 200, 250.0, 250.0, 139.5, 99.5)
    fa, fb = extract_sift(a), extract_sift(b)
    m = match_descriptors(fa.descriptors, fb.descriptors)
    old = match_options(RefineConfig(matching={"ransac_min_trials": 100}))
    hundred = verify_matches(fa.uv, fb.uv, m, cam, old)
    own = verify_matches(fa.uv, fb.uv, m, cam, MatchOptions(ransac_min_trials=None))
    assert np.array_equal(hundred[0], own[0]) and hundred[1] == own[1]
    keys = {frame_cache_key([], {"match": o.to_dict()})
            for o in (MatchOptions(), old, MatchOptions(ransac_min_trials=None))}
    assert len(keys) == 3


def test_verified_matches_of_a_shifted_image(shifted_pair: tuple) -> None:
    """A pure image shift is panoramic: nearly all true matches pass verification."""
    a, b, (du, dv) = shifted_pair
    cam = Camera(280, 200, 250.0, 250.0, 139.5, 99.5)
    fa, fb = extract_sift(a), extract_sift(b)
    pm = match_pair(fa, fb, cam, 3, 4)
    assert (pm.frame_a, pm.frame_b) == (3, 4)
    disp = fa.uv[pm.idx[:, 0]] - fb.uv[pm.idx[:, 1]]
    assert pm.num_putative > 300 and len(pm.idx) > 0.95 * pm.num_putative
    assert np.median(np.linalg.norm(disp - [du, dv], axis=1)) < 0.1


def test_too_few_matches_give_none(shifted_pair: tuple) -> None:
    a, _, _ = shifted_pair
    other = _noise(seed=99)[:200, :280]
    cam = Camera(280, 200, 250.0, 250.0, 139.5, 99.5)
    pm = match_pair(extract_sift(a), extract_sift(np.ascontiguousarray(other)), cam, 0, 1)
    assert pm.idx.shape == (0, 2) and pm.idx.dtype == np.int32


def test_sequential_pairs() -> None:
    assert sequential_pairs(4, 2) == [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]
    assert sequential_pairs(1, 3) == []
    with pytest.raises(FeatureError):
        sequential_pairs(4, 0)


#: OpenCV's SIFT with its first octave at the native resolution (the image halved, then doubled),
#: small test images included.
OPENCV_OCTAVE0 = SiftOptions(backend=SiftBackend.OPENCV, opencv_first_octave=0,
                             opencv_halve_min_side=2)


def test_opencv_first_octave_is_validated() -> None:
    from bimcap.pipeline.config import ConfigError, RefineConfig
    from bimcap.pipeline.refine import sift_options

    for bad in (1, -2):
        with pytest.raises(FeatureError, match="opencv_first_octave must be -1 or 0"):
            SiftOptions(opencv_first_octave=bad)
    with pytest.raises(ConfigError, match="opencv_first_octave"):
        sift_options(RefineConfig(features={"opencv_first_octave": 2}))
    with pytest.raises(ConfigError, match=r"features\.opencv_first_octave"):
        sift_options(RefineConfig(features={"opencv_first_octave": 0.5}))
    assert sift_options(RefineConfig(features={"backend": "opencv", "opencv_first_octave": 0,
                                               "opencv_halve_min_side": 2})) == OPENCV_OCTAVE0
    with pytest.raises(ConfigError, match="opencv_halve_min_side must be >= 2"):
        sift_options(RefineConfig(features={"opencv_halve_min_side": 1}))


def test_opencv_first_octave_0_shapes_and_dtypes(shifted_pair: tuple) -> None:
    a, _, _ = shifted_pair
    f = extract_sift(np.stack([a, a, a], axis=-1), OPENCV_OCTAVE0)
    assert len(f) > 100
    assert f.uv.shape == (len(f), 2) and f.uv.dtype == np.float64
    assert f.scale.shape == f.orientation.shape == (len(f),)
    assert f.scale.dtype == f.orientation.dtype == np.float64
    assert f.descriptors.shape == (len(f), 128) and f.descriptors.dtype == np.uint8
    norms = np.linalg.norm(f.descriptors.astype(np.float64), axis=1)
    assert np.allclose(norms, 512.0, rtol=0.02)
    # An image too small to halve still gives (0, ...) arrays of the right kinds.
    empty = extract_sift(np.full((1, 1), 7, np.uint8), OPENCV_OCTAVE0)
    assert empty.uv.shape == (0, 2) and empty.descriptors.shape == (0, 128)


def test_opencv_first_octave_0_keypoints_at_full_resolution(shifted_pair: tuple) -> None:
    """Blobs are found at their full-resolution pixels (the halved image's keypoints mapped
    back), matches follow a known shift, and the smallest scale is that of a first octave at
    the native resolution: about twice OpenCV's own (doubled) first octave."""
    centres = [(100.0, 60.0), (200.5, 140.25)]
    blobs = extract_sift(_blob_image(centres), OPENCV_OCTAVE0)
    for c in centres:
        d = np.linalg.norm(blobs.uv - np.array(c), axis=1)
        assert d.min() < 0.3, (c, blobs.uv)
    a, b, (du, dv) = shifted_pair
    fa, fb = extract_sift(a, OPENCV_OCTAVE0), extract_sift(b, OPENCV_OCTAVE0)
    m = match_descriptors(fa.descriptors, fb.descriptors)
    assert len(m) > 100
    disp = fa.uv[m[:, 0]] - fb.uv[m[:, 1]]
    assert np.mean(np.linalg.norm(disp - [du, dv], axis=1) < 0.5) > 0.9
    doubled = extract_sift(a, SiftOptions(backend=SiftBackend.OPENCV, opencv_first_octave=-1))
    assert fa.scale.min() == pytest.approx(2.0 * doubled.scale.min(), rel=0.25)
    assert len(fa) < len(doubled)


def test_the_default_halves_only_images_big_enough() -> None:
    """The default is OpenCV's SIFT at its native first octave; an image whose shorter side is
    below ``opencv_halve_min_side`` is extracted unhalved, exactly as at -1."""
    opts = SiftOptions()
    assert opts.backend is SiftBackend.OPENCV and opts.opencv_first_octave == 0
    small = _noise()[:240, :320]
    unhalved = extract_sift(small, SiftOptions(opencv_first_octave=-1))
    same = extract_sift(small, opts)
    assert np.array_equal(same.uv, unhalved.uv)
    assert np.array_equal(same.descriptors, unhalved.descriptors)
    halved = extract_sift(small, SiftOptions(opencv_halve_min_side=240))
    assert halved.scale.min() > 1.5 * unhalved.scale.min()


def test_opencv_octave_layers() -> None:
    """``opencv_octave_layers``: validated; 3 is the default bit for bit and stays out of the
    cache key (``to_dict``); 2 gives other keypoints and is in the key."""
    from bimcap.pipeline.config import ConfigError, RefineConfig
    from bimcap.pipeline.refine import sift_options

    for bad in (0, 9):
        with pytest.raises(FeatureError, match="opencv_octave_layers must be in"):
            SiftOptions(opencv_octave_layers=bad)
    with pytest.raises(ConfigError, match="opencv_octave_layers"):
        sift_options(RefineConfig(features={"opencv_octave_layers": 0}))
    assert "opencv_octave_layers" not in SiftOptions().to_dict()
    assert SiftOptions(opencv_octave_layers=2).to_dict()["opencv_octave_layers"] == 2
    img = _noise()
    default = extract_sift(img, SiftOptions())
    three = extract_sift(img, SiftOptions(opencv_octave_layers=3))
    assert np.array_equal(default.uv, three.uv)
    assert np.array_equal(default.descriptors, three.descriptors)
    two = extract_sift(img, SiftOptions(opencv_octave_layers=2))
    assert len(two) > 0 and len(two) != len(default)


def test_sampson_refinement_option(shifted_pair: tuple) -> None:
    """``sampson_refinement``: True (pycolmap's own, the default before 2026-11-28) stays out of
    the cache key and verifies as before the option; False (the default now) is in the key, so
    pairs verified with the refinement are never read back as the default's, and still removes
    the outliers."""
    from bimcap.pipeline.config import ConfigError, RefineConfig
    from bimcap.pipeline.refine import match_options

    assert MatchOptions().sampson_refinement is False
    assert "sampson_refinement" not in MatchOptions(sampson_refinement=True).to_dict()
    assert MatchOptions().to_dict()["sampson_refinement"] is False
    with pytest.raises(ConfigError, match="sampson_refinement"):
        match_options(RefineConfig(matching={"sampson_refinement": "no"}))
    assert not match_options(RefineConfig(matching={"sampson_refinement": False})
                             ).sampson_refinement
    cam, uv_a, uv_b, matches, n_bad = _matches_with_outliers()
    n = len(uv_a)
    inl, model = verify_matches(uv_a, uv_b, matches, cam, MatchOptions(sampson_refinement=False))
    is_good = inl[:, 0] == inl[:, 1]
    assert model == "CALIBRATED" and is_good.sum() > 0.97 * n
    assert (~is_good).sum() <= 0.05 * n_bad


def test_bench_generalization_reads_bool_settings() -> None:
    """``bench_generalization.py --matching sampson_refinement=false`` gives the bool (a string
    would be refused by the config), ints and floats as numbers."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    try:
        from bench_generalization import _feature_setting
    finally:
        sys.path.pop(0)
    assert _feature_setting("sampson_refinement=false") == ("sampson_refinement", False)
    assert _feature_setting("cross_check=true") == ("cross_check", True)
    assert _feature_setting("max_num_features=2048") == ("max_num_features", 2048)
    assert _feature_setting("peak_threshold=0.004") == ("peak_threshold", 0.004)
    assert _feature_setting("backend=opencv") == ("backend", "opencv")


def test_the_default_budget_keeps_the_strongest_2048() -> None:
    """The default keeps at most 2048 SIFT keypoints (4096 before 2026-11-27): on an image with
    more, the 2048 kept are among those of a larger budget, with the same descriptors."""
    big = _noise(seed=3, shape=(800, 1060), sigma=1.5)
    assert SiftOptions().max_num_features == 2048
    kept = extract_sift(big)
    more = extract_sift(big, SiftOptions(max_num_features=8192))
    assert len(kept) == 2048 < len(more)
    # a keypoint is its pixel and orientation (one pixel can carry two orientations)
    index = {(u, v, a): i for i, (u, v, a) in
             enumerate(zip(more.uv[:, 0], more.uv[:, 1], more.orientation, strict=True))}
    rows = [index[k] for k in zip(kept.uv[:, 0], kept.uv[:, 1], kept.orientation, strict=True)]
    assert np.array_equal(kept.descriptors, more.descriptors[rows])


@pytest.mark.parametrize("cols", [1, 7, 8, 128, 129, 300])
def test_rootsift_in_compiled_code_is_numpys(cols: int) -> None:
    """OpenCV's descriptors to RootSIFT ×512 uint8 (compiled) give numpy's float64 expression's
    bytes: integer-valued rows (as OpenCV's SIFT gives them), values over twelve decades, zero
    rows (the 1e-12 floor), a row whose values round to 255.5 · k."""
    from bimcap import _core

    rng = np.random.default_rng(cols)
    rows = [rng.integers(0, 256, (500, cols)).astype(np.float32),
            (10.0 ** rng.uniform(-6, 6, (500, cols))).astype(np.float32),
            np.zeros((3, cols), np.float32), np.full((2, cols), 7.0, np.float32)]
    for desc in rows:
        d = desc.astype(np.float64)
        d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
        want = np.clip(np.rint(np.sqrt(d) * 512.0), 0, 255).astype(np.uint8)
        got = _core.rootsift_u8(desc)
        assert got.dtype == np.uint8 and got.tobytes() == want.tobytes()
