"""The front end's speed-ups (issue 14) give the same arrays, bit for bit, as the code before them
(``tests/_frontend_reference.py``), on the box-room frames run through the whole chain: LiDAR
projection, linear completion, geometric segmentation, planar smoothing, semantic sampling; and
BLAS / OpenCV on one thread inside the front end's jobs changes none of its arrays."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import _frontend_reference as ref
from _fusion_scene import frames
from bimcap.frontend.semantic_map import (
    SamplingMode,
    SemanticMapError,
    SemanticSamplingOptions,
    pixel_surface_area,
    sample_semantic_points,
)
from bimcap.fusion import CompletionMethod, CompletionOptions, complete_depth, project_lidar
from bimcap.fusion.completion import (
    LinearOptions,
    PlanarSmoothingOptions,
    Triangulation,
    complete_linear,
    smooth_planar_regions,
)
from bimcap.geometry.camera import Camera
from bimcap.segmentation.geometric import GeometricOptions, segment_geometric

#: Generated worlds (bench_generalization.py); the tests on their frames skip without them.
_WORLDS = Path("/tmp/gen")


@dataclass
class _Frame:
    camera: Camera  # the pinhole camera of every map
    world_from_cam: np.ndarray  # (7,)
    sparse: object  # bimcap.fusion.SparseDepth
    dense: np.ndarray  # (H, W) float32 linear completion
    labels: np.ndarray  # (H, W) uint8 geometric labels
    smoothed: np.ndarray  # (H, W) float32 after planar smoothing


@pytest.fixture(scope="module")
def chain() -> list[_Frame]:
    out = []
    for f in frames(3) + frames(2, 516, 386, 7):
        cam = f.camera.pinhole()
        sparse = project_lidar(f.points_in_lidar, f.cam_from_lidar, cam)
        dense = np.asarray(complete_depth(sparse, CompletionOptions(CompletionMethod.LINEAR)),
                           np.float32)
        labels = segment_geometric(dense, cam, f.world_from_cam)
        smoothed = smooth_planar_regions(dense, labels, cam)
        out.append(_Frame(cam, f.world_from_cam, sparse, dense, labels, smoothed))
    return out


def test_chain_has_content(chain: list[_Frame]) -> None:
    """The frames exercise every stage (a check that cannot pass on empty maps)."""
    for f in chain:
        assert (f.dense > 0).mean() > 0.5
        assert len(np.unique(f.labels)) >= 3
        assert not np.array_equal(f.smoothed, f.dense)


def test_pixel_surface_area_same_as_before(chain: list[_Frame]) -> None:
    for f in chain:
        for depth in (f.dense, f.smoothed):
            new = pixel_surface_area(depth, f.camera)
            assert np.array_equal(new, ref.pixel_surface_area_reference(depth, f.camera))
            assert new.tobytes() == ref.pixel_surface_area_a219de7(depth, f.camera).tobytes()
            assert new.tobytes() == ref.pixel_surface_area_ec113ba(depth, f.camera).tobytes()
    # zeros, edges and a tilted plane, where the gradient's one-sided ends matter
    cam = chain[0].camera
    d = np.zeros((cam.height, cam.width), np.float32)
    d[50:200, 30:300] = 2.0 + np.linspace(0, 1, 270, dtype=np.float32)
    assert np.array_equal(pixel_surface_area(d, cam), ref.pixel_surface_area_reference(d, cam))
    # heights around the blocks of rows: the first and last rows' one-sided differences
    rng = np.random.default_rng(0)
    for h in (2, 3, 31, 32, 33, 64, 65, 97):
        d = (1.0 + 3.0 * rng.random((h, 9))).astype(np.float32)
        d[rng.random(d.shape) < 0.2] = 0.0
        new = pixel_surface_area(d, cam)
        assert new.tobytes() == ref.pixel_surface_area_reference(d, cam).tobytes()
        assert new.tobytes() == ref.pixel_surface_area_ec113ba(d, cam).tobytes()


def test_pixel_surface_area_compiled_same_as_numpy() -> None:
    """The compiled surface area (``_core.pixel_surface_area``) against ec113ba's numpy, bytes
    equal: every width and height from 2 (one-sided differences only) up, non-finite depths
    (their neighbours' cos θ is not finite: 1), other ``min_cos``, float32 and float64 and
    non-contiguous input, a camera with integer intrinsics; and a depth map of a real plane.
    (The compiled rows vectorise on AVX2 CPUs: the same operations, the same bits.)"""
    rng = np.random.default_rng(11)
    for h, w in [(2, 2), (2, 3), (3, 2), (5, 7), (40, 2), (2, 41), (386, 516)]:
        cam = Camera(w, h, 300.7, 301.9, 0.43 * w, 0.55 * h)
        d = 0.5 + 6.0 * rng.random((h, w))
        d[rng.random(d.shape) < 0.15] = 0.0
        d[rng.random(d.shape) < 0.02] = np.nan
        d[rng.random(d.shape) < 0.01] = np.inf
        for depth, min_cos in ((d, 0.1), (d.astype(np.float32), 0.1), (d, 0.0), (d, 0.7)):
            new = pixel_surface_area(depth, cam, min_cos)
            # min_cos 0: a surface seen edge-on, area inf; inf depths: inf − inf
            with np.errstate(divide="ignore", invalid="ignore"):
                old = ref.pixel_surface_area_ec113ba(depth, cam, min_cos)
            assert new.dtype == np.float64 and new.tobytes() == old.tobytes()
    cam = Camera(60, 40, 50, 50, 30, 20)  # integer intrinsics
    v, u = np.mgrid[0:40, 0:120]
    plane = (2.0 + 0.01 * u + 0.02 * v)[:, ::2]  # non-contiguous view; a tilted plane
    new = pixel_surface_area(plane, cam)
    assert new.tobytes() == ref.pixel_surface_area_ec113ba(plane, cam).tobytes()
    assert (new > 0).all()
    with pytest.raises(SemanticMapError, match="H, W >= 2"):
        pixel_surface_area(np.ones((1, 5)), cam)


def test_semantic_sampling_same_as_before(chain: list[_Frame]) -> None:
    opts = SemanticSamplingOptions(mode=SamplingMode.DENSITY)
    for i, f in enumerate(chain):
        new = sample_semantic_points(f.labels, f.smoothed, f.camera, i, opts)
        with ref.old_semantic_sampling():
            old = sample_semantic_points(f.labels, f.smoothed, f.camera, i, opts)
        assert new.keys() == old.keys()
        assert sum(len(v) for v in new.values()) > 100
        for k in new:
            assert np.array_equal(new[k], old[k])


def test_linear_completion_same_as_before(chain: list[_Frame]) -> None:
    """With Qhull's triangles in Qhull's order (the references triangulate with it), the
    completion of every earlier version bit for bit."""
    qhull = Triangulation.QHULL
    for f in chain:
        for inverse in (True, False):
            opts = LinearOptions(inverse_depth=inverse, triangulation=qhull)
            new = complete_linear(f.sparse, opts)
            assert np.array_equal(new, ref.complete_linear_reference(f.sparse, opts))
            assert new.tobytes() == ref.complete_linear_a219de7(f.sparse, opts).tobytes()
            assert new.tobytes() == ref.complete_linear_c52a7fb(f.sparse, opts).tobytes()
        # a dense map given as an (H, W) array takes the other input path
        assert np.array_equal(complete_linear(f.sparse.depth, LinearOptions(triangulation=qhull)),
                              ref.complete_linear_reference(f.sparse.depth))


def test_filter_triangles_same_as_numpy() -> None:
    """The linear completion's triangle filter in compiled code: c52a7fb's numpy (lengths,
    depth ratio, signed area, the kept ones, their 1/16 px corners) bytes equal, on random
    triangles with long edges, slivers, collinear and repeated corners, corners on half
    sixteenths, NaN coordinates and depths; bad indices raise."""
    from bimcap import _core

    rng = np.random.default_rng(21)
    kept = dropped = 0
    for n, t in ((3, 1), (50, 200), (4000, 8000)):
        uv = rng.uniform(-0.5, 515.5, (n, 2))
        uv[: n // 4] = np.round(uv[: n // 4] * 32) / 32  # ties of rint(16 uv)
        z = 10.0 ** rng.uniform(-1, 1.5, n)
        simp = rng.integers(0, n, (t, 3)).astype(np.int32)
        simp[: t // 10, 2] = simp[: t // 10, 0]  # repeated corners: zero area
        if n > 3:
            uv[5, 0] = np.nan
            z[7] = np.nan
        for max_edge, max_ratio in ((80.0, 1.3), (1e9, 1e9), (5.0, 1.01)):
            good, corners, edge, det = _core.filter_triangles(uv, z, simp, max_edge, max_ratio)
            pa, pb, pc = uv[simp[:, 0]], uv[simp[:, 1]], uv[simp[:, 2]]
            want_edge = np.maximum.reduce([np.linalg.norm(pa - pb, axis=1),
                                           np.linalg.norm(pb - pc, axis=1),
                                           np.linalg.norm(pc - pa, axis=1)])
            zt = z[simp]
            e1, e2 = pb - pa, pc - pa
            want_det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
            with np.errstate(invalid="ignore"):
                ok = ((want_edge <= max_edge) & (zt.max(1) / zt.min(1) <= max_ratio)
                      & (np.abs(want_det) > 2.0))
            want_good = np.flatnonzero(ok)
            want_corners = np.rint(np.stack([pa, pb, pc], 1)[want_good] * 16).astype(np.int32)
            assert edge.tobytes() == want_edge.tobytes() and det.tobytes() == want_det.tobytes()
            assert np.array_equal(good, want_good)
            assert corners.tobytes() == want_corners.tobytes()
            kept += len(good)
            dropped += t - len(good)
    assert kept > 0 and dropped > 0
    with pytest.raises(_core.InputError, match="triangles"):
        _core.filter_triangles(np.zeros((3, 2)), np.ones(3), np.array([[0, 1, 3]], np.int32),
                               80.0, 1.3)


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_linear_completion_real_frames_same_as_before(world: str) -> None:
    """The LiDAR of a generated world's first 6 frames, projected as the front end projects it:
    the completion (inverse depth and depth) with Qhull's triangles, the c52a7fb code's bit for
    bit; skipped without the world."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider

    seq = read_sequence(seq_dir)
    projection = LidarDepthProvider().projection
    for i in range(6):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        maps = []
        for inverse in (True, False):
            opts = LinearOptions(inverse_depth=inverse, triangulation=Triangulation.QHULL)
            maps.append(complete_linear(sparse, opts))
            assert (maps[-1] > 0).mean() > 0.5
            assert maps[-1].tobytes() == ref.complete_linear_c52a7fb(sparse, opts).tobytes()
        # 1/z and z interpolated differ by a few per cent inside a triangle, by a bit on a
        # plane seen square on: the comparison of bytes tells them apart
        assert maps[0].tobytes() != maps[1].tobytes()


def test_planar_smoothing_same_as_before(chain: list[_Frame]) -> None:
    for f in chain:
        old = ref.smooth_planar_regions_reference(f.dense, f.labels, f.camera)
        assert np.array_equal(f.smoothed, old)
        # small regions too: more components, some skipped
        opts = PlanarSmoothingOptions(min_region_px=50)
        assert np.array_equal(smooth_planar_regions(f.dense, f.labels, f.camera, opts),
                              ref.smooth_planar_regions_reference(f.dense, f.labels, f.camera,
                                                                  opts))
        # fitted to the returns (the front end's default since the code before issue 14), with
        # the a219de7 code's rays, distance tables and per-pixel gathers as the reference
        measured = np.asarray(f.sparse.depth, np.float32)
        # (the 8 cm options without the edge-on plane rule of hard-tilt, which the a219de7
        # code does not have: test_fusion_completion checks them)
        for o in (PlanarSmoothingOptions(), PlanarSmoothingOptions(min_region_px=50),
                  replace(PlanarSmoothingOptions().for_noise(0.08), reject_oblique=False)):
            new = smooth_planar_regions(f.dense, f.labels, f.camera, o, measured=measured)
            old = ref.smooth_planar_regions_a219de7(f.dense, f.labels, f.camera, o,
                                                    measured=measured)
            assert new.tobytes() == old.tobytes()
            assert not np.array_equal(new, f.smoothed)  # the returns' fit moved other pixels


def test_planar_smoothing_same_as_fe4da1c(chain: list[_Frame], monkeypatch: pytest.MonkeyPatch
                                          ) -> None:
    """The depth moved onto the planes in compiled code (``_core.move_onto_planes``): the
    fe4da1c numpy code's float32 map bit for bit, fitted to the pixels and to the returns, at
    3 cm and 8 cm noise (with the edge-on plane rule), with one to four planes a region (every
    plane count occurs)."""
    from bimcap import _core

    counts: list[int] = []
    move = _core.move_onto_planes

    def counted(*args: object) -> int:
        counts.append(len(args[5]))  # type: ignore[arg-type]
        return move(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(_core, "move_onto_planes", counted)
    options = [PlanarSmoothingOptions(), PlanarSmoothingOptions(min_region_px=50),
               PlanarSmoothingOptions(min_region_px=50, max_planes=4, assign_threshold_m=0.02,
                                      ransac_threshold_m=0.01),
               PlanarSmoothingOptions(max_change_rel=0.001),
               PlanarSmoothingOptions().for_noise(0.08)]
    for f in chain:
        measured = np.asarray(f.sparse.depth, np.float32)
        for o in options:
            for meas in (None, measured):
                new = smooth_planar_regions(f.dense, f.labels, f.camera, o, measured=meas)
                old = ref.smooth_planar_regions_fe4da1c(f.dense, f.labels, f.camera, o,
                                                        measured=meas)
                assert new.tobytes() == old.tobytes()
    assert set(counts) >= {1, 2, 3}, sorted(set(counts))


def _provider_frames(seq_dir: Path, count: int) -> Iterator[tuple[Any, np.ndarray, Any]]:
    """``(frame context, labels, planar smoothing)`` of a sequence's first ``count`` frames as
    ``refine``'s providers make them (linear completion into ``ctx.depth``, geometric labels);
    the smoothing is ``refine``'s, to be called on them."""
    from bimcap.dataset import read_sequence
    from bimcap.frontend.runner import FrameContext, _load_raw_image, get_undistorter
    from bimcap.geometry.trajectory import read_tum
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import make_providers

    seq = read_sequence(seq_dir)
    depth_p, label_p, refiner = make_providers(RefineConfig(workers=1), seq)
    poses = read_tum(seq.root / "poses" / "gt.tum").poses
    und = get_undistorter(seq.camera)
    for i in range(count):
        image = und.image(_load_raw_image(seq, i, seq.camera))
        ctx = FrameContext(seq, i, seq.camera, und.pinhole, image, und, poses[i])
        depth = depth_p(ctx)
        ctx.depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        yield ctx, label_p(ctx), refiner


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_planar_smoothing_real_frames_same_as_fe4da1c(world: str) -> None:
    """The front end's planar smoothing (``refine``'s providers: linear completion, geometric
    labels, planes fitted to the returns at the scan's own noise) of a generated world's first
    6 frames: the fe4da1c code's map bit for bit; skipped without the world."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    moved = 0
    for ctx, labels, refiner in _provider_frames(seq_dir, 6):
        new = refiner(ctx, labels)
        with ref.old_planar_smoothing():
            old = refiner(ctx, labels)
        assert new.tobytes() == old.tobytes()
        moved += int((new != ctx.depth).sum())
    assert moved > 10_000


def _fused_denominator_ties(rng: np.random.Generator, n: int
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` rays ``x``, ``y`` (N,) and planes (N, 4) whose depth ``−d / (x n0 + y n1 + n2)``
    is, with each product rounded, a float32 tie (1 + odd · 2⁻²⁴ …) exactly, and with either
    product fused into its sum (a fused multiply-add), a double that rounds to the other
    float32: a compiled version with contraction gives other depths on these."""
    from fractions import Fraction

    xs, ys, planes = [], [], []
    while len(xs) < n:
        x, y = rng.uniform(-0.6, 0.6, 2)
        n0, n1 = rng.uniform(-1.0, 1.0, 2)
        s = x * n0 + y * n1  # numpy's rounding: each product, then the sum (n2 = 0)
        if abs(s) < 0.1:
            continue
        f32 = np.float32(rng.uniform(1.0, 8.0))
        tie = float(f32) + float(np.spacing(f32)) / 2  # half-way to the next float32
        d = -tie * s
        if -d / s != tie:
            continue
        fused = [float(Fraction(x) * Fraction(n0) + Fraction(y * n1)),
                 float(Fraction(y) * Fraction(n1) + Fraction(x * n0))]
        if all(np.float32(-d / f) != np.float32(tie) for f in fused):
            xs.append(x)
            ys.append(y)
            planes.append((n0, n1, 0.0, d))
    return np.array(xs), np.array(ys), np.array(planes)


def test_move_onto_planes_same_as_numpy() -> None:
    """``_core.move_onto_planes`` against the fe4da1c numpy (``ref.move_onto_planes_fe4da1c``)
    on random regions with one to four planes and on the edge cases: equal distances (the first
    plane wins), NaN products, zero denominators (±inf, NaN depths), −0 offsets, depths at the
    change limit, planes beyond float32's range, and float32 ties where a fused multiply-add
    would round the other way."""
    from bimcap import _core

    rng = np.random.default_rng(11)
    size, n = 20_000, 6000
    for k in (1, 2, 3, 4):
        flat = rng.permutation(size)[:n].astype(np.int64)
        x, y = rng.uniform(-0.6, 0.6, n), rng.uniform(-0.45, 0.45, n)
        normals = rng.normal(size=(k, 3)) * [0.3, 0.3, 1.0]  # seen from the front
        normals[:, 2] = np.abs(normals[:, 2])
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        pl = np.concatenate([normals, -rng.uniform(1.0, 5.0, (k, 1))], 1)
        if k > 1:
            pl[1] = pl[0]  # equal distances: np.argmin's first plane
        if k == 3:
            pl[2] = [1.0, 0.0, 0.0, -0.0]  # through the camera: zero denominators at x = 0
            x[50:60] = 0.0
        # depths near the first plane's (±20 %), and none
        z0 = -pl[0, 3] / (x * pl[0, 0] + y * pl[0, 1] + pl[0, 2])
        cur = z0 * rng.uniform(0.8, 1.2, n)
        cur[:50] = 0.0
        pts = np.stack([x * cur, y * cur, cur], 1)
        products = pts @ pl[:, :3].T if k > 1 else None
        if products is not None:
            products[60:70, 1] = np.nan
            products[70:80, :] = np.nan
        for rel, thr in ((0.15, 0.08), (0.5, 0.3), (0.0, 0.0), (np.inf, np.inf)):
            out = rng.uniform(0, 9, size).astype(np.float32)
            expected = out.copy()
            with np.errstate(invalid="ignore"):  # inf · 0 at rel = inf: NaN, not moved
                ref.move_onto_planes_fe4da1c(expected, flat, x, y, cur, pl, products, thr, rel)
            moved = _core.move_onto_planes(out, flat, x, y, cur, pl, products, thr, rel)
            assert out.tobytes() == expected.tobytes()
            if rel > 0:
                assert moved > 100
    # zero denominators, −0 and the float32 range, one plane (1, 0, 0, d) or (0, 0, 1, d)
    x = np.array([0.0, -0.0, 0.0, 0.0, 0.0, 0.0])
    cur = np.array([1.0, 1.0, 3.0e38, 3.0e38, 3.0e38, 3.3e38])
    flat = np.arange(6, dtype=np.int64)
    big = float(np.finfo(np.float32).max)
    for pl in ([[1.0, 0.0, 0.0, -1.0]], [[1.0, 0.0, 0.0, 0.0]], [[-1.0, 0.0, 0.0, -0.0]],
               [[0.0, 0.0, 1.0, -big]], [[0.0, 0.0, 1.0, -(big + 2.0**102)]],
               [[0.0, 0.0, 1.0, -(big + 2.0**103)]], [[0.0, 0.0, 1.0, -3.5e38]]):
        plane = np.array(pl)
        out = np.zeros(6, np.float32)
        expected = out.copy()
        with np.errstate(over="ignore"):
            ref.move_onto_planes_fe4da1c(expected, flat, x, x, cur, plane, None, 0.08, 1.0)
        _core.move_onto_planes(out, flat, x, x, cur, plane, None, 0.08, 1.0)
        assert out.tobytes() == expected.tobytes()
    assert np.isinf(expected[2:]).sum() == 4  # (the last plane: beyond float32's largest)
    # float32 ties: a contracted product would round them the other way
    x, y, planes = _fused_denominator_ties(rng, 20)
    flat = np.arange(len(x), dtype=np.int64)
    cur = np.full(len(x), 5.0)  # the tie depths (1 … 8 m) all within 100 %
    for i in range(len(x)):
        out = np.zeros(len(x), np.float32)
        expected = out.copy()
        ref.move_onto_planes_fe4da1c(expected, flat[i:i + 1], x[i:i + 1], y[i:i + 1],
                                     cur[i:i + 1], planes[i:i + 1], None, 0.08, 1.0)
        _core.move_onto_planes(out, flat[i:i + 1], x[i:i + 1], y[i:i + 1], cur[i:i + 1],
                               planes[i:i + 1], None, 0.08, 1.0)
        assert out.tobytes() == expected.tobytes() and out[i] > 0


def test_component_pixels_same_as_numpy() -> None:
    """``_core.component_pixels`` against fe4da1c's stable sort and ``searchsorted``: the same
    int64 arrays on OpenCV's components of random masks (4- and 8-connected), on label images
    with unused and empty labels, all background and one pixel; bad labels raise."""
    import cv2

    from bimcap import _core

    rng = np.random.default_rng(8)
    images = []
    for density in (0.3, 0.6, 0.9):
        mask = (rng.random((97, 131)) < density).astype(np.uint8)
        for connectivity in (4, 8):
            n_comp, comp = cv2.connectedComponents(mask, connectivity=connectivity)
            images.append((comp, n_comp))
    images.append((rng.integers(0, 5, (40, 60)).astype(np.int32), 9))  # labels 5..8 unused
    images.append((np.zeros((3, 4), np.int32), 1))
    images.append((np.array([[0, 0], [0, 1]], np.int32), 2))
    images.append((np.zeros((0, 4), np.int32), 1))
    for comp, n_comp in images:
        pixels, starts = _core.component_pixels(comp, n_comp)
        old_pixels, old_starts = ref.component_pixels_fe4da1c(comp, n_comp)
        assert pixels.dtype == old_pixels.dtype and starts.dtype == old_starts.dtype
        assert pixels.tobytes() == old_pixels.tobytes()
        assert starts.tobytes() == old_starts.tobytes()
    assert images[0][1] > 100
    for labels, count, field, text in [
        (np.array([[0, 3]], np.int32), 3, "labels", "label 3 at 1 is outside [0, 3)"),
        (np.array([[-1, 0]], np.int32), 3, "labels", "label -1 at 0"),
        (np.zeros((2, 2), np.int64), 3, "labels", "dtype int32"),
        (np.zeros(4, np.int32), 3, "labels", "shape (n, n)"),
        (np.zeros((2, 2), np.int32), 0, "count", ">= 1"),
    ]:
        with pytest.raises(_core.InputError, match=field) as err:
            _core.component_pixels(labels, count)
        assert err.value.field == field and text in str(err.value)


def test_move_onto_planes_forms_numpys_products() -> None:
    """With no products given, the move forms p · n_k itself: the same depths, bytes equal, as
    with numpy's ``_points(x, y, z) @ n.T`` (random regions of 2 to 5000 pixels, 2 to 5 planes,
    pixels tied between two planes, NaN depths)."""
    from bimcap import _core
    from bimcap.fusion.completion import _points

    rng = np.random.default_rng(12)
    moved = 0
    for n in (2, 3, 17, 512, 5000):
        for k in (2, 3, 5):
            x, y = rng.uniform(-0.7, 0.7, n), rng.uniform(-0.5, 0.5, n)
            z = rng.uniform(0.5, 8.0, n)
            z[::97] = np.nan
            nrm = rng.normal(size=(k, 3))
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            planes = np.concatenate([nrm, rng.uniform(-6.0, -0.5, (k, 1))], axis=1)
            planes[1] = planes[0]  # ties: the first of two equal planes
            flat = rng.permutation(2 * n)[:n].astype(np.int64)
            outs = []
            for products in (_points(x, y, z) @ planes[:, :3].T, None):
                out = np.zeros(2 * n, np.float32)
                moved += _core.move_onto_planes(out, flat, x, y, z, planes, products, 0.5, 0.6)
                outs.append(out)
            assert outs[0].tobytes() == outs[1].tobytes()
    assert moved > 0


def test_move_onto_planes_rejects_bad_arrays() -> None:
    """Wrong dtypes, shapes, layouts, indices and plane tables raise ``_core.InputError``
    naming the argument, and nothing is written."""
    from bimcap import _core

    n = 4
    good = {"out": np.zeros(10, np.float32), "flat": np.arange(n, dtype=np.int64),
            "ray_x": np.zeros(n), "ray_y": np.zeros(n), "depth": np.ones(n),
            "planes": np.array([[0.0, 0.0, 1.0, -1.0], [0.0, 0.0, 1.0, -2.0]]),
            "products": np.ones((n, 2)), "assign_threshold_m": 0.08, "max_change_rel": 1.0}
    bad = [
        ({"out": np.zeros(10)}, "out", "dtype float32"),
        ({"out": np.zeros((2, 5), np.float32)}, "out", "shape (n,)"),
        ({"out": np.zeros(20, np.float32)[::2]}, "out", "C-contiguous"),
        ({"flat": np.arange(n, dtype=np.int32)}, "flat", "dtype int64"),
        ({"flat": np.array([0, 1, 10, 2])}, "flat", "index 10 at 2 is outside"),
        ({"flat": np.array([0, -1, 1, 2])}, "flat", "index -1 at 1"),
        ({"ray_x": np.zeros(n + 1)}, "ray_x", "shape (4,)"),
        ({"ray_y": [0.0] * n}, "ray_y", "numpy array"),
        ({"depth": np.ones(n, np.float32)}, "depth", "dtype float64"),
        ({"planes": np.zeros((2, 3))}, "planes", "shape (n, 4)"),
        ({"planes": np.zeros((0, 4))}, "planes", "at least one plane"),
        ({"products": np.ones((n, 3))}, "products", "shape (4, 2)"),
        ({"products": np.ones((2, n)).T}, "products", "C-contiguous"),
    ]
    for override, field, text in bad:
        args = good | override
        out = args["out"]
        before = np.array(out, copy=True)
        with pytest.raises(_core.InputError, match=field) as err:
            _core.move_onto_planes(**args)
        assert err.value.field == field and text in str(err.value)
        assert np.array_equal(np.asarray(out), before)
    read_only = np.zeros(10, np.float32)
    read_only.flags.writeable = False
    with pytest.raises(_core.InputError, match="out") as err:
        _core.move_onto_planes(**(good | {"out": read_only}))
    assert "read-only" in str(err.value)
    assert _core.move_onto_planes(**good) == n  # z = 1 / 1, 2 / 1 within 100 %: all moved
    assert _core.move_onto_planes(**(good | {"flat": np.zeros(0, np.int64), "ray_x": np.zeros(0),
                                             "ray_y": np.zeros(0), "depth": np.zeros(0),
                                             "products": np.zeros((0, 2))})) == 0


def test_segmentation_same_as_before(chain: list[_Frame], monkeypatch: pytest.MonkeyPatch
                                     ) -> None:
    """The labels (the code as of a219de7, ``_geometric_reference``), and every protrusion
    decision on the way (columns and walls both occur), also against the walk before issue 14."""
    import _geometric_reference as before
    from bimcap.segmentation import geometric

    decisions: list[tuple[bool, bool, bool]] = []
    new_protrudes = geometric._protrudes

    def both(region, pts, plane, opts):  # type: ignore[no-untyped-def]
        out = new_protrudes(region, pts, plane, opts)
        full = region.full_mask()
        decisions.append((out, before._protrudes(full, pts, plane, opts),
                          ref.protrudes_reference(full, pts, plane, opts)))
        return out

    monkeypatch.setattr(geometric, "_protrudes", both)
    # completed LiDAR depth, and the rendered depth (where the columns come out whole)
    inputs = [(f.dense, f.camera, f.world_from_cam, f.labels) for f in chain]
    inputs += [(g.depth, g.camera, g.world_from_cam, None) for g in frames(4, 516, 386, 7)]
    for depth, camera, pose, labels in inputs:
        new = segment_geometric(depth, camera, pose)
        old = before.segment_geometric(depth, camera, pose)
        assert np.array_equal(new, old)
        assert labels is None or np.array_equal(new, labels)
        with ref.old_segmentation():  # what the bench times as the previous code
            assert np.array_equal(geometric.segment_geometric(depth, camera, pose), new)
    assert decisions and all(a == b == c for a, b, c in decisions)
    assert {a for a, _, _ in decisions} == {True, False}
    # other working resolutions (other nearest-neighbour upsampling maps), noisier settings
    f = chain[0]
    for opts in (GeometricOptions(work_width=100), GeometricOptions(work_width=173),
                 GeometricOptions(work_width=300), GeometricOptions().for_noise(0.08)):
        new = segment_geometric(f.dense, f.camera, f.world_from_cam, opts)
        assert np.array_equal(new, before.segment_geometric(f.dense, f.camera, f.world_from_cam,
                                                            opts))


@pytest.mark.parametrize("threads", [1, 2])
def test_components_on_the_box_numbered_as_on_the_image(threads: int) -> None:
    """The segmenter's connected components, found on the even-aligned box of the mask's
    pixels: the same numbering, pixels and stats as OpenCV's on the whole image (masks of
    noise, of blobs, in boxes at odd and even rows and columns, touching the borders, empty)."""
    import cv2

    from bimcap.segmentation.geometric import _Components, _Region

    rng = np.random.default_rng(threads)
    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        for t in range(400):
            h, w = 193, 258
            m = rng.random((h, w)) < rng.uniform(0.02, 0.8)
            if t % 2:
                m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN,
                                     np.ones((2, 2), np.uint8)).astype(bool)
            r0, r1 = sorted(rng.integers(0, h, 2))
            c0, c1 = sorted(rng.integers(0, w, 2))
            mask = np.zeros_like(m)
            mask[r0:r1 + 1, c0:c1 + 1] = m[r0:r1 + 1, c0:c1 + 1]
            if t == 0:
                mask[:] = False
            n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8),
                                                                 connectivity=8)
            comps = _Components.of(mask)
            assert comps.count == n
            pts = np.zeros((h, w, 3))
            for c in range(1, n):
                assert comps.stats[c, 4] == stats[c, 4]
                region = _Region.component(comps, c, pts)
                x, y, bw, bh = stats[c, :4]
                assert (region.rows, region.cols) == (slice(y, y + bh), slice(x, x + bw))
                assert np.array_equal(region.full_mask(), comp == c)
    finally:
        cv2.setNumThreads(before)


