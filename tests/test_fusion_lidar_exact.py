"""The LiDAR stages after the exact cuts of branch fe-pix (docs/speed.md, "LiDAR stages, the
triangulation and the cache writes"): the projection and the scan's surface points give the
941624b code's arrays bit for bit (frozen below), on the box-room frames, on scans with
non-finite and far rows, on float64 (M, 3) input, and on every frame of two generated worlds
(skipped without them); so do the keypoints whose depth the returns contradict."""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
from numpy.typing import ArrayLike, NDArray

from _fusion_scene import frames
from bimcap.fusion import NanPolicy, ProjectionOptions, project_lidar
from bimcap.fusion import projection as projection_module
from bimcap.fusion.scan import ScanSamplingError, ScanSamplingOptions, scan_surface_points
from bimcap.geometry import Camera, quat_to_rotmat

_WORLDS = Path("/tmp/gen")
F64 = NDArray[np.float64]


# ----------------------------------------------------------------------- the 941624b code
def _checked_points_941624b(points_in_lidar: ArrayLike,
                            opts: ProjectionOptions) -> tuple[F64, NDArray[np.bool_]]:
    pts = np.asarray(points_in_lidar, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise projection_module.FusionInputError(
            f"points must have shape (M, 3) or (M, 4), got {pts.shape}", field="points_in_lidar")
    pts = pts[:, :3]
    n_input = len(pts)
    if n_input == 0:
        raise projection_module.FusionInputError("the LiDAR scan is empty (0 points)",
                                                 field="points_in_lidar")
    finite = cast(NDArray[np.bool_], np.isfinite(pts).all(axis=1))
    if not finite.all() and opts.nan_policy is NanPolicy.RAISE:
        bad = int((~finite).sum())
        raise projection_module.FusionInputError(
            f"{bad} of {n_input} points are NaN/inf (ProjectionOptions.nan_policy DROP drops them)",
            field="points_in_lidar",
        )
    return pts, finite


def _in_front_941624b(pts: F64, finite: NDArray[np.bool_], cam_from_lidar: ArrayLike,
                      opts: ProjectionOptions) -> tuple[NDArray[np.int64], F64, F64]:
    index = np.flatnonzero(finite)
    rot, t = projection_module._pose_rt(cam_from_lidar, "cam_from_lidar")
    p_in_cam = pts[index] @ rot.T + t
    z = p_in_cam[:, 2]
    front = (z > opts.min_depth_m) & (z < opts.max_depth_m)
    index, p_in_cam, z = index[front], p_in_cam[front], z[front]
    return index, z, p_in_cam[:, :2] / z[:, None]


def _voxel_means_941624b(points: F64, voxel: float) -> F64:
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= np.array([keys[:, j].min() for j in range(3)])
    span = np.array([keys[:, j].max() for j in range(3)]) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.stack([np.bincount(inverse, points[:, j], len(counts)) for j in range(3)], axis=1)
    return sums / counts[:, None]


def _normals_941624b(cloud: F64, query: F64, k: int, max_flatness: float, min_spread: float
                     ) -> tuple[F64, NDArray[np.bool_]]:
    from scipy.spatial import cKDTree

    k = min(k, len(cloud))
    _, idx = cKDTree(cloud).query(query, k=k)
    nb = cloud[idx]  # (n, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred) / k
    evals, evecs = np.linalg.eigh(cov)  # ascending
    normal = evecs[:, :, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        planar = (evals[:, 0] <= max_flatness * evals[:, 1]) & (
            evals[:, 1] >= min_spread * evals[:, 2])
    return normal, planar


def scan_surface_points_941624b(points_in_lidar: ArrayLike, cam_from_lidar: ArrayLike,
                                camera: Camera, options: ScanSamplingOptions | None = None
                                ) -> tuple[F64, F64]:
    opts = options or ScanSamplingOptions()
    pts = np.asarray(points_in_lidar, np.float64)
    pts = pts[:, :3]
    finite = np.isfinite(pts)
    pts = pts[finite[:, 0] & finite[:, 1] & finite[:, 2]]
    rng = np.linalg.norm(pts, axis=1)
    pts = pts[(rng >= opts.min_range_m) & (rng <= opts.max_range_m)]
    empty = np.zeros((0, 3))
    if len(pts) < opts.neighbours:
        return empty, empty
    vox = _voxel_means_941624b(pts, opts.voxel_m)
    if len(vox) < opts.neighbours:
        return empty, empty
    pose = np.asarray(cam_from_lidar, np.float64)
    rot = quat_to_rotmat(pose[3:])
    p_cam = vox @ rot.T + pose[:3]
    keep = np.ones(len(vox), bool)
    if opts.exclude_camera_view:
        z = p_cam[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = camera.fx * p_cam[:, 0] / z + camera.cx
            v = camera.fy * p_cam[:, 1] / z + camera.cy
        keep = ~((z > 0.05) & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5)
                 & (v < camera.height - 0.5))
    cand = np.flatnonzero(keep)
    if len(cand) > opts.max_candidates:
        cand = cand[np.linspace(0, len(cand) - 1, opts.max_candidates).astype(np.int64)]
    normal, planar = _normals_941624b(vox, vox[cand], opts.neighbours, opts.max_flatness,
                                          opts.min_spread)
    cand, normal = cand[planar], normal[planar]
    flip = (normal * vox[cand]).sum(axis=1) > 0
    normal[flip] *= -1.0
    return p_cam[cand], normal @ rot.T


# ----------------------------------------------------------------------- helpers
def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return (a.dtype == b.dtype and a.shape == b.shape
                and a.tobytes() == np.ascontiguousarray(b).tobytes())
    return bool(a == b)


def _project_both(scan: ArrayLike, cam_from_lidar: ArrayLike, camera: Camera,
                  opts: ProjectionOptions, monkeypatch: pytest.MonkeyPatch) -> tuple[Any, Any]:
    def arrays(s: Any) -> tuple[Any, ...]:
        return (s.depth, s.uv, s.z, s.point_index, sorted(s.counts.items()))

    new = arrays(project_lidar(scan, cam_from_lidar, camera, opts, distort=False))
    with monkeypatch.context() as m:
        m.setattr(projection_module, "_checked_points", _checked_points_941624b)
        m.setattr(projection_module, "_in_front", _in_front_941624b)
        old = arrays(project_lidar(scan, cam_from_lidar, camera, opts, distort=False))
    return new, old


def _variants(scan: NDArray[np.floating]) -> list[NDArray[np.floating]]:
    """The scan; with NaN / inf rows and rows far out (range filters); as float64 (M, 3)."""
    bad = np.array(scan, copy=True)
    bad[::97, 1] = np.nan
    bad[5::89, 0] = np.inf
    bad[7::83, 2] *= 40.0
    return [scan, bad, np.ascontiguousarray(np.asarray(scan, np.float64)[:, :3])]


def _check_scan(scan: NDArray[np.floating], cam_from_lidar: ArrayLike, camera: Camera,
                monkeypatch: pytest.MonkeyPatch) -> int:
    """Both stages on the scan's variants, new against 941624b; the surface points found."""
    drop = ProjectionOptions(nan_policy=NanPolicy.DROP)
    found = 0
    for k, s in enumerate(_variants(scan)):
        new, old = _project_both(s, cam_from_lidar, camera, drop, monkeypatch)
        assert _same(new, old), k
        if k != 1:  # all finite: the default policy, which raises on NaN
            new, old = _project_both(s, cam_from_lidar, camera, ProjectionOptions(), monkeypatch)
            assert _same(new, old), k
        for opts in (ScanSamplingOptions(), ScanSamplingOptions(voxel_m=0.2, min_range_m=1.0),
                     ScanSamplingOptions(max_range_m=np.inf)):
            p_new, n_new = scan_surface_points(s, cam_from_lidar, camera, opts)
            p_old, n_old = scan_surface_points_941624b(s, cam_from_lidar, camera, opts)
            # the same points; normals to rounding (compiled PCA, not LAPACK's: voxel_normals.h)
            assert _same(p_new, p_old), k
            assert n_new.shape == n_old.shape and n_new.dtype == n_old.dtype, k
            np.testing.assert_allclose(n_new, n_old, rtol=0, atol=1e-12, err_msg=str(k))
            found += len(p_new)
    return found


# ----------------------------------------------------------------------- tests
@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 9, 255, 256, 257, 5000])
def test_voxel_means_same_as_numpy(n: int) -> None:
    """The compiled voxel means: numpy's (941624b) bit for bit, for one point and many, voxels
    of one point and of many, points at voxel edges and far apart; the range test of the scan."""
    from bimcap import _core

    rng = np.random.default_rng(n)
    for spread, voxel in ((0.05, 0.1), (3.0, 0.1), (40.0, 0.25), (1e4, 0.5)):
        pts = rng.normal(0.0, spread, (n, 3))
        pts[: n // 3] = np.round(pts[: n // 3] / voxel) * voxel  # exactly on voxel edges
        means, kept = _core.voxel_means(pts, 0.0, np.inf, voxel)
        assert kept == n
        assert _same(means, _voxel_means_941624b(pts, voxel))
        rng_m = np.sqrt(pts[:, 0] * pts[:, 0] + pts[:, 1] * pts[:, 1] + pts[:, 2] * pts[:, 2])
        inside = (rng_m >= 0.5 * spread) & (rng_m <= 2.0 * spread)
        means, kept = _core.voxel_means(pts, 0.5 * spread, 2.0 * spread, voxel)
        assert kept == int(inside.sum())
        if kept:
            assert _same(means, _voxel_means_941624b(pts[inside], voxel))


def test_voxel_means_and_pca_normals_bad_input() -> None:
    from bimcap import _core

    with pytest.raises(_core.InputError, match="voxel"):
        _core.voxel_means(np.zeros((3, 3)), 0.0, 1.0, 0.0)
    with pytest.raises(_core.InputError, match="points"):
        _core.voxel_means(np.array([[1e30, 0.0, 0.0]]), 0.0, np.inf, 0.1)
    with pytest.raises(_core.InputError, match="points"):
        _core.voxel_means(np.zeros((3, 4)), 0.0, 1.0, 0.1)
    with pytest.raises(_core.InputError, match="neighbours"):
        _core.pca_normals(np.zeros((3, 3)), np.array([[0, 1, 3]]), 0.1, 0.05)
    with pytest.raises(_core.InputError, match="neighbours"):
        _core.pca_normals(np.zeros((3, 3)), np.zeros((2, 0), np.int64), 0.1, 0.05)
    with pytest.raises(ScanSamplingError, match="2\\^40"):
        scan_surface_points(np.array([[1e30, 0.0, 0.0]] * 20), [0, 0, 0, 0, 0, 0, 1],
                            Camera(100, 100, 50, 50, 100, 80),
                            ScanSamplingOptions(max_range_m=np.inf))


def test_lidar_stages_same_as_941624b_on_box_room(monkeypatch: pytest.MonkeyPatch) -> None:
    found = 0
    for f in frames(3) + frames(2, 516, 386, 7):
        found += _check_scan(np.asarray(f.points_in_lidar), f.cam_from_lidar,
                             f.camera.pinhole(), monkeypatch)
    assert found > 0


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_lidar_stages_same_as_941624b_on_real_frames(world: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Every third frame of a generated world's scans, projected as the front end does."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence

    seq = read_sequence(seq_dir)
    found = 0
    for i in range(0, len(seq.frames), 3):
        found += _check_scan(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, monkeypatch)
    assert found > 1000


def unsupported_depths_941624b(depth: ArrayLike, measured: ArrayLike, uv: ArrayLike,
                               noise_m: float, options: Any = None,
                               ties_by_index: bool = False) -> NDArray[np.bool_]:
    """The 941624b code: the k returns nearest each keypoint from scipy's cKDTree, or, with
    ``ties_by_index``, from every return's distance (dx² + dy², rounded as cKDTree does), the
    nearest first and equal distances by index (the compiled search's rule since f43df25)."""
    from scipy.spatial import cKDTree

    from bimcap.features.tracks import DepthLookupOptions

    opts = options or DepthLookupOptions()
    q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(depth, dtype=np.float64)
    m = np.asarray(measured, dtype=np.float64)
    out = np.zeros(len(q), dtype=bool)
    k = opts.support_returns
    if opts.max_support_z is None or len(q) == 0:
        return out
    v, u = np.nonzero((m > 0) & (d > 0))
    if len(u) < k:
        return out
    diff = m[v, u] - d[v, u]
    pts = np.stack([u, v], axis=1).astype(np.float64)
    if ties_by_index:
        dx, dy = q[:, :1] - pts[:, 0], q[:, 1:] - pts[:, 1]
        idx = np.argsort(dx * dx + dy * dy, axis=1, kind="stable")[:, :k]
    else:
        _, idx = cKDTree(pts).query(q, k=k)
    bias = diff[np.asarray(idx).reshape(len(q), k)].mean(axis=1)
    sigma = max(noise_m, opts.min_noise_m)
    return np.asarray(np.abs(bias) > opts.max_support_z * sigma / np.sqrt(k))


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_unsupported_depths_same_as_941624b(world: str) -> None:
    """The keypoints whose depth the returns contradict: the same flags as the 941624b code on
    the front end's float32 maps (and as float64 / float16 / integer maps), for sub-pixel
    keypoints, and for whole-pixel keypoints (equal distances to many returns) with equal
    distances taken by index, as the compiled search does (cKDTree takes them in the order its
    tree visits them), on the completed depth and the depth moved 6 cm off (many flagged)."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.features.tracks import DepthLookupOptions, unsupported_depths
    from bimcap.frontend.providers import LidarDepthProvider
    from bimcap.frontend.runner import FrameContext, get_undistorter

    seq = read_sequence(seq_dir)
    provider = LidarDepthProvider()
    rng = np.random.default_rng(3)
    flagged = 0
    for i in range(0, 12, 3):
        und = get_undistorter(seq.camera)
        ctx = FrameContext(seq, i, seq.camera, und.pinhole, np.zeros((1, 1, 3), np.uint8), und,
                           np.array([0, 0, 0, 0, 0, 0, 1.0]))
        dense = provider(ctx)
        measured = ctx.measured_depth
        assert measured is not None and dense.dtype == np.float32
        h, w = dense.shape
        sub = rng.uniform(-0.5, [w - 0.5, h - 0.5], (800, 2))
        whole = rng.integers(0, [w, h], (800, 2)).astype(np.float64)
        off = np.where(dense > 0, dense + np.float32(0.06), dense).astype(np.float32)
        for depth in (dense, off):
            for opts in (None, DepthLookupOptions(support_returns=4, max_support_z=2.0)):
                for uv, by_index in ((sub, False), (whole, True)):
                    want = unsupported_depths_941624b(depth, measured, uv, 0.02, opts, by_index)
                    for dd, mm in ((depth, measured), (depth.astype(np.float64), measured),
                                   (depth, measured.astype(np.float16))):
                        assert np.array_equal(
                            unsupported_depths(dd, mm, uv, 0.02, opts),
                            unsupported_depths_941624b(dd, mm, uv, 0.02, opts, by_index))
                    assert np.array_equal(unsupported_depths(depth, measured, uv, 0.02, opts),
                                          want)
                    mm_int = (measured * 1000).astype(np.uint16)
                    dd_int = (depth * 1000).astype(np.int32)
                    assert np.array_equal(
                        unsupported_depths(dd_int, mm_int, uv, 20.0, opts),
                        unsupported_depths_941624b(dd_int, mm_int, uv, 20.0, opts, by_index))
                    flagged += int(want.sum())
    assert flagged > 100
