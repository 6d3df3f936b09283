"""Semantic sampling (density and the peers' stride), the semantic map and its PLY."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _frontend_scene import COLUMN, ROOM, TEST_CAMERA, Room, default_poses
from bimcap.frontend import (
    SamplingMode,
    SemanticMapError,
    SemanticSamplingOptions,
    build_semantic_map,
    read_semantic_ply,
    sample_semantic_points,
    write_semantic_ply,
)
from bimcap.frontend.runner import Undistorter
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import transform_points
from bimcap.labels import LABEL_COLORS, Label

PINHOLE = TEST_CAMERA.pinhole()


@pytest.fixture(scope="module")
def frames() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(labels, depth, world_from_cam) of 3 rendered frames, undistorted to the pinhole camera."""
    room = Room()
    und = Undistorter(TEST_CAMERA)
    out = []
    for pose in default_poses(3):
        r = room.render(TEST_CAMERA, pose)
        out.append((und.nearest(r.labels), und.nearest(r.depth), pose))
    return out


def test_samples_lie_on_their_surfaces(frames: list) -> None:
    """Under the true poses floor samples are on z = 0, wall samples on a wall, columns on the
    column."""
    opts = SemanticSamplingOptions()
    for i, (labels, depth, pose) in enumerate(frames):
        s = sample_semantic_points(labels, depth, PINHOLE, i, opts)
        floor = transform_points(pose, s[Label.FLOOR])
        wall = transform_points(pose, s[Label.WALL])
        col = transform_points(pose, s[Label.COLUMN])
        assert len(floor) > 100 and len(wall) > 100 and len(col) > 20
        assert np.abs(floor[:, 2]).max() < 0.01
        d_wall = np.min(
            np.abs(np.stack([wall[:, 0], wall[:, 0] - ROOM[0], wall[:, 1], wall[:, 1] - ROOM[1]])),
            axis=0,
        )
        assert d_wall.max() < 0.02
        (x0, y0), (x1, y1) = COLUMN
        assert ((col[:, 0] > x0 - 0.02) & (col[:, 0] < x1 + 0.02)).all()
        assert ((col[:, 1] > y0 - 0.02) & (col[:, 1] < y1 + 0.02)).all()
        assert len(s[Label.CEILING]) == 0  # looking down: no ceiling in view


def test_density_is_per_square_metre() -> None:
    """A fronto-parallel wall at 2 m: the image covers W·H·z²/(fx·fy) m²; expect density × that."""
    cam = Camera(200, 150, 100.0, 100.0, 99.5, 74.5)
    depth = np.full((150, 200), 2.0)
    labels = np.full((150, 200), int(Label.WALL), np.uint8)
    area = 200 * 150 * 4.0 / 1e4  # 12 m²
    opts = SemanticSamplingOptions(wall_density=50.0, max_per_frame=None)
    counts = [len(sample_semantic_points(labels, depth, cam, i, opts)[Label.WALL])
              for i in range(5)]
    assert abs(np.mean(counts) - 50.0 * area) < 0.05 * 50.0 * area
    # A wall twice as far covers 4× the area → 4× the samples.
    far = [len(sample_semantic_points(labels, 2 * depth, cam, i, opts)[Label.WALL])
           for i in range(5)]
    assert np.mean(far) / np.mean(counts) == pytest.approx(4.0, rel=0.05)


