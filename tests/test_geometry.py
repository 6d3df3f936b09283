from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.geometry import (
    Camera,
    Trajectory,
    TrajectoryError,
    compose,
    invert,
    matrix_to_pose,
    pose_to_matrix,
    read_tum,
    transform_points,
    write_tum,
)


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    q = Rotation.random(n, random_state=rng).as_quat()
    return np.concatenate([rng.normal(size=(n, 3)), q], axis=1)


def test_compose_with_inverse_is_identity() -> None:
    rng = np.random.default_rng(0)
    p = random_poses(rng, 20)
    ident = compose(p, invert(p))
    np.testing.assert_allclose(ident[:, :3], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(ident[:, 6]), 1.0, atol=1e-12)


def test_matrix_round_trip_and_transform_agree() -> None:
    rng = np.random.default_rng(1)
    p = random_poses(rng, 5)
    m = pose_to_matrix(p)
    back = pose_to_matrix(matrix_to_pose(m))
    np.testing.assert_allclose(back, m, atol=1e-12)
    pts = rng.normal(size=(5, 3))
    expected = np.einsum("nij,nj->ni", m[:, :3, :3], pts) + m[:, :3, 3]
    np.testing.assert_allclose(transform_points(p, pts), expected, atol=1e-12)
    np.testing.assert_allclose(transform_points(p[0], pts), pts @ m[0, :3, :3].T + m[0, :3, 3])


def test_tum_round_trip(tmp_path) -> None:
    rng = np.random.default_rng(2)
    traj = Trajectory(np.arange(10) * 0.1 + 1e9, random_poses(rng, 10))
    write_tum(tmp_path / "a.tum", traj)
    back = read_tum(tmp_path / "a.tum")
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-15)


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("0 1 2 3 0 0 0", "expected 8 fields"),
        ("0 1 2 nan 0 0 0 1", "not finite"),
        ("0 1 2 x 0 0 0 1", "not a number"),
        ("0 1 2 3 0 0 0 2", "norm"),
    ],
)
def test_tum_rejects_bad_lines(tmp_path, line: str, match: str) -> None:
    f = tmp_path / "bad.tum"
    f.write_text("# header\n" + line + "\n")
    with pytest.raises(TrajectoryError, match=match) as info:
        read_tum(f)
    assert str(f) in str(info.value)


def test_camera_projection_round_trip_with_distortion() -> None:
    cam = Camera(1032, 772, 1175.9, 1176.8, 508.4, 394.1,
                 (-0.054366, 0.118389, 0.001781, -0.003908, 0.0))
    rng = np.random.default_rng(3)
    uv = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], size=(100, 2))
    depth = rng.uniform(0.5, 10.0, size=100)
    p = cam.backproject(uv, depth)
    uv2, ok = cam.project(p)
    assert ok.all()
    np.testing.assert_allclose(uv2, uv, atol=1e-8)


def test_camera_matches_opencv_projectpoints() -> None:
    cv2 = pytest.importorskip("cv2")
    cam = Camera(640, 480, 500.0, 510.0, 320.0, 240.0, (-0.1, 0.05, 0.001, -0.002, 0.01))
    rng = np.random.default_rng(4)
    p = rng.uniform([-1, -1, 2], [1, 1, 5], size=(50, 3))
    uv_cv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist))
    uv, _ = cam.project(p)
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2), atol=1e-9)
