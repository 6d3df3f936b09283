"""The linear completion's compiled Delaunay triangulation (``bimcap._core.delaunay_triangles``,
cpp/bimcap/raster/delaunay.h): a valid Delaunay triangulation, the triangles of
``scipy.spatial.Delaunay`` (Qhull) where the points are in general position (random points,
every third frame of two generated worlds' LiDAR, skipped without them), clear errors, and the
completion it gives beside Qhull's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from bimcap import _core
from bimcap.fusion import (
    FusionInputError,
    LinearOptions,
    Triangulation,
    complete_linear,
    project_lidar,
)

_WORLDS = Path("/tmp/gen")
SWEEP = LinearOptions(triangulation=Triangulation.SWEEP)


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
        qhull = complete_linear(sparse)  # the default
        assert qhull.tobytes() == complete_linear(
            sparse, LinearOptions(triangulation=Triangulation.QHULL)).tobytes()
        assert np.array_equal(sweep > 0, qhull > 0)
        assert (sweep == qhull).mean() > 0.5
        both = sweep > 0
        assert np.median(np.abs(sweep[both] - qhull[both])) < 1e-3


@pytest.mark.parametrize("world", ["gen-demo-s0", "ifc-SampleHouse4"])
def test_completion_draws_the_fattest_triangles_last(world: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The triangles' order from the triangulator does not matter (they are drawn by their least
    altitude: reversing or shuffling its list gives the same map, the rotation of each
    triangle's corners too), and against the simulator's ground truth the depth is no worse
    than with Qhull's order, on average and at the 99th percentile."""
    seq_dir = _WORLDS / world / "seq_60_standard"
    if not seq_dir.is_dir():
        pytest.skip(f"{seq_dir} not generated")
    from bimcap.dataset import read_sequence
    from bimcap.frontend.providers import LidarDepthProvider
    from bimcap.frontend.runner import get_undistorter

    seq = read_sequence(seq_dir)
    projection = LidarDepthProvider().projection
    und = get_undistorter(seq.camera)
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
        qhull = complete_linear(sparse, LinearOptions(triangulation=Triangulation.QHULL))
        truth = und.nearest(np.asarray(seq.load_depth(i), np.float32))
        both = (truth > 0) & (sweep > 0)
        errors["sweep"].append(np.abs(sweep[both] - truth[both]))
        errors["qhull"].append(np.abs(qhull[both] - truth[both]))
    sweep_err, qhull_err = (np.concatenate(errors[k]) for k in ("sweep", "qhull"))
    assert sweep_err.mean() <= qhull_err.mean()
    assert np.percentile(sweep_err, 99) <= np.percentile(qhull_err, 99)
