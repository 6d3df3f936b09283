"""The linear completion's compiled Delaunay triangulation (``bimcap._core.delaunay_triangles``,
cpp/bimcap/raster/delaunay.h): a valid Delaunay triangulation, the triangles of
``scipy.spatial.Delaunay`` (Qhull) where the points are in general position (random points,
every third frame of two generated worlds' LiDAR, skipped without them), clear errors, and the
completion it gives beside Qhull's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from bimcap import _core
from bimcap.fusion import (
    FusionInputError,
    LinearOptions,
    PixelOwner,
    Triangulation,
    complete_linear,
    project_lidar,
)

_WORLDS = Path("/tmp/gen")
#: the triangles drawn thinnest first, the last drawn owning shared pixels (the sweep's option
#: before PixelOwner)
SWEEP = LinearOptions(triangulation=Triangulation.SWEEP, pixel_owner=PixelOwner.LAST_DRAWN)
QHULL = LinearOptions(triangulation=Triangulation.QHULL, pixel_owner=PixelOwner.LAST_DRAWN)
CENTRE_QHULL = LinearOptions(triangulation=Triangulation.QHULL, pixel_owner=PixelOwner.CENTRE)
CENTRE_SWEEP = LinearOptions(triangulation=Triangulation.SWEEP, pixel_owner=PixelOwner.CENTRE)


def _triangle_set(simplices: np.ndarray) -> set[tuple[int, ...]]:
    return set(map(tuple, np.sort(np.asarray(simplices), axis=1).tolist()))


def _check_delaunay(points: np.ndarray, tri: np.ndarray) -> None:
    """Counter-clockwise triangles that tile the convex hull with no point strictly inside any
    circumcircle (up to rounding)."""
    assert tri.dtype == np.int32 and tri.ndim == 2 and tri.shape[1] == 3
    p = points[tri]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert (cross > 0).all()
    assert np.isclose(cross.sum() / 2, ConvexHull(points).volume, rtol=1e-9)
    if len(points) <= 400:  # every point against every circumcircle
        for a, b, c in p:
            d = points - c
            ad, bd = a - c, b - c
            m = np.stack([np.full(len(d), ad[0]) - d[:, 0], np.full(len(d), ad[1]) - d[:, 1],
                          (ad[0] - d[:, 0]) ** 2 + (ad[1] - d[:, 1]) ** 2], 1)
            n = np.stack([np.full(len(d), bd[0]) - d[:, 0], np.full(len(d), bd[1]) - d[:, 1],
                          (bd[0] - d[:, 0]) ** 2 + (bd[1] - d[:, 1]) ** 2], 1)
            o = np.stack([-d[:, 0], -d[:, 1], d[:, 0] ** 2 + d[:, 1] ** 2], 1)
            det = np.linalg.det(np.stack([m, n, o], 1))
            scale = np.abs(m).max() * np.abs(n).max() * np.abs(o).max() + 1e-300
            assert (det / scale < 1e-9).all()


@pytest.mark.parametrize("n", [3, 4, 5, 10, 100, 400, 3000])
def test_same_triangles_as_qhull_on_random_points(n: int) -> None:
    rng = np.random.default_rng(n)
    for scale in (1.0, 516.0, 1e4):
        pts = rng.random((n, 2)) * scale + rng.normal(0, scale, 2)
        tri = _core.delaunay_triangles(pts)
        _check_delaunay(pts, tri)
        assert _triangle_set(tri) == _triangle_set(Delaunay(pts).simplices)


def test_degenerate_inputs_give_a_valid_triangulation() -> None:
    """A grid (four points on every circle, so no unique answer), points on a hull edge,
    repeated points (used once) and a cluster far from the rest."""
    g = np.stack(np.meshgrid(np.arange(12.0), np.arange(9.0)), -1).reshape(-1, 2)
    _check_delaunay(g, _core.delaunay_triangles(g))
    rng = np.random.default_rng(1)
    edge = np.concatenate([rng.random((200, 2)) * 10, np.stack([np.linspace(0, 10, 11),
                                                                 np.full(11, -1.0)], 1)])
    _check_delaunay(edge, _core.delaunay_triangles(edge))
    pts = rng.random((300, 2)) * 50
    rep = np.concatenate([pts, pts[:40], pts[:3]])
    tri = _core.delaunay_triangles(rep)
    assert _triangle_set(np.where(tri >= 300, tri % 300, tri)) == _triangle_set(
        _core.delaunay_triangles(pts))
    far = np.concatenate([pts, pts[:50] * 1e-3 + 1e5])
    _check_delaunay(far, _core.delaunay_triangles(far))


def test_bad_points_are_clear_errors() -> None:
    for pts, words in ((np.zeros((2, 2)), "at least 3"),
                       (np.array([[0.0, 0], [1, 1], [2, 2], [3, 3]]), "one line"),
                       (np.ones((5, 2)), "one line"),
                       (np.array([[0.0, 0], [1, 0], [0, np.nan]]), "not finite"),
                       (np.zeros((4, 3)), "shape"),
                       (np.zeros((4, 2), np.float32), "float64"),
                       (np.zeros((2, 4))[:, ::2].T.copy(order="F"), "contiguous")):
        with pytest.raises(_core.InputError, match=words):
            _core.delaunay_triangles(pts)
    # the completion reports such returns as the sparse depth's fault
    line = np.zeros((40, 60), np.float32)
    line[10, 5:50] = 3.0
    for triangulation in Triangulation:
        with pytest.raises(FusionInputError) as err:
            complete_linear(line, LinearOptions(triangulation=triangulation))
        assert err.value.field == "sparse_depth"
    with pytest.raises(FusionInputError):
        LinearOptions(triangulation="fast")  # type: ignore[arg-type]
    assert LinearOptions(triangulation="qhull").triangulation is Triangulation.QHULL  # type: ignore[arg-type]


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_same_triangles_as_qhull_on_real_frames(world: str) -> None:
    """Every third frame's projected returns: Qhull's triangles, every one; the completion has
    the same support (pixels with depth) and, where the order of triangles sharing edge pixels
    differs, close depths (most pixels equal)."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider

    seq = read_sequence(seq_dir)
    projection = LidarDepthProvider().projection
    for i in range(0, len(seq.frames), 3):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        tri = _core.delaunay_triangles(np.ascontiguousarray(sparse.uv))
        assert _triangle_set(tri) == _triangle_set(Delaunay(sparse.uv).simplices), i
        sweep = complete_linear(sparse, SWEEP)
        qhull = complete_linear(sparse, QHULL)
        assert np.array_equal(sweep > 0, qhull > 0)
        assert (sweep == qhull).mean() > 0.5
        both = sweep > 0
        assert np.median(np.abs(sweep[both] - qhull[both])) < 1e-3


