"""bimcap.io.ply: the one labelled-PLY writer and reader (semantic cloud float32, map float64)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimcap.io.ply import PlyError, Precision, read_labelled_ply, write_labelled_ply


@pytest.mark.parametrize("precision", list(Precision))
def test_round_trip_and_open3d_agrees(tmp_path: Path, precision: Precision) -> None:
    import open3d as o3d

    rng = np.random.default_rng(0)
    pts = rng.uniform(-50, 50, (200, 3))
    labels = rng.integers(0, 8, 200).astype(np.uint8)
    path = tmp_path / "c.ply"
    write_labelled_ply(path, pts, labels, precision, "test")
    back, lab = read_labelled_ply(path)
    expect = pts.astype(np.float32).astype(np.float64) if precision is Precision.FLOAT32 else pts
    assert np.array_equal(back, expect) and np.array_equal(lab, labels)
    assert np.allclose(np.asarray(o3d.io.read_point_cloud(str(path)).points), expect)


def test_errors_name_the_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "c.ply"
    with pytest.raises(PlyError, match=r"c\.ply: label: 3 points but 2 labels"):
        write_labelled_ply(path, np.zeros((3, 3)), np.zeros(2), Precision.FLOAT64, "x")
    with pytest.raises(PlyError, match=r"label ids must be in 0\.\.7"):
        write_labelled_ply(path, np.zeros((1, 3)), np.array([9]), Precision.FLOAT64, "x")
    write_labelled_ply(path, np.zeros((4, 3)), np.zeros(4), Precision.FLOAT32, "x")
    cut = tmp_path / "cut.ply"
    cut.write_bytes(path.read_bytes()[:-5])
    with pytest.raises(PlyError, match=r"cut\.ply: vertex: expected 4 vertices"):
        read_labelled_ply(cut)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"solid x\n")
    with pytest.raises(PlyError, match=r"bad\.ply: header: not a PLY file"):
        read_labelled_ply(bad)


def test_far_from_origin_float32_cloud_keeps_millimetres(tmp_path: Path) -> None:
    """A georeferenced cloud (northing 5.4·10⁶ m, where float32 steps by 0.5 m) asked for as
    float32 is written as float64; a cloud near the origin stays float32."""
    rng = np.random.default_rng(1)
    local = rng.uniform(-20, 20, (100, 3))
    far = local + np.array([512_345.6, 5_401_234.5, 212.3])
    labels = rng.integers(0, 8, 100).astype(np.uint8)
    write_labelled_ply(tmp_path / "far.ply", far, labels, Precision.FLOAT32, "far")
    back, _ = read_labelled_ply(tmp_path / "far.ply")
    assert np.abs(back - far).max() < 1e-6
    assert b"property double x" in (tmp_path / "far.ply").read_bytes()[:400]
    write_labelled_ply(tmp_path / "near.ply", local, labels, Precision.FLOAT32, "near")
    assert b"property float x" in (tmp_path / "near.ply").read_bytes()[:400]