def test_normals_same_as_before(chain: list[_Frame]) -> None:
    """Points, normals and their masks, component by component: the stacked code's bit for bit
    (signed zeros included), with and without the box blur."""
    import _geometric_reference as before
    from bimcap.segmentation.geometric import _points_and_normals

    for f in chain:
        for step, box in ((2, 5), (3, 1), (4, 11)):
            opts = GeometricOptions(normal_step_px=step, normal_smooth_px=box)
            for new, old in zip(_points_and_normals(f.dense, f.camera, opts),
                                before._points_and_normals(f.dense, f.camera, opts),
                                strict=True):
                assert new.dtype == old.dtype and new.shape == old.shape
                assert new.tobytes() == old.tobytes()


def _work_depths(world: str, count: int) -> list[tuple[np.ndarray, Camera]]:
    """The segmenter's working-resolution depth (258 px across, nearest-neighbour) and camera
    of a generated world's first ``count`` frames (the front end's linear completion of their
    LiDAR); [] without the world."""
    import cv2

    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        return []
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider

    seq = read_sequence(seq_dir)
    projection = LidarDepthProvider().projection
    cam = seq.camera.pinhole()
    work = cam.scaled(258 / cam.width)
    out = []
    for i in range(count):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        dense = np.asarray(complete_linear(sparse), np.float32)
        out.append((cv2.resize(dense, (work.width, work.height),
                               interpolation=cv2.INTER_NEAREST), work))
    return out


