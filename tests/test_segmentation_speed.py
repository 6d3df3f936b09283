"""The geometric segmenter's and the planar smoothing's exact cuts (issue 14, branch fe-seg) give
the numbers of the code before them: numpy's percentile without its machinery, plane distances
taken at the pixels that read them only, ``np.take`` gathers, OpenCV's labels without their
statistics. (The whole segmenter against the code as of a219de7 is
``test_frontend_speed.py::test_segmentation_same_as_before``; the smoothing against its
references, ``test_planar_smoothing_*``.)"""

from __future__ import annotations

import numpy as np
import pytest

from _fusion_scene import frames
from bimcap.fusion import CompletionMethod, CompletionOptions, complete_depth, project_lidar
from bimcap.fusion.completion import smooth_planar_regions
from bimcap.segmentation import geometric
from bimcap.segmentation.geometric import GeometricOptions, segment_geometric


def _arrays(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """1-D float64 arrays of 1–3000 values: spreads of many scales, rounded values (ties),
    all-zero arrays with signed zeros, NaN and infinities."""
    out = []
    for k in range(count):
        n = int(rng.integers(1, 3000)) if k % 3 else int(rng.integers(1, 8))
        a = rng.normal(size=n) * 10.0 ** int(rng.integers(-5, 5))
        if k % 7 == 0:
            a = np.round(a, 1)
        if k % 11 == 0:
            a[rng.integers(0, n)] = np.nan
        if k % 13 == 0:
            a[:] = rng.choice([0.0, -0.0, 1.0], n)
        if k % 17 == 0:
            a[rng.integers(0, n)] = np.inf
        if k % 19 == 0:
            a[rng.integers(0, n)] = -np.inf
        out.append(a)
    return out


def test_percentiles_same_as_numpy() -> None:
    """``_percentiles`` is ``np.percentile`` bit for bit (interpolated and exact indexes, both
    halves of numpy's interpolation, the last index, NaN and infinities), and leaves its input
    alone."""
    rng = np.random.default_rng(14)
    for a in _arrays(rng, 3000):
        before = a.copy()
        for qs in ((2, 98), (98,), (50,), (0, 100), (37.5,), (2.0, 25, 75, 98)):
            got = np.array(geometric._percentiles(a, qs))
            with np.errstate(invalid="ignore"):  # numpy's inf - inf
                want = np.asarray(np.percentile(a, qs), dtype=np.float64)
            assert got.tobytes() == want.tobytes(), (len(a), qs, got, want)
        assert before.tobytes() == a.tobytes()


def test_rows_dot_same_as_whole_product() -> None:
    """``(p @ v)[idx]`` whether the product is taken on the gathered rows or the whole array
    (row-major (h, w, 3) images as the segmenter's, and (N, 3) point lists), one row included:
    the property the segmenter's distances at a mask's pixels rest on."""
    rng = np.random.default_rng(15)
    for _ in range(300):
        h, w = (int(x) for x in rng.integers(2, 260, 2))
        img = rng.normal(size=(h, w, 3)) * float(rng.choice([1e-3, 1.0, 1e3]))
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        whole = img @ v
        flat = img.reshape(-1, 3)
        for count in (1, 2, 3, int(rng.integers(1, h * w + 1))):
            idx = np.sort(rng.choice(h * w, size=min(count, h * w), replace=False))
            got = geometric._rows_dot(flat, idx, v)
            assert got.tobytes() == whole.reshape(-1)[idx].tobytes()
            assert got.tobytes() == (flat @ v)[idx].tobytes()


@pytest.fixture(scope="module")
def dense_frames() -> list[tuple[np.ndarray, object, np.ndarray]]:
    """(completed depth, pinhole camera, pose) of box-room frames at two sizes."""
    out = []
    for f in frames(3) + frames(2, 516, 386, 7):
        cam = f.camera.pinhole()
        sparse = project_lidar(f.points_in_lidar, f.cam_from_lidar, cam)
        dense = np.asarray(complete_depth(sparse, CompletionOptions(CompletionMethod.LINEAR)),
                           np.float32)
        out.append((dense, cam, f.world_from_cam))
    return out


def _plane_inliers_whole(scene: geometric._WorkScene, plane: geometric._Plane, mask: np.ndarray,
                         opts: GeometricOptions) -> np.ndarray:
    """``_plane_inliers`` before fe-seg: every pixel's distance and agreement, then the mask."""
    dist = np.abs(scene.pts @ plane.normal + plane.offset)
    agree = np.abs(scene.nrm @ plane.normal)
    cos_n = np.cos(np.deg2rad(opts.normal_agreement_deg))
    out: np.ndarray = (dist < scene.thr) & (agree > cos_n) & mask
    return out


def test_plane_inliers_at_mask_same_as_whole_image(
        dense_frames: list[tuple[np.ndarray, object, np.ndarray]]) -> None:
    """The inliers from the masked pixels' distances (sparse masks) are the whole image's,
    for masks of every size (empty, one pixel, two, sparse and dense; both paths)."""
    import cv2

    rng = np.random.default_rng(16)
    opts = GeometricOptions()
    for depth, cam, pose in dense_frames:
        scale = opts.work_width / cam.width  # type: ignore[attr-defined]
        work = cam.scaled(scale)  # type: ignore[attr-defined]
        d = cv2.resize(depth, (work.width, work.height), interpolation=cv2.INTER_NEAREST)
        scene = geometric._work_scene(d, work, pose, opts)
        for _ in range(20):
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            p = scene.pts[scene.valid][int(rng.integers(0, int(scene.valid.sum())))]
            plane = geometric._Plane(n, float(-n @ p))
            for frac in (0.0, 0.01, 0.1, 0.24, 0.26, 0.9):
                mask = rng.random(d.shape) < frac
                for m in (mask, mask & scene.nok):
                    got = geometric._plane_inliers(scene, plane, m, opts)
                    assert np.array_equal(got, _plane_inliers_whole(scene, plane, m, opts))
            for count in (1, 2):
                m = np.zeros(d.shape, dtype=bool)
                m.reshape(-1)[rng.choice(m.size, count, replace=False)] = True
                got = geometric._plane_inliers(scene, plane, m, opts)
                assert np.array_equal(got, _plane_inliers_whole(scene, plane, m, opts))


def test_region_points_same_as_boolean_gather(
        dense_frames: list[tuple[np.ndarray, object, np.ndarray]]) -> None:
    """``_Region.points`` (``np.take`` of the raveled image) is the boolean gather of its box,
    for connected components touching every border."""
    import cv2

    rng = np.random.default_rng(17)
    for depth, _, _ in dense_frames:
        h, w = depth.shape
        pts = rng.normal(size=(h, w, 3))
        mask = (rng.random((h, w)) < 0.6).astype(np.uint8)
        n_comp, comp, _, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        comps = geometric._Components.of(mask.astype(bool))
        assert comps.count == n_comp
        for c in range(1, min(n_comp, 200)):
            region = geometric._Region.component(comps, c, pts)
            want = pts[region.rows, region.cols][region.mask]
            assert region.points().tobytes() == want.tobytes()
            assert np.array_equal(region.flat(), np.flatnonzero(comp == c))


def test_segmentation_and_smoothing_unchanged_by_gather_paths(
        dense_frames: list[tuple[np.ndarray, object, np.ndarray]],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole segmenter and the smoothing of its labels with the whole-image inliers and
    numpy's percentile swapped back in give the same arrays (the walls, floor and ceiling of
    the box room all go through both)."""
    new = []
    for depth, cam, pose in dense_frames:
        labels = segment_geometric(depth, cam, pose)  # type: ignore[arg-type]
        new.append((labels, smooth_planar_regions(depth, labels, cam)))  # type: ignore[arg-type]
    assert any(len(np.unique(lab)) >= 4 for lab, _ in new)

    def numpy_percentiles(a: np.ndarray, qs: tuple[float, ...]) -> list[float]:
        return [float(x) for x in np.atleast_1d(np.percentile(a, list(qs)))]

    monkeypatch.setattr(geometric, "_plane_inliers", _plane_inliers_whole)
    monkeypatch.setattr(geometric, "_percentiles", numpy_percentiles)
    for (depth, cam, pose), (labels, smoothed) in zip(dense_frames, new, strict=True):
        old = segment_geometric(depth, cam, pose)  # type: ignore[arg-type]
        assert np.array_equal(old, labels)
        assert smooth_planar_regions(depth, old, cam).tobytes() == smoothed.tobytes()  # type: ignore[arg-type]


@pytest.mark.parametrize("reach", [1, 8])
def test_near_region_same_as_whole_dilation(reach: int) -> None:
    """``_near_region`` (compiled: each window's count from a table over the region's band)
    gives the positions the whole image's dilation by OpenCV gives, for regions touching the
    image's top and bottom, empty regions, single pixels, with entries in ascending rows or in
    any order (the upsampling's lookups, with repeated indices as nearest-neighbour upsampling
    reads them), and with a band of rows that holds the region (exactly its rows, or wider)."""
    import cv2

    rng = np.random.default_rng(18 + reach)
    kernel = np.ones((2 * reach + 1,) * 2, np.uint8)
    for _ in range(200):
        h, w = (int(x) for x in rng.integers(1, 60, 2))
        region_id = rng.integers(-1, 6, size=(h, w)).astype(np.int32)
        if rng.random() < 0.5:  # a few compact regions instead of noise
            region_id[:] = -1
            for k in range(4):
                y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
                region_id[y:y + int(rng.integers(1, 9)), x:x + int(rng.integers(1, 9))] = k
        at = np.sort(rng.integers(0, h * w, size=int(rng.integers(0, 3 * h * w + 1))))
        shuffled = rng.permutation(at)
        for k in range(-1, 7):
            whole = cv2.dilate((region_id == k).astype(np.uint8), kernel).reshape(-1)
            held = np.flatnonzero((region_id == k).any(1))
            bands = [None, (0, h)]
            if len(held):
                lo, hi = int(held[0]), int(held[-1]) + 1
                bands += [(lo, hi), (max(lo - 2, 0), min(hi + 3, h))]
            for entries, ascending in ((at, True), (at, False), (shuffled, False)):
                want = np.flatnonzero(np.take(whole, entries)) if len(entries) else []
                for band in bands:
                    got = geometric._near_region(region_id, k, reach, entries, ascending, band)
                    assert np.array_equal(got, want), (h, w, k, ascending, band)
