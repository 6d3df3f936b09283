"""Exact slicing, coverage / precision, sampling and merging on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from bimcap.bim.floorplan import FloorPlanOptions, merge_collinear
from bimcap.bim.semantic_cloud import read_ply, sample_surface, write_ply
from bimcap.bim.slicing import agreement, sample_segments, slice_mesh, thin_points


def unit_cube(
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.float64)
    v += np.asarray(offset)
    f = np.array([
        [0, 2, 1], [1, 2, 3],  # bottom
        [4, 5, 6], [5, 7, 6],  # top
        [0, 1, 4], [1, 5, 4],  # y = 0
        [2, 6, 3], [3, 6, 7],  # y = 1
        [0, 4, 2], [2, 4, 6],  # x = 0
        [1, 3, 5], [3, 7, 5],  # x = 1
    ], dtype=np.int32)
    return v, f


def test_slice_cube_is_unit_square() -> None:
    v, f = unit_cube((2.0, -1.0, 0.0))
    seg = slice_mesh(v, f, 0.3)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    assert length.sum() == pytest.approx(4.0, abs=1e-12)
    xy = seg.reshape(-1, 2)
    assert xy.min(axis=0) == pytest.approx([2.0, -1.0])
    assert xy.max(axis=0) == pytest.approx([3.0, 0.0])
    # Every slice point lies on the square's boundary.
    on_edge = np.isclose(xy[:, 0], 2) | np.isclose(xy[:, 0], 3) | np.isclose(xy[:, 1], -1) | \
        np.isclose(xy[:, 1], 0)
    assert on_edge.all()


def test_slice_outside_and_through_vertices() -> None:
    v, f = unit_cube()
    assert slice_mesh(v, f, 1.5).shape == (0, 4)
    # An octahedron cut exactly through its four equator vertices: vertices on the plane count
    # as above it, so each equator edge is produced once (by the lower half), not twice.
    v = np.array([[1, 0, 0.5], [0, 1, 0.5], [-1, 0, 0.5], [0, -1, 0.5], [0, 0, 0], [0, 0, 1.0]])
    f = np.array([[0, 1, 5], [1, 2, 5], [2, 3, 5], [3, 0, 5],
                  [1, 0, 4], [2, 1, 4], [3, 2, 4], [0, 3, 4]], dtype=np.int32)
    seg = slice_mesh(v, f, 0.5)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    assert len(seg) == 4
    assert length.sum() == pytest.approx(4 * np.sqrt(2), abs=1e-6)


def test_agreement_half_detected() -> None:
    exact = np.array([[0.0, 0.0, 4.0, 0.0]])
    detected = np.array([[0.0, 0.01, 2.0, 0.01], [10.0, 10.0, 11.0, 10.0]])
    a = agreement(exact, exact, detected, tol=0.05)
    # Half the exact length is near a detection (plus up to one tol at the end).
    assert a.coverage == pytest.approx(2.05 / 4.0, abs=0.01)
    # 2 m of 3 m detected lie on the outline; the far 1 m does not.
    assert a.precision == pytest.approx(2.0 / 3.0, abs=0.01)
    assert a.exact_length_m == pytest.approx(4.0)
    assert a.detected_length_m == pytest.approx(3.0)


def test_sample_segments_weights_sum_to_length() -> None:
    seg = np.array([[0.0, 0.0, 3.0, 4.0], [1.0, 1.0, 1.0, 1.25]])
    pts, w = sample_segments(seg, 0.1)
    assert w.sum() == pytest.approx(5.25)
    assert len(pts) == 50 + 3


def test_thin_points_keeps_one_per_cell() -> None:
    pts = np.array([[0.001, 0.001], [0.002, 0.003], [0.011, 0.0], [0.0, 0.011]])
    assert len(thin_points(pts, 0.01)) == 3


def test_merge_collinear_joins_and_keeps_gaps() -> None:
    opts = FloorPlanOptions()
    segs = np.array([
        [0.0, 0.0, 1.0, 0.0],
        [0.95, 0.002, 2.0, 0.002],  # overlaps, 2 mm off: joins
        [2.03, 0.0, 3.0, 0.0],  # 3 cm gap < gap_m (4 cm): joins
        [3.9, 0.0, 5.0, 0.0],  # 0.9 m gap (a door): stays apart
        [0.0, 0.5, 1.0, 0.5],  # parallel 0.5 m away: apart
    ])
    out = merge_collinear(segs, opts)
    assert len(out) == 3
    lengths = sorted(np.hypot(out[:, 2] - out[:, 0], out[:, 3] - out[:, 1]))
    assert lengths == pytest.approx([1.0, 1.1, 3.0], abs=1e-3)


def test_sample_surface_density_and_support() -> None:
    v = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    p = sample_surface(v, f, 500.0, np.random.default_rng(3))
    # Poisson(1000): within 5 sigma.
    assert abs(len(p) - 1000) < 5 * np.sqrt(1000)
    assert (p[:, 0] >= 0).all() and (p[:, 0] <= 2).all() and (p[:, 1] >= 0).all()
    assert (p[:, 1] <= 1).all() and np.all(p[:, 2] == 0)
    # Uniform: each half of the rectangle holds about half the points.
    assert abs((p[:, 0] < 1).mean() - 0.5) < 0.06


def test_ply_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3))
    labels = rng.integers(0, 8, size=100).astype(np.uint8)
    write_ply(tmp_path / "c.ply", pts, labels)
    p2, l2 = read_ply(tmp_path / "c.ply")
    assert np.allclose(p2, pts, atol=1e-6)
    assert np.array_equal(l2, labels)