def test_normals_same_as_fe4da1c(chain: list[_Frame]) -> None:
    """Points, normals and their masks from ``_core.points_and_cross`` / ``orient_normals`` (and
    OpenCV's blur between them): the fe4da1c numpy code's bytes (signed zeros included), with
    and without the blur, at steps 1 to 24, on the box-room frames, 3 frames each of two
    generated worlds at the working resolution (when generated), and images too small for an
    interior."""
    from bimcap.segmentation.geometric import _points_and_normals

    inputs = [(f.dense, f.camera) for f in chain]
    for world in ("gen-demo-s0", "ifc-SampleHouse4"):
        inputs += _work_depths(world, 3)
    rng = np.random.default_rng(5)
    cam = Camera(5, 3, 4.0, 4.0, 2.0, 1.0)
    for h, w in ((3, 5), (5, 3), (1, 1), (7, 9)):
        depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
        depth[rng.random((h, w)) < 0.2] = 0.0
        inputs.append((depth, Camera(w, h, 4.0, 4.0, w / 2, h / 2)))
    inputs.append((np.full((3, 5), 2.0, np.float32), cam))
    checked = 0
    for depth, camera in inputs:
        for step, box in ((2, 5), (3, 1), (4, 11), (1, 1), (24, 3)):
            opts = GeometricOptions(normal_step_px=step, normal_smooth_px=box)
            new = _points_and_normals(depth, camera, opts)
            old = ref.points_and_normals_fe4da1c(depth, camera, opts)
            for a, b in zip(new, old, strict=True):
                assert a.dtype == b.dtype and a.shape == b.shape
                assert a.tobytes() == b.tobytes()
            checked += int(new[3].sum())
    assert checked > 100_000
    assert len(inputs) >= len(chain) + 5