def _real_world(world: str) -> tuple[Any, Any, Any]:
    """(sequence, projection options, undistorter) of a simulated world's standard sequence in
    /tmp/gen (skips when it was not generated)."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider
    from bimcap.frontend.runner import get_undistorter

    seq = read_sequence(seq_dir)
    return seq, LidarDepthProvider().projection, get_undistorter(seq.camera)


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_completion_draws_the_fattest_triangles_last(world: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The triangles' order from the triangulator does not matter (they are drawn by their least
    altitude: reversing or shuffling its list gives the same map, the rotation of each
    triangle's corners too), and against the simulator's ground truth the depth is no worse
    than with Qhull's order, on average and at the 99th percentile."""
    seq, projection, und = _real_world(world)
    rng = np.random.default_rng(2)
    real = _core.delaunay_triangles
    errors: dict[str, list[np.ndarray]] = {"sweep": [], "qhull": []}
    for i in range(0, len(seq.frames), 6):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        sweep = complete_linear(sparse, SWEEP)
        for shuffle in (lambda t: t[::-1], lambda t: t[rng.permutation(len(t))],
                        lambda t: np.roll(t, 1, axis=1)):
            monkeypatch.setattr(_core, "delaunay_triangles",
                                lambda pts, s=shuffle: np.ascontiguousarray(s(real(pts))))
            other = complete_linear(sparse, SWEEP)
            monkeypatch.setattr(_core, "delaunay_triangles", real)
            assert np.array_equal(other > 0, sweep > 0)
            assert (np.abs(other - sweep) <= 1e-6 * sweep).all()
        qhull = complete_linear(sparse, QHULL)
        truth = und.nearest(np.asarray(seq.load_depth(i), np.float32))
        both = (truth > 0) & (sweep > 0)
        errors["sweep"].append(np.abs(sweep[both] - truth[both]))
        errors["qhull"].append(np.abs(qhull[both] - truth[both]))
    sweep_err, qhull_err = (np.concatenate(errors[k]) for k in ("sweep", "qhull"))
    assert sweep_err.mean() <= qhull_err.mean()
    assert np.percentile(sweep_err, 99) <= np.percentile(qhull_err, 99)