def test_slanted_floor_counts_its_true_area(frames: list) -> None:
    """Floor samples per visible floor area match the density (the cos θ correction)."""
    labels, depth, pose = frames[0]
    dens = 40.0
    opts = SemanticSamplingOptions(floor_density=dens, max_per_frame=None)
    s = sample_semantic_points(labels, depth, PINHOLE, 0, opts)
    # Oracle: the exact floor area of every floor pixel, intersecting its 4 corner rays with z = 0.
    from bimcap.geometry.poses import quat_to_rotmat

    v, u = np.nonzero((labels == Label.FLOOR) & (depth > 0))
    rot = quat_to_rotmat(pose[3:7])
    corners = []
    for du, dv in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
        ray_w = PINHOLE.rays(np.stack([u + du, v + dv], 1).astype(float), distorted=False) @ rot.T
        t = -pose[2] / ray_w[:, 2]
        corners.append(pose[:2] + t[:, None] * ray_w[:, :2])
    x = np.stack([c[:, 0] for c in corners], 1)
    y = np.stack([c[:, 1] for c in corners], 1)
    area = 0.5 * np.abs((x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y).sum(1)).sum()
    assert len(s[Label.FLOOR]) == pytest.approx(dens * area, rel=0.1)


def test_peers_stride_preset(frames: list) -> None:
    labels, depth, _ = frames[0]
    opts = SemanticSamplingOptions.peers()
    assert opts.mode is SamplingMode.STRIDE and opts.wall_stride == 150 and opts.floor_stride == 30
    s = sample_semantic_points(labels, depth, PINHOLE, 0, opts)
    n_floor = int(((labels == Label.FLOOR) & (depth >= 0.1)).sum())
    n_wall = int(((labels == Label.WALL) & (depth >= 0.1)).sum())
    assert len(s[Label.FLOOR]) == -(-n_floor // 30)
    assert len(s[Label.WALL]) == -(-n_wall // 150)


def test_seeded_and_capped(frames: list) -> None:
    labels, depth, _ = frames[1]
    a = sample_semantic_points(labels, depth, PINHOLE, 7, SemanticSamplingOptions(seed=3))
    b = sample_semantic_points(labels, depth, PINHOLE, 7, SemanticSamplingOptions(seed=3))
    c = sample_semantic_points(labels, depth, PINHOLE, 7, SemanticSamplingOptions(seed=4))
    assert np.array_equal(a[Label.FLOOR], b[Label.FLOOR])
    assert not np.array_equal(a[Label.FLOOR], c[Label.FLOOR])
    capped = sample_semantic_points(
        labels, depth, PINHOLE, 7, SemanticSamplingOptions(max_per_frame=10, floor_density=1e4)
    )
    assert len(capped[Label.FLOOR]) == 10


def test_size_mismatch_is_an_error(frames: list) -> None:
    labels, depth, _ = frames[0]
    with pytest.raises(SemanticMapError, match="same"):
        sample_semantic_points(labels[:-1], depth, PINHOLE, 0)
    with pytest.raises(SemanticMapError, match="camera"):
        sample_semantic_points(labels, depth, PINHOLE.scaled(0.5), 0)
    with pytest.raises(SemanticMapError):
        SemanticSamplingOptions(wall_stride=0)


def test_ply_round_trip_and_open3d_reads_it(tmp_path: Path, frames: list) -> None:
    import open3d as o3d

    samples = {}
    for i, (labels, depth, _) in enumerate(frames):
        for lab, p in sample_semantic_points(labels, depth, PINHOLE, i).items():
            f, q = samples.get(lab, (np.zeros(0, np.int32), np.zeros((0, 3))))
            samples[lab] = (np.concatenate([f, np.full(len(p), i, np.int32)]),
                            np.concatenate([q, p]))
    smap = build_semantic_map(samples, np.stack([f[2] for f in frames]))
    path = tmp_path / "map.ply"
    write_semantic_ply(path, smap.points, smap.labels)
    pts, labs = read_semantic_ply(path)
    assert np.array_equal(pts, smap.points) and np.array_equal(labs, smap.labels)
    pcd = o3d.io.read_point_cloud(str(path))
    assert np.allclose(np.asarray(pcd.points), smap.points)
    assert np.allclose(np.asarray(pcd.colors) * 255, LABEL_COLORS[smap.labels], atol=0.5)
    assert not list(tmp_path.glob(".*.tmp"))  # atomic: no temporary left behind
    with pytest.raises(SemanticMapError):
        write_semantic_ply(path, smap.points, smap.labels[:-1])