def test_normals_reject_bad_arrays() -> None:
    """Wrong dtypes, shapes, layouts and steps raise ``_core.InputError`` naming the argument."""
    from bimcap import _core

    depth = np.ones((4, 6), np.float32)
    for override, field, text in [
        ({"depth": depth.astype(np.float64)}, "depth", "dtype float32"),
        ({"depth": depth[:, ::2]}, "depth", "C-contiguous"),
        ({"depth": depth.ravel()}, "depth", "shape (n, n)"),
        ({"step": 0}, "step", ">= 1"),
    ]:
        args = {"depth": depth, "fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0, "step": 1,
                "float32": True} | override
        with pytest.raises(_core.InputError, match=field) as err:
            _core.points_and_cross(**args)
        assert err.value.field == field and text in str(err.value)
    pts, _, ok, cross = _core.points_and_cross(depth, 1.0, 1.0, 0.0, 0.0, 1, False)
    read_only = ok.copy()
    read_only.flags.writeable = False
    for override, field, text in [
        ({"normals": cross.astype(np.float32)}, "normals", "dtype float64"),
        ({"points": pts[:, :5]}, "points", "shape (4, 6, 3)"),
        ({"ok": ok.astype(np.uint8)}, "ok", "dtype bool"),
        ({"ok": read_only}, "ok", "read-only"),
    ]:
        args = {"normals": cross, "points": pts, "ok": ok} | override
        with pytest.raises(_core.InputError, match=field) as err:
            _core.orient_normals(**args)
        assert err.value.field == field and text in str(err.value)


def test_vertical_ransac_same_as_before(chain: list[_Frame]) -> None:
    import _geometric_reference as before
    from bimcap.segmentation.geometric import (
        _points_and_normals,
        _ransac_vertical,
        _work_scene,
    )

    opts = GeometricOptions()
    for f in chain:
        scene = _work_scene(f.dense, f.camera, f.world_from_cam, opts)
        pts, _, nrm, nok = _points_and_normals(f.dense, f.camera, opts)
        up = np.array([0.0, -1.0, 0.0])
        vert = nok & (np.abs(nrm @ up) < 0.4)
        new = _ransac_vertical(scene, np.flatnonzero(vert), up, opts, np.random.default_rng(3))
        old = ref.ransac_vertical_reference(pts[vert], nrm[vert], up, opts,
                                            np.random.default_rng(3))
        old_a219 = before._ransac_vertical(pts[vert], nrm[vert], up, opts,
                                           np.random.default_rng(3))
        assert new is not None and old is not None and old_a219 is not None
        assert np.array_equal(new.normal, old.normal) and new.offset == old.offset
        assert np.array_equal(new.normal, old_a219.normal) and new.offset == old_a219.offset


def test_one_thread_changes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole front end (LiDAR, completion, geometric labels, smoothing, SIFT, matching) gives
    the same arrays with BLAS and OpenCV on their default threads as on one."""
    from contextlib import nullcontext

    from _frontend_scene import SceneSequence, default_poses
    from bimcap.features import SiftOptions
    from bimcap.frontend import FrontendConfig, run_frontend, runner
    from bimcap.frontend.providers import (
        LidarDepthProvider,
        PlanarDepthRefiner,
        SegmenterLabelProvider,
    )
    from bimcap.segmentation.geometric import GeometricSegmenter

    seq = SceneSequence.write(tmp_path / "seq", poses=default_poses(3), lidar=True)
    config = FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2)

    def run() -> dict[str, np.ndarray]:
        res = run_frontend(seq, config, seq.gt, LidarDepthProvider(),
                           SegmenterLabelProvider(GeometricSegmenter(), uses_pose=True),
                           depth_refiner=PlanarDepthRefiner(), workers=1, progress=False)
        return {k: v for k, v in vars(res).items() if isinstance(v, np.ndarray)}

    one = run()
    monkeypatch.setattr(runner, "one_thread", nullcontext)
    default = run()
    assert one.keys() == default.keys() and len(one["match_frames"]) > 0
    for k in one:
        assert np.array_equal(one[k], default[k]), k


def test_one_thread_restores_opencv() -> None:
    import cv2

    from bimcap.frontend.runner import one_thread

    before = cv2.getNumThreads()
    with one_thread():
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


@pytest.mark.parametrize("n", [3, 4, 511, 512, 513, 514, 1024, 1025, 3000])
@pytest.mark.parametrize("hypotheses", [1, 2, 3, 150])
def test_blocked_ransac_scores_same_as_whole_table(n: int, hypotheses: int) -> None:
    """The RANSACs' scores in blocks of rows: the whole table's, for every block remainder."""
    from bimcap.fusion.completion import _inlier_counts
    from bimcap.segmentation.geometric import _plane_scores

    rng = np.random.default_rng(n + hypotheses)
    pts = rng.normal(size=(n, 3)) * 3.0
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    hn = rng.normal(size=(hypotheses, 3))
    hn /= np.linalg.norm(hn, axis=1, keepdims=True)
    d = rng.normal(size=hypotheses)
    thr = (0.5 + 0.01 * np.abs(pts[:, 2]))[:, None]
    whole = ((np.abs(pts @ hn.T + d) < thr) & (np.abs(nrm @ hn.T) > 0.5)).sum(0)
    assert np.array_equal(_plane_scores(pts, hn, d, thr, nrm, 0.5), whole)
    assert np.array_equal(_plane_scores(pts, hn, d, thr), (np.abs(pts @ hn.T + d) < thr).sum(0))
    assert np.array_equal(_inlier_counts(pts, hn, d, 0.5),
                          (np.abs(pts @ hn.T + d) < 0.5).sum(0))
    assert n < 500 or whole.sum() > 0  # the large tables have inliers to count


def test_plane_ransac_same_as_before(chain: list[_Frame]) -> None:
    from bimcap.fusion.completion import fit_plane_ransac

    for f in chain:
        rows, cols = np.nonzero(f.dense > 0)
        pts = f.camera.backproject(np.stack([cols, rows], 1)[::7], f.dense[rows, cols][::7],
                                   distorted=False)
        for iterations in (1, 2, 64):
            new = fit_plane_ransac(pts, 0.03, iterations, np.random.default_rng(1))
            old = ref.fit_plane_ransac_reference(pts, 0.03, iterations, np.random.default_rng(1))
            assert new is not None and old is not None
            assert np.array_equal(new[0], old[0]) and np.array_equal(new[1], old[1])


def test_matching_same_as_before() -> None:
    """Descriptor matches of the box-room images (every pair, both directions), and a tie."""
    from bimcap.features import extract_sift, match_descriptors

    feats = [extract_sift(f.image) for f in frames(3) + frames(2, 516, 386, 7)]
    n = 0
    for fa in feats:
        for fb in feats:
            new = match_descriptors(fa.descriptors, fb.descriptors)
            with ref.old_matching():
                old = match_descriptors(fa.descriptors, fb.descriptors)
            assert np.array_equal(new, old)
            n += len(new)
    assert n > 1000
    sim = np.random.default_rng(0).random((40, 30)).astype(np.float32)
    sim[[3, 7], 5] = 2.0  # a tie: the first row is the arg-max
    new, old = ref.top2_columns_opencv_reference(sim.copy()), ref.top2_columns_reference(sim.copy())
    assert new[0][5] == 3
    for x, y in zip(new, old, strict=True):
        assert np.array_equal(x, y) and x.dtype == y.dtype


def _noisy_copies(rng: np.random.Generator, n_a: int, n_b: int, width: int,
                  high: int) -> tuple[np.ndarray, np.ndarray]:
    """``a`` (n_a, width) random uint8 rows (below ``high``, scaled to RootSIFT's norm of 512
    for 128 wide ones); ``b`` (n_b, width): some of them
    permuted with a little noise, some exact (ties between rows of a and of b), the rest new."""
    def rows(n: int) -> np.ndarray:  # SIFT-like: rows of norm ~512, as RootSIFT's
        r = rng.integers(0, high, (n, width)).astype(np.float64)
        if width == 128:
            r *= 512.0 / np.linalg.norm(r, axis=1, keepdims=True)
        return np.clip(np.rint(r), 0, 255).astype(np.uint8)

    a = rows(n_a)
    a[5] = a[4]  # two equal rows of a: a tie in b's direction
    b = rows(n_b)
    k = min(n_a, n_b) * 2 // 3
    pick = rng.permutation(n_a)[:k]
    noise = rng.integers(-2, 3, (k, width))
    b[:k] = np.clip(a[pick].astype(int) + noise, 0, 255).astype(np.uint8)
    b[k] = a[4]
    b[k + 1] = b[k + 2] = a[7]  # two equal rows of b: a tie in a's direction
    return a, b


@pytest.mark.parametrize(("n_a", "n_b"), [(300, 250), (2047, 900), (2049, 800), (4500, 2600)])
def test_matching_blocks_and_ties_same_as_before(n_a: int, n_b: int) -> None:
    """Matches of one block of rows and of several (the candidate columns multiplied again),
    with equal rows on both sides, SIFT-like and binary (ORB) descriptors, with and without the
    cross check: the c52a7fb code's exactly; and the check is not vacuous (the ties and the
    cross check change the matches)."""
    from bimcap.features import MatchOptions, match_descriptors
    from bimcap.features.sift import ORB_DESCRIPTOR_BYTES

    rng = np.random.default_rng(n_a + n_b)
    for width, high in ((128, 40), (ORB_DESCRIPTOR_BYTES, 256)):
        a, b = _noisy_copies(rng, n_a, n_b, width, high)
        for opts in (MatchOptions(), MatchOptions(cross_check=False),
                     MatchOptions(max_ratio=0.95, max_distance=1.0, max_hamming=120)):
            for x, y in ((a, b), (b, a)):
                new = match_descriptors(x, y, opts)
                with ref.old_matching():
                    old = match_descriptors(x, y, opts)
                assert np.array_equal(new, old) and new.dtype == old.dtype
                assert len(new) > min(len(x), len(y)) // 3
        both = match_descriptors(a, b)
        assert 4 not in both[:, 0] and 5 not in both[:, 0]  # the tie in b's direction
        assert 7 not in both[:, 0]  # the tie in a's direction
        assert len(match_descriptors(a, b, MatchOptions(cross_check=False))) > len(both)



@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_matching_real_frames_same_as_before(world: str) -> None:
    """Every pair of a generated world's first 8 frames, window 4 (its SIFT as the front end
    extracts it): the same matches as the c52a7fb code; skipped without the world."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.features import extract_sift, match_descriptors
    from bimcap.frontend.runner import _load_raw_image, get_undistorter
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import sift_options

    seq = read_sequence(seq_dir)
    und = get_undistorter(seq.camera)
    opts = sift_options(RefineConfig())
    desc = [extract_sift(und.image(_load_raw_image(seq, i, seq.camera)), opts).descriptors
            for i in range(8)]
    n = 0
    for i in range(8):
        for j in range(i + 1, min(8, i + 5)):
            new = match_descriptors(desc[i], desc[j])
            with ref.old_matching():
                old = match_descriptors(desc[i], desc[j])
            assert np.array_equal(new, old)
            n += len(new)
    assert n > 2000