def _edge_distance_px(points: np.ndarray, simplices: np.ndarray, owner: np.ndarray,
                      centres: np.ndarray) -> np.ndarray:
    """(P,) distance in px of each centre to the nearest edge line of its owner triangle."""
    tri = points[simplices[owner]]  # (P, 3, 2)
    out = np.full(len(centres), np.inf)
    for e in range(3):
        a, b = tri[:, e], tri[:, (e + 1) % 3]
        d = b - a
        cross = d[:, 0] * (centres[:, 1] - a[:, 1]) - d[:, 1] * (centres[:, 0] - a[:, 0])
        out = np.minimum(out, np.abs(cross) / np.linalg.norm(d, axis=1))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_centre_pass_gives_the_containing_triangle_in_any_order(seed: int) -> None:
    """fill_triangle_ids(..., centres=True): every pixel whose centre lies clearly inside a
    triangle (1/8 px from its edges: the corners are rounded to 1/16 px) gets that triangle
    (scipy's find_simplex), whatever the triangles' order; orders differ only at pixels no
    triangle contains (the outlines' half pixel outside the hull)."""
    rng = np.random.default_rng(seed)
    h, w = 90, 120
    pts = rng.uniform([-3, -3], [w + 2, h + 2], size=(700, 2))
    d = Delaunay(pts)
    simp = np.ascontiguousarray(d.simplices, dtype=np.int32)
    corners = np.ascontiguousarray(np.round(pts[simp] * 16), dtype=np.int32)
    ids = np.arange(1, len(simp) + 1, dtype=np.int32)
    vv, uu = np.mgrid[0:h, 0:w]
    centres = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
    owner = d.find_simplex(centres)
    inside = owner >= 0
    clear = np.zeros(len(centres), bool)
    clear[inside] = _edge_distance_px(pts, simp, owner[inside], centres[inside]) > 0.125
    maps = []
    for order in (np.arange(len(simp)), np.arange(len(simp))[::-1], rng.permutation(len(simp))):
        m = _core.fill_triangle_ids(np.ascontiguousarray(corners[order]), ids[order], h, w,
                                    shift=4, centres=True).ravel()
        assert np.array_equal(m[clear], owner[clear] + 1)
        maps.append(m)
    # centres 1/8 px or more inside the hull (its rounded corners may leave the rest out)
    deep = inside.copy()
    for shift in ((0.125, 0.125), (0.125, -0.125), (-0.125, 0.125), (-0.125, -0.125)):
        deep &= d.find_simplex(centres + np.array(shift)) >= 0
    assert deep.mean() > 0.9
    for m in maps[1:]:
        assert np.array_equal(m[deep], maps[0][deep])  # the same in every order
    # without the centre pass the order shows inside the hull (the sliver-free random mesh
    # still shares edge pixels), so the check above can fail
    last = [_core.fill_triangle_ids(np.ascontiguousarray(corners[o]), ids[o], h, w).ravel()
            for o in (np.arange(len(simp)), np.arange(len(simp))[::-1])]
    assert (last[0] != last[1])[deep].any()


def test_centre_owner_same_map_from_either_triangulation() -> None:
    """With PixelOwner.CENTRE the completion does not depend on the triangulator: Qhull's and
    the sweep's triangles (the same set, in other orders) give the same map bit for bit, and
    the values a plane's returns give are its depth at every covered pixel (interpolated; the
    outline's pixels extrapolated, exact for a plane too)."""
    rng = np.random.default_rng(5)
    h, w = 120, 160
    uv = rng.uniform([0, 0], [w - 1, h - 1], size=(900, 2))
    z = 1.0 / (0.3 + 0.001 * uv[:, 0] + 0.0005 * uv[:, 1])  # a plane: 1/z affine in (u, v)
    sparse = np.zeros((h, w), np.float32)
    sparse[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)] = z
    from bimcap.fusion import SparseDepth

    sp = SparseDepth(depth=sparse, uv=uv, z=z, point_index=np.arange(len(z)), counts={})
    a = complete_linear(sp, CENTRE_QHULL)
    b = complete_linear(sp, CENTRE_SWEEP)
    assert a.tobytes() == b.tobytes()
    vv, uu = np.nonzero(a > 0)
    expect = 1.0 / (0.3 + 0.001 * uu + 0.0005 * vv)
    assert np.allclose(a[vv, uu], expect, rtol=1e-5)
    with pytest.raises(FusionInputError) as err:
        LinearOptions(pixel_owner="nearest")  # type: ignore[arg-type]
    assert err.value.field == "pixel_owner"
    assert LinearOptions(pixel_owner="centre").pixel_owner is PixelOwner.CENTRE  # type: ignore[arg-type]


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_centre_owner_on_real_frames_is_closer_to_the_truth(world: str) -> None:
    """Every sixth frame: Qhull and the sweep give the same map with PixelOwner.CENTRE, the same
    support as the last drawn owner's, and against the simulator's depth a lower mean and
    99th-percentile error than Qhull's order (docs/speed.md: ~1 mm lower mean on 4 worlds)."""
    seq, projection, und = _real_world(world)
    errors: dict[str, list[np.ndarray]] = {"centre": [], "qhull": []}
    for i in range(0, len(seq.frames), 6):
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, projection,
                               distort=False)
        centre = complete_linear(sparse, CENTRE_SWEEP)
        assert centre.tobytes() == complete_linear(sparse, CENTRE_QHULL).tobytes()
        qhull = complete_linear(sparse, QHULL)
        assert np.array_equal(centre > 0, qhull > 0)
        truth = und.nearest(np.asarray(seq.load_depth(i), np.float32))
        both = (truth > 0) & (centre > 0)
        errors["centre"].append(np.abs(centre[both] - truth[both]))
        errors["qhull"].append(np.abs(qhull[both] - truth[both]))
    centre_err, qhull_err = (np.concatenate(errors[k]) for k in ("centre", "qhull"))
    assert centre_err.mean() < qhull_err.mean()
    assert np.percentile(centre_err, 99) <= np.percentile(qhull_err, 99)