def test_matching_real_frames_same_as_float32() -> None:
    """Every pair of a 1032 × 772 world's first 6 frames, window 4 (~1,400–3,300 keypoints, some
    descriptors with values >= 128): the integer products give the matches of the 4206b3e code
    (float32 BLAS) and of ``product = "float32"``; skipped without the world."""
    seq_dir = Path("/tmp/speeddef/w1032/gen-demo-s0/seq_12_standard_1032")
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.features import DescriptorProduct, MatchOptions, extract_sift, match_descriptors
    from bimcap.frontend.runner import _load_raw_image, get_undistorter
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import sift_options

    seq = read_sequence(seq_dir)
    und = get_undistorter(seq.camera)
    opts = sift_options(RefineConfig())
    desc = [extract_sift(und.image(_load_raw_image(seq, i, seq.camera)), opts).descriptors
            for i in range(6)]
    assert min(len(d) for d in desc) > 1000 and all((d >= 128).any() for d in desc)
    n = 0
    f32 = MatchOptions(product=DescriptorProduct.FLOAT32)
    for i in range(6):
        for j in range(i + 1, min(6, i + 5)):
            new = match_descriptors(desc[i], desc[j])
            with ref.float32_matching():
                old = match_descriptors(desc[i], desc[j])
            assert np.array_equal(new, old) and new.dtype == old.dtype
            assert np.array_equal(match_descriptors(desc[i], desc[j], f32), old)
            n += len(new)
    assert n > 3000


def test_int8_products_exact() -> None:
    """The integer products equal numpy's int64 ones: uint8 rows over the whole range (high
    bits on both sides, as the last rows and scattered), all-255 rows (the largest sum,
    128 · 255²) and zero rows; a variant without the high bits' terms differs."""
    from bimcap.features import matching

    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, (300, 128)).astype(np.uint8)
    b = rng.integers(0, 120, (250, 128)).astype(np.uint8)
    b[[3, 17, 200]] = rng.integers(128, 256, (3, 128))
    a[7] = b[7] = 255
    a[8] = b[8] = 0
    for x, y in ((a, b), (b, a), (a[:40], a)):
        want = x.astype(np.int64) @ y.astype(np.int64).T
        order = matching._hi_last(y)
        got = matching._int8_products(matching._Int8Rows(x), matching._Int8Rows(y[order]))
        assert got.dtype == np.int32 and np.array_equal(got, want[:, order])
        scattered = matching._int8_products(matching._Int8Rows(x), matching._Int8Rows(y))
        assert np.array_equal(scattered, want)
    assert want.max() <= 128 * 255 * 255 < 2**24
    order = matching._hi_last(b)
    lo_only = matching._int8_session().run(None, {"a": a & 127,
                                                  "b": np.ascontiguousarray((b[order] & 127).T)
                                                  .view(np.int8)})[0]
    assert not np.array_equal(lo_only, (a.astype(np.int64) @ b[order].astype(np.int64).T))


@pytest.mark.parametrize("case", ["some", "none", "all", "last", "one_row", "empty"])
def test_descriptor_split_same_bytes(case: str) -> None:
    """``_Int8Rows.high_bits_last`` (compiled) gives ``_hi_last``'s order and the arrays of
    ``_Int8Rows(d[order])`` byte for byte, dtypes and shapes included, whether no row, some
    rows (scattered or already last) or every row has a value >= 128."""
    from bimcap.features import matching

    rng = np.random.default_rng(len(case))
    d = rng.integers(0, 128, (301, 128)).astype(np.uint8)
    if case == "some":
        d[rng.choice(301, 40, replace=False), rng.integers(0, 128, 40)] = 200
    elif case == "all":
        d[:, 5] = 128
    elif case == "last":
        d[-7:, 0] = 255
    elif case == "one_row":
        d = d[:1] | np.uint8(128)
    elif case == "empty":
        d = d[:0]
    order, got = matching._Int8Rows.high_bits_last(d)
    want_order = matching._hi_last(d)
    want = matching._Int8Rows(d[want_order])
    assert order.dtype == want_order.dtype and np.array_equal(order, want_order)
    for name in ("d", "lo", "lo_t", "hi", "hi_t"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name
        assert a.flags["C_CONTIGUOUS"], name
    assert isinstance(want.hi_rows, slice) and got.hi_rows == want.hi_rows

def _rootsift_like(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n,) uint8 of norm ~512 (as a RootSIFT descriptor), all below 128."""
    r = rng.integers(1, 40, n).astype(np.float64)
    return np.rint(r * 512.0 / np.linalg.norm(r)).astype(np.uint8)


def test_int8_matching_ties_across_the_row_order() -> None:
    """Rows reordered (those with a high bit last) change which of two equal similarities comes
    first; the matches stay the 4206b3e code's: a row of a whose best two columns tie, one of
    them with a high bit, and a column whose best two rows tie, one of them with a high bit."""
    from bimcap.features import match_descriptors

    rng = np.random.default_rng(5)
    a, b = _noisy_copies(rng, 200, 150, 128, 40)  # RootSIFT-like rows, all below 128
    assert a.max() < 128 and b.max() < 128
    # b[10] (high bit at dimension 100) and b[11] tie on a[0] (zero at dimension 100)
    a[0, :100] = _rootsift_like(rng, 100)
    b[10, :100] = b[11, :100] = a[0, :100]
    b[10, 100:], b[11, 100:] = 0, 0
    b[10, 100] = 200
    a[0, 100:] = 0
    # a[20] (high bit at dimension 120) and a[21] tie on b[30] (zero at dimension 120)
    b[30, :120] = _rootsift_like(rng, 120)
    a[20, :120] = a[21, :120] = b[30, :120]
    a[20, 120:], a[21, 120:] = 0, 0
    a[20, 120] = 250
    b[30, 120:] = 0
    sim = a.astype(np.int64) @ b.astype(np.int64).T
    assert sorted(np.argsort(sim[0])[-2:]) == [10, 11] and sim[0, 10] == sim[0, 11]
    assert sorted(np.argsort(sim[:, 30])[-2:]) == [20, 21] and sim[20, 30] == sim[21, 30]
    for x, y in ((a, b), (b, a)):
        new = match_descriptors(x, y)
        with ref.float32_matching():
            old = match_descriptors(x, y)
        assert np.array_equal(new, old) and len(new) > 50
    both = match_descriptors(a, b)
    assert 0 not in both[:, 0] and 30 not in both[:, 1]


@pytest.mark.parametrize(("rows", "cols"), [(1, 2), (2, 2), (3, 7), (4, 5), (9, 30), (130, 41)])
def test_similarity_top2_same_as_numpy(rows: int, cols: int) -> None:
    """``_core.similarity_top2`` (blocks of four rows and the rest, equal values in rows and
    columns): numpy's first arg-max and top two a row (``_top2``), and each column's two largest
    counted with multiplicity (sorted column), INT32_MIN with one row."""
    from bimcap import _core
    from bimcap.features.matching import _top2

    rng = np.random.default_rng(rows * 100 + cols)
    for high in (3, 2**23):  # many ties, few
        sim = rng.integers(0, high, (rows, cols)).astype(np.int32)
        best, s1, s2, c1, c2 = _core.similarity_top2(sim)
        want = _top2(sim.copy(), -1)
        assert np.array_equal(best, want[0]) and best.dtype == np.int64
        assert np.array_equal(s1, want[1]) and np.array_equal(s2, want[2])
        top = np.sort(sim, axis=0)
        assert np.array_equal(c1, top[-1])
        assert np.array_equal(c2, top[-2] if rows > 1 else np.full(cols, np.iinfo(np.int32).min))


def test_similarity_top2_rejects_bad_arrays() -> None:
    """Wrong dtype, shape or layout: ``_core.InputError`` naming ``sim``."""
    from bimcap import _core

    sim = np.zeros((3, 4), np.int32)
    for bad, text in ((sim.astype(np.float32), "dtype int32"), (sim[:, :1].copy(), "2 columns"),
                      (np.zeros((0, 4), np.int32), "1 row"), (sim.T, "C-contiguous"),
                      (sim.ravel(), "shape (n, n)")):
        with pytest.raises(_core.InputError, match="sim") as err:
            _core.similarity_top2(bad)
        assert err.value.field == "sim" and text in str(err.value)


@pytest.mark.parametrize("one_pass", [True, False])
@pytest.mark.parametrize("blocks", [False, True])
def test_int8_matching_paths_same_as_float32(monkeypatch: pytest.MonkeyPatch, one_pass: bool,
                                             blocks: bool) -> None:
    """The integer products' matches with the one-pass reductions of ``_core`` or numpy's, in
    one block or several (the candidate columns multiplied again): the 4206b3e code's, on
    RootSIFT-like rows with high bits and ties, with and without the cross check."""
    from bimcap.features import MatchOptions, match_descriptors, matching

    if blocks:
        monkeypatch.setattr(matching, "_BLOCK_ELEMENTS", 1)  # blocks of 2,048 rows
    if not one_pass:
        monkeypatch.setattr(matching, "_core_top2", lambda: False)
    rng = np.random.default_rng(11)
    a, b = _noisy_copies(rng, 2600, 1500, 128, 40)
    for d in (a, b):
        hi = rng.choice(len(d), len(d) // 10, replace=False)
        d[hi, rng.integers(0, 128, len(hi))] = rng.integers(128, 256, len(hi))
    for opts in (MatchOptions(), MatchOptions(cross_check=False)):
        for x, y in ((a, b), (b, a)):
            new = match_descriptors(x, y, opts)
            with ref.float32_matching():
                old = match_descriptors(x, y, opts)
            assert np.array_equal(new, old) and new.dtype == old.dtype
            assert len(new) > 500


def test_matching_product_option() -> None:
    """``product`` reads from a ``[matching]`` table; the default stays out of the cache key
    (the same matches as before the option), ``"float32"`` is in it; a bad value names the
    field."""
    from bimcap.features import DescriptorProduct, MatchOptions
    from bimcap.pipeline.config import ConfigError, RefineConfig
    from bimcap.pipeline.refine import match_options

    assert "product" not in MatchOptions().to_dict()
    assert MatchOptions(product=DescriptorProduct.FLOAT32).to_dict()["product"] == "float32"
    opts = match_options(RefineConfig(matching={"product": "float32"}))
    assert opts.product is DescriptorProduct.FLOAT32
    with pytest.raises(ConfigError) as info:
        match_options(RefineConfig(matching={"product": "int4"}))
    assert info.value.field == "matching.product"


def test_int8_model_is_matmul_integer() -> None:
    """The serialized model in ``bimcap.features.matching`` is one ``MatMulInteger`` of a uint8
    (n, 128) by an int8 (128, m) into int32, as ``onnx.helper`` builds it."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from bimcap.features.matching import _MATMUL_INTEGER_ONNX

    model = onnx.load_from_string(_MATMUL_INTEGER_ONNX)
    onnx.checker.check_model(model)
    a = helper.make_tensor_value_info("a", TensorProto.UINT8, ["n", 128])
    b = helper.make_tensor_value_info("b", TensorProto.INT8, [128, "m"])
    y = helper.make_tensor_value_info("y", TensorProto.INT32, ["n", "m"])
    graph = helper.make_graph([helper.make_node("MatMulInteger", ["a", "b"], ["y"])],
                              "descriptor_products", [a, b], [y])
    built = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 10)],
                              producer_name="bimcap")
    built.ir_version = 7
    assert built.SerializeToString() == _MATMUL_INTEGER_ONNX


def test_scan_range_noise_same_as_before() -> None:
    """The range noise of ring scans (ties in azimuth, non-finite and zero rows included): the
    a219de7 code's value exactly (it picks the segmentation's and smoothing's thresholds)."""
    import _geometric_reference as before
    from bimcap.segmentation.geometric import scan_range_noise

    rng = np.random.default_rng(5)
    elev = np.deg2rad(np.arange(-15.0, 16.0, 2.0))
    azim = np.deg2rad(np.round(np.arange(0.0, 360.0, 0.2), 1))
    e, a = (g.ravel() for g in np.meshgrid(elev, azim))
    # a 6 m × 4 m room seen from near its middle: range to the nearest wall along each ray
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1)
    with np.errstate(divide="ignore"):
        t = np.min(np.abs(np.stack([3.2 / d[:, 0], 2.1 / d[:, 1], 1.4 / d[:, 2]], 1)), 1)
    for sigma in (0.01, 0.03, 0.08):
        p = d * (t + rng.normal(0.0, sigma, len(t)))[:, None]
        p = np.concatenate([p, p[:50], np.full((3, 3), np.nan), np.zeros((2, 3))])  # ties
        p = p[rng.permutation(len(p))].astype(np.float32)
        new = scan_range_noise(p)
        assert new is not None and new == before.scan_range_noise(p)
        assert 0.5 * sigma < new < 2.0 * sigma
        # in the sensor's order (each ring by azimuth, as scans come), other bins and steps,
        # rings narrower than the returns are many (one sort), too few triples
        in_order = d * (t + rng.normal(0.0, sigma, len(t)))[:, None]
        for q in (p, in_order):
            for ring_bin, step in ((0.5, 0.5), (0.25, 0.3), (1.5, 1.0), (1e-7, 0.5), (2.0, 0.01)):
                assert scan_range_noise(q, ring_bin, step) == before.scan_range_noise(
                    q, ring_bin, step), (ring_bin, step)
    from bimcap.segmentation import SegmentationInputError

    with pytest.raises(SegmentationInputError, match="ring_bin_deg"):
        scan_range_noise(p, 0.0)


# ------------------------------------------------------------- the completion's raster in C++
def _random_triangles(rng: np.random.Generator, n: int, h: int, w: int) -> np.ndarray:
    """(n, 3, 2) float64 triangle corners in px of an (h, w) image, of every kind the Delaunay
    triangles of a frame have and more: small ones, large ones across the image, touching the
    border (corners on the half-pixel edge of the image), partly and wholly outside, slivers and
    collinear corners, corners on half pixels (ties of the 4-bit rounding)."""
    kinds = rng.integers(0, 7, n)
    centre = rng.uniform(-0.5, [w - 0.5, h - 0.5], (n, 1, 2))
    tri = centre + rng.normal(0, 4, (n, 3, 2))  # 0: a few px across, the frames' kind
    tri[kinds == 6] = rng.uniform(-0.5, [w - 0.5, h - 0.5], (n, 3, 2))[kinds == 6]  # large
    big = rng.uniform(-0.3 * w, 1.3 * w, (n, 3, 2))
    big[:, :, 1] = rng.uniform(-0.3 * h, 1.3 * h, (n, 3))
    tri[kinds == 1] = big[kinds == 1]  # partly or wholly outside
    edge = tri[:, :1] + rng.normal(0, 8, (n, 1, 2)) * np.array([[[0.0], [1.0], [1.0]]])
    edge[:, 2] = edge[:, 0] + (edge[:, 1] - edge[:, 0]) * rng.uniform(0, 1, (n, 1))
    sliver = edge + rng.normal(0, 0.05, (n, 3, 2))
    tri[kinds == 2] = sliver[kinds == 2]  # slivers
    tri[kinds == 3] = edge[kinds == 3]  # collinear (zero area)
    border = tri.copy()  # one or two corners on the image's border
    border[:, 0, 0] = -0.5
    border[:, 1, 1] = rng.choice([-0.5, h - 0.5], n)
    tri[kinds == 4] = border[kinds == 4]
    half = np.round(tri * 2) / 2 + rng.choice([0.0, 1 / 32], (n, 3, 2))  # 4-bit ties
    tri[kinds == 5] = half[kinds == 5]
    return tri


def _fixed_point(tri: np.ndarray, shift: int = 4) -> np.ndarray:
    return np.rint(tri * (1 << shift)).astype(np.int32)


@pytest.mark.parametrize(("h", "w"), [(386, 516), (31, 17), (1, 1), (2, 5)])
def test_triangle_ids_same_as_opencv(h: int, w: int) -> None:
    """``_core.fill_triangle_ids`` against one cv2.fillConvexPoly call a triangle (the code of
    ec113ba): the same pixels, bit for bit, for thousands of overlapping triangles of every
    kind (later ones overwrite shared pixels), at shift 4 and at other shifts."""
    from bimcap import _core

    rng = np.random.default_rng(h * 1000 + w)
    n = 4000 if h > 100 else 600
    tri = _random_triangles(rng, n, h, w)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    tri = tri[np.argsort(-np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]))]  # large first
    corners = _fixed_point(tri)
    ids = rng.permutation(n).astype(np.int32) + 1
    new = _core.fill_triangle_ids(corners, ids, h, w)
    old = ref.triangle_ids_opencv(corners, ids, h, w)
    assert new.dtype == np.int32 and new.shape == (h, w)
    assert np.array_equal(new, old)
    if h > 100:
        assert len(np.unique(new)) > 0.2 * n  # the check saw many triangles, not a few
    for shift in (1, 2, 8, 16):
        c = _fixed_point(np.clip(tri[:200], -5000, 5000), shift)
        assert np.array_equal(_core.fill_triangle_ids(c, ids[:200], h, w, shift=shift),
                              ref.triangle_ids_opencv(c, ids[:200], h, w, shift))


def _pixel_centre_ids(corners: np.ndarray, ids: np.ndarray, h: int, w: int) -> np.ndarray:
    """A plausible other rule: a pixel takes a triangle's id when its centre lies inside or on
    the triangle (barycentric test), later triangles overwriting."""
    out = np.zeros((h, w), np.int32)
    for c, k in zip(corners / 16.0, ids, strict=True):
        lo = np.clip(np.ceil(c.min(0)).astype(int), 0, [w, h])
        hi = np.clip(np.floor(c.max(0)).astype(int) + 1, 0, [w, h])
        vv, uu = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
        (x0, y0), (x1, y1), (x2, y2) = c
        d = [(x1 - x0) * (vv - y0) - (y1 - y0) * (uu - x0),
             (x2 - x1) * (vv - y1) - (y2 - y1) * (uu - x1),
             (x0 - x2) * (vv - y2) - (y0 - y2) * (uu - x2)]
        inside = ((d[0] >= 0) & (d[1] >= 0) & (d[2] >= 0)) | ((d[0] <= 0) & (d[1] <= 0)
                                                             & (d[2] <= 0))
        out[lo[1]:hi[1], lo[0]:hi[0]][inside] = k
    return out


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_triangle_ids_real_frames_same_as_opencv(world: str) -> None:
    """Every Delaunay triangle of the LiDAR returns of 10 frames of a generated world (also the
    long, the bridging and the sliver ones that the completion drops), in Delaunay's order:
    the same ids as OpenCV's; a pixel-centre rule, which a generic rasteriser would follow,
    differs (so the comparison can fail); skipped without the world."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from scipy.spatial import Delaunay

    from bimcap import _core
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider

    seq = read_sequence(seq_dir)
    projection = LidarDepthProvider().projection
    h, w = seq.camera.height, seq.camera.width
    for i in range(0, 60, 6):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        simp = Delaunay(sparse.uv).simplices
        corners = _fixed_point(sparse.uv[simp])
        ids = np.arange(1, len(simp) + 1, dtype=np.int32)
        new = _core.fill_triangle_ids(corners, ids, h, w)
        assert np.array_equal(new, ref.triangle_ids_opencv(corners, ids, h, w))
        assert (new > 0).mean() > 0.5
        if i == 0:
            assert not np.array_equal(new, _pixel_centre_ids(corners, ids, h, w))


def test_piecewise_affine_same_as_numpy() -> None:
    """``_core.evaluate_piecewise_affine`` against ec113ba's numpy (gathers, ``f *= u``,
    ``f += c1 v``, ``f += c2``, then 1/f or f): the same float32 bits, on coefficients of real
    magnitudes and of extreme ones (f ≤ 0, f below 1e-12, overflow to inf, NaN)."""
    from bimcap import _core

    rng = np.random.default_rng(3)
    h, w, n = 97, 131, 500
    coef = np.zeros((3, n + 1))
    coef[0, 1:] = rng.normal(0, 1e-3, n)  # 1/z slopes per px of a 516-px image
    coef[1, 1:] = rng.normal(0, 1e-3, n)
    coef[2, 1:] = rng.uniform(-0.05, 1.0, n)
    coef[:, 1:40] *= rng.choice([1e-300, 1e-13, 1e300, -1.0, 0.0], (3, 39))
    coef[2, 40:45] = np.nan
    coef[:, 45] = -0.0
    tri_id = rng.integers(0, n + 1, (h, w)).astype(np.int32)
    for inverse in (True, False):
        new = _core.evaluate_piecewise_affine(tri_id, coef, inverse)
        with np.errstate(all="ignore"):
            old = ref.piecewise_affine_numpy(tri_id, coef, inverse)
        assert new.dtype == np.float32 and new.shape == (h, w)
        assert new.tobytes() == old.tobytes()
    # f = c0 · u + c1 · v at a float32 tie (1 + 2⁻²⁴): numpy rounds both products first and
    # gets 1.0; a fused multiply-add (either product kept exact) would give 1.0000001
    ties = [(-0.004808793512333502, 0.008843887274834851, 467, 367),
            (-0.005731758197324269, 0.009116805383667964, 422, 375),
            (-0.09414626308327533, 0.009121171692512708, 26, 378)]
    tri_id = np.zeros((400, 500), np.int32)
    coef = np.zeros((3, len(ties) + 1))
    for k, (c0, c1, u, v) in enumerate(ties, start=1):
        tri_id[v, u] = k
        coef[:2, k] = c0, c1
    new = _core.evaluate_piecewise_affine(tri_id, coef, False)
    assert new.tobytes() == ref.piecewise_affine_numpy(tri_id, coef, False).tobytes()
    assert (new[[t[3] for t in ties], [t[2] for t in ties]] == 1.0).all()


def test_raster_rejects_bad_arrays() -> None:
    """Wrong dtypes, shapes, layouts, shifts and ids raise ``_core.InputError`` (a ValueError)
    naming the argument; the process goes on."""
    from bimcap import _core

    c = np.zeros((2, 3, 2), np.int32)
    k = np.ones(2, np.int32)
    bad_fill = [
        ({"corners": c.astype(np.float64)}, "corners", "dtype int32"),
        ({"corners": c.reshape(2, 6)}, "corners", "shape (n, 3, 2)"),
        ({"corners": np.zeros((2, 2, 3), np.int32).transpose(0, 2, 1)}, "corners",
         "C-contiguous"),
        ({"corners": [[[0, 0], [1, 0], [0, 1]]]}, "corners", "numpy array"),
        ({"ids": np.ones(3, np.int32)}, "ids", "shape (2,)"),
        ({"ids": np.ones(2, np.int64)}, "ids", "dtype int32"),
        ({"shift": 0}, "shift", "[1, 16]"),
        ({"shift": 17}, "shift", "[1, 16]"),
        ({"height": -1}, "height", "[0, 16384]"),
        ({"width": 20000}, "width", "[0, 16384]"),
        ({"corners": np.array([[[0, 0], [16, 0], [0, 16]], [[0, 0], [16, 0], [0, 16385 * 16]]],
                              np.int32)}, "corners", "triangle 1 has a coordinate 262160"),
    ]
    for override, field, text in bad_fill:
        args = {"corners": c, "ids": k, "height": 4, "width": 5} | override
        with pytest.raises(_core.InputError, match=field) as err:
            _core.fill_triangle_ids(**args)
        assert err.value.field == field and text in str(err.value)
    ids = np.zeros((4, 5), np.int32)
    coef = np.zeros((3, 2))
    bad_eval = [
        ({"tri_id": ids.astype(np.int64)}, "tri_id", "dtype int32"),
        ({"tri_id": ids[:, ::2]}, "tri_id", "C-contiguous"),
        ({"tri_id": np.full((4, 5), 2, np.int32)}, "tri_id", "outside [0, 2)"),
        ({"tri_id": np.full((4, 5), -1, np.int32)}, "tri_id", "outside [0, 2)"),
        ({"coef": np.zeros((2, 2))}, "coef", "shape (3, n)"),
        ({"coef": np.zeros((3, 0))}, "coef", "column 0"),
        ({"coef": np.zeros((3, 2), np.float32)}, "coef", "dtype float64"),
    ]
    for override, field, text in bad_eval:
        args = {"tri_id": ids, "coef": coef, "inverse_depth": True} | override
        with pytest.raises(_core.InputError, match=field) as err:
            _core.evaluate_piecewise_affine(**args)
        assert err.value.field == field and text in str(err.value)
    # empty inputs are fine
    assert _core.fill_triangle_ids(np.zeros((0, 3, 2), np.int32), np.zeros(0, np.int32),
                                   0, 3).shape == (0, 3)
    assert _core.evaluate_piecewise_affine(np.zeros((0, 3), np.int32), coef, False).shape == (0, 3)


# ------------------------------------------------------------- fe-exact (2026-11-27, 02ca12e →)
@pytest.mark.parametrize("n", [1, 2, 3, 511, 512, 513, 514, 1025, 3000])
@pytest.mark.parametrize("hypotheses", [1, 2, 7, 150])
def test_plane_scores_same_as_02ca12e(n: int, hypotheses: int) -> None:
    """The RANSAC scores with their products, tests and counts in ``_core.add_plane_scores``
    (the products rounded as numpy's matrix products: fused multiply-adds): 02ca12e's numpy
    counts, with points at exactly the threshold (``<`` is strict), NaN points and normals,
    zero thresholds and a normal agreement exactly at ``cos_n``, for every block remainder."""
    from bimcap.segmentation.geometric import _plane_scores

    rng = np.random.default_rng(7 * n + hypotheses)
    pts = rng.normal(size=(n, 3)) * 3.0
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    hn = rng.normal(size=(hypotheses, 3))
    hn /= np.linalg.norm(hn, axis=1, keepdims=True)
    d = rng.normal(size=hypotheses)
    d[0] = -0.0
    thr = (0.5 + 0.01 * np.abs(pts[:, 2]))[:, None]
    # ties: a third of the points exactly at the threshold of hypothesis 0 (the same product as
    # the table's: a one-hypothesis column is the whole table's column, see _plane_scores)
    tie = np.arange(0, n, 3)
    thr[tie, 0] = np.abs((pts @ hn.T + d)[tie, 0])
    thr[1::7] = 0.0
    pts[2::11] = np.nan
    nrm[5::13] = np.nan
    cos_n = float(np.abs(nrm[0] @ hn[0]))  # point 0 agrees with hypothesis 0 exactly at cos_n
    for sub_n, c in ((None, 0.0), (nrm, 0.5), (nrm, cos_n)):
        new = _plane_scores(pts, hn, d, thr, sub_n, c)
        old = ref.plane_scores_02ca12e(pts, hn, d, thr, sub_n, c)
        assert new.dtype == np.int64 and np.array_equal(new, old)
    assert n < 500 or old.sum() > 0
    # the smoothing's RANSAC counts (the same compiled pass, one scalar threshold) at a tie
    from bimcap.fusion.completion import _inlier_counts

    at = float(np.abs(pts[0] @ hn[0] + d[0]))
    for threshold in (at, 0.5):
        assert np.array_equal(_inlier_counts(pts, hn, d, threshold),
                              (np.abs(pts @ hn.T + d) < threshold).sum(0))


def test_plane_scores_reject_bad_arrays() -> None:
    """Wrong dtypes, shapes, layouts and a read-only score raise ``_core.InputError`` naming the
    argument, and leave the scores as they were."""
    from bimcap import _core

    p = np.zeros((5, 3))
    good = {"score": np.zeros(3, np.int64), "points": p, "normals": p,
            "planes": np.zeros((3, 3)), "offsets": np.zeros(3), "thresholds": np.ones(5),
            "cos_n": 0.5}
    read_only = np.zeros(3, np.int64)
    read_only.flags.writeable = False
    for override, field, text in [
        ({"score": np.zeros(3, np.int32)}, "score", "dtype int64"),
        ({"score": read_only}, "score", "read-only"),
        ({"points": p.astype(np.float32)}, "points", "dtype float64"),
        ({"points": p[:, :2]}, "points", "shape (n, 3)"),
        ({"points": np.zeros((5, 6))[:, ::2]}, "points", "C-contiguous"),
        ({"normals": p[:4]}, "normals", "shape (5, 3)"),
        ({"planes": np.zeros((2, 3))}, "planes", "shape (3, 3)"),
        ({"offsets": np.zeros(4)}, "offsets", "shape (3,)"),
        ({"thresholds": np.ones((5, 1))}, "thresholds", "shape (5,)"),
    ]:
        args = good | override
        with pytest.raises(_core.InputError, match=field) as err:
            _core.add_plane_scores(**args)
        assert err.value.field == field and text in str(err.value)
        assert not args["score"].any()
    _core.add_plane_scores(**good)  # |0 + 0| < 1, but |0| > 0.5 is false
    assert np.array_equal(good["score"], [0, 0, 0])
    _core.add_plane_scores(**(good | {"normals": None}))
    assert np.array_equal(good["score"], [5, 5, 5])


def _orientation_inputs(world: str, count: int
                        ) -> list[tuple[np.ndarray, np.ndarray, Camera, np.ndarray]]:
    """``(labels, depth, pinhole camera, world_from_cam)`` of a generated world's first
    ``count`` frames as the front end hands them to the label orientation check (``refine``'s
    providers: linear completion, geometric labels, planar smoothing); [] without the world."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        return []
    out = []
    for ctx, labels, refiner in _provider_frames(seq_dir, count):
        depth = refiner(ctx, labels)
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        out.append((labels, depth, ctx.pinhole, ctx.world_from_cam))
    return out


def test_label_orientation_same_as_02ca12e(chain: list[_Frame]) -> None:
    """The label orientation check (coarse normals through ``_core``, each normal-equation sum
    once): 02ca12e's labels and counts bit for bit on the box-room frames, with the check's
    working width and tolerances varied, and on 6 frames each of two generated worlds (skipped
    without them); regions and pixels are dropped on the way."""
    from bimcap.frontend.semantic_map import SemanticSamplingOptions, check_label_orientation

    inputs = [(f.labels, f.smoothed, f.camera, f.world_from_cam) for f in chain]
    for world in ("gen-demo-s0", "ifc-SampleHouse4"):
        inputs += _orientation_inputs(world, 6)
    option_sets = [SemanticSamplingOptions(), SemanticSamplingOptions(orientation_work_width=516),
                   SemanticSamplingOptions(orientation_work_width=97, orientation_check_deg=10.0,
                                           orientation_strict_deg=20.0)]
    dropped = 0
    for labels, depth, camera, pose in inputs:
        for opts in option_sets:
            new, new_stats = check_label_orientation(labels, depth, camera, pose, opts)
            with ref.old_label_orientation():
                old, old_stats = check_label_orientation(labels, depth, camera, pose, opts)
            assert new.dtype == old.dtype and new.tobytes() == old.tobytes()
            assert new_stats == old_stats
            dropped += new_stats["dropped_pixels"]
    assert dropped > 0


def test_region_plane_sums_same_as_bincount() -> None:
    """The label check's normal equations in compiled code: np.bincount's sums (02ca12e) bytes
    equal, on random regions with holes, depths across five orders of magnitude, regions with
    no valid pixel; bad input raises."""
    from bimcap import _core

    rng = np.random.default_rng(3)
    for h, w, n_comp in ((1, 1, 1), (7, 5, 3), (97, 129, 40), (193, 258, 200)):
        comp = rng.integers(0, n_comp, (h, w)).astype(np.int32)
        valid = (rng.random((h, w)) < 0.8) & (comp > 0)
        depth = (10.0 ** rng.uniform(-2, 3, (h, w))).astype(np.float32)
        cam = Camera(w, h, 311.3, 297.1, 0.47 * w, 0.52 * h)
        count, ata, atb = _core.region_plane_sums(comp, valid, depth, cam.fx, cam.fy, cam.cx,
                                                  cam.cy, n_comp)
        # 02ca12e's numpy
        ids = comp[valid]
        v, u = np.nonzero(valid)
        x = (u - cam.cx) / cam.fx
        y = (v - cam.cy) / cam.fy
        wt = 1.0 / depth[valid].astype(np.float64)
        want_count = np.bincount(ids, minlength=n_comp)
        want_ata = np.zeros((n_comp, 3, 3))
        want_atb = np.zeros((n_comp, 3))
        cols = (x, y)
        for r in range(2):
            want_atb[:, r] = np.bincount(ids, cols[r] * wt, minlength=n_comp)
            want_ata[:, r, 2] = want_ata[:, 2, r] = np.bincount(ids, cols[r], minlength=n_comp)
            for c in range(r, 2):
                want_ata[:, r, c] = want_ata[:, c, r] = np.bincount(ids, cols[r] * cols[c],
                                                                    minlength=n_comp)
        want_atb[:, 2] = np.bincount(ids, wt, minlength=n_comp)
        want_ata[:, 2, 2] = want_count
        assert np.array_equal(count, want_count)
        assert ata.tobytes() == want_ata.tobytes() and atb.tobytes() == want_atb.tobytes()
    with pytest.raises(_core.InputError, match="comp"):
        _core.region_plane_sums(np.full((2, 2), 5, np.int32), np.ones((2, 2), bool),
                                np.ones((2, 2), np.float32), 1.0, 1.0, 0.0, 0.0, 3)
    with pytest.raises(_core.InputError, match="valid"):
        _core.region_plane_sums(np.zeros((2, 2), np.int32), np.ones((2, 3), bool),
                                np.ones((2, 2), np.float32), 1.0, 1.0, 0.0, 0.0, 3)


def test_coarse_normals_same_as_02ca12e(chain: list[_Frame]) -> None:
    """The check's coarse normals: where defined, the same mask and ``|n · up|`` (all the check
    reads) as 02ca12e's numpy, for every up; now 0 where undefined and facing the camera."""
    from bimcap.frontend.semantic_map import _coarse_normals

    rng = np.random.default_rng(11)
    for f in chain:
        for step, box in ((4, 11), (2, 5), (1, 1)):
            n_new, ok_new = _coarse_normals(f.dense, f.camera, step, box)
            n_old, ok_old = ref.coarse_normals_02ca12e(f.dense, f.camera, step, box)
            assert np.array_equal(ok_new, ok_old) and ok_new.any()
            for up in [np.array([0.0, -1.0, 0.0]), *rng.normal(size=(3, 3))]:
                assert np.abs(n_new @ up)[ok_new].tobytes() == np.abs(n_old @ up)[ok_old].tobytes()
            assert not n_new[~ok_new].any()


def test_depth_jump_offset() -> None:
    """``points_and_cross``'s depth jump test: |Δz| < 2 (0.05 z + jump_offset_m), the segmenter's
    0.05 by default, the orientation check's 0.1."""
    from bimcap import _core

    depth = np.full((3, 5), 2.0, np.float32)
    depth[:, 3] = 2.0 + 0.35  # |z(u+1) − z(u−1)| at u = 2: 0.35; 2 (0.1 + 0.05) = 0.3 < 0.35
    _, _, ok_seg, _ = _core.points_and_cross(depth, 1.0, 1.0, 0.0, 0.0, 1, False)
    _, _, ok_chk, _ = _core.points_and_cross(depth, 1.0, 1.0, 0.0, 0.0, 1, False,
                                             jump_offset_m=0.1)
    assert not ok_seg[1, 2] and ok_chk[1, 2]  # 2 (0.1 + 0.1) = 0.4 > 0.35
    assert ok_seg[1, 1] and ok_chk[1, 1]  # no jump around u = 1


def test_one_thread_makes_its_controller_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``one_thread`` limits BLAS to one thread through one ``ThreadpoolController`` a process
    (made again only after an import), and restores the libraries' threads after the block."""
    import sys

    from threadpoolctl import threadpool_info

    from bimcap.frontend import runner

    with runner.one_thread():
        first = runner._THREADPOOLS
        assert all(lib["num_threads"] == 1 for lib in threadpool_info())
    with runner.one_thread():
        assert runner._THREADPOOLS is first
    monkeypatch.setitem(sys.modules, "_an_imported_module", sys)
    with runner.one_thread():
        assert runner._THREADPOOLS is not first and runner._THREADPOOLS is not None
    before = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info()}
    with runner.one_thread():
        pass
    assert {lib["filepath"]: lib["num_threads"] for lib in threadpool_info()} == before


def test_gray_compiled_same_as_numpy() -> None:
    """SIFT's grey levels from ``_core.rgb_to_gray`` against 882f965's numpy expression, bytes
    equal, on every one of the 2²⁴ RGB colours (each rounding case of rint, halves included) and
    on a non-contiguous view; wrong dtypes and shapes raise ``_core.InputError`` naming the
    image; grey input passes through."""
    from bimcap import _core
    from bimcap.features.sift import to_gray_u8

    levels = np.arange(256, dtype=np.uint8)
    every = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(4096, 4096, 3)
    new = to_gray_u8(every)
    assert new.dtype == np.uint8 and new.shape == (4096, 4096)
    assert new.tobytes() == ref.to_gray_u8_882f965(every).tobytes()
    view = every[::7, ::3]
    assert to_gray_u8(view).tobytes() == ref.to_gray_u8_882f965(view).tobytes()
    grey = levels.reshape(16, 16)
    assert np.array_equal(to_gray_u8(grey), grey)
    for bad, text in [(every[:4, :4].astype(np.int32), "dtype uint8"),
                      (every[:4, :4, :2].copy(), "shape (n, n, 3)"),
                      (every[:4, ::2], "C-contiguous")]:
        with pytest.raises(_core.InputError, match="image") as err:
            _core.rgb_to_gray(bad)
        assert err.value.field == "image" and text in str(err.value)


def test_cross_rows_same_as_np_cross() -> None:
    """The RANSACs' row-wise cross products: np.cross's bytes, for one row and many, with
    signed zeros, huge, tiny, infinite and NaN entries."""
    from bimcap.geometry.vectors import cross_rows

    rng = np.random.default_rng(4)
    for n in (1, 2, 150, 3000):
        a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        a[::7] *= 1e300
        b[::11] *= 1e-300
        a[::13, 1] = -0.0
        b[::17, 2] = np.inf
        a[::19, 0] = np.nan
        with np.errstate(all="ignore"):
            assert cross_rows(a, b).tobytes() == np.cross(a, b).tobytes()


def test_median_same_as_np_median() -> None:
    """The smoothing's median: np.median's value bit for bit for odd and even lengths, one and
    two values, ties, NaN anywhere, infinities; NaN when empty."""
    from bimcap.fusion.completion import _median

    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 4, 5, 100, 101, 4000, 4001):
        for kind in range(4):
            a = rng.normal(size=n) * 10.0 ** rng.uniform(-3, 3, n)
            if kind == 1:
                a = np.round(a)  # ties
            elif kind == 2:
                a[rng.integers(0, n)] = np.nan
            elif kind == 3:
                a[rng.integers(0, n)] = np.inf
            got, want = _median(a), float(np.median(a))
            assert (np.isnan(got) and np.isnan(want)) or got.hex() == want.hex(), (n, kind)
    assert np.isnan(_median(np.zeros(0)))
