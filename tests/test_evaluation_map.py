"""Map metrics: MME/MPV vs the map-metrics 0.0.5 oracle, neighbourhood rules, NND by hand, PLY."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bimcap.evaluation.errors import EvaluationError
from bimcap.evaluation.map_metrics import (
    CutoffMode,
    aggregate_map,
    map_metrics,
    map_metrics_with_reference,
    nearest_neighbour_distance,
    neighbourhood_covariances,
    read_ply_points,
)


@pytest.fixture(scope="module")
def oracle(oracles_dir: Path) -> tuple[list[np.ndarray], dict[str, np.ndarray], list[dict]]:
    d = oracles_dir / "map_metrics"
    npz = np.load(d / "scans.npz")
    scans = [npz[f"scan_{i}"].T for i in range(len(npz.files))]  # stored (3, N)
    poses = {
        "true_poses": np.load(d / "poses.npy"),
        "perturbed_poses": np.load(d / "poses_perturbed.npy"),
    }
    cases = json.loads((d / "map_metrics_expected.json").read_text())["cases"]
    return scans, poses, cases


@pytest.mark.needs_shared
@pytest.mark.parametrize("case_index", [0, 1, 2, 3])
def test_mme_mpv_equal_map_metrics(
    oracle: tuple[list[np.ndarray], dict[str, np.ndarray], list[dict]], case_index: int
) -> None:
    scans, poses, cases = oracle
    case = cases[case_index]
    m = map_metrics(aggregate_map(scans, poses[case["poses"]]), case["radius"], case["min_knn"])
    assert m.mme == pytest.approx(case["MME"], abs=1e-9, rel=0)
    assert m.mpv == pytest.approx(case["MPV"], abs=1e-9, rel=0)
    assert m.radius_m == case["radius"] and m.min_neighbours == case["min_knn"]


@pytest.mark.needs_shared
def test_perturbed_map_is_worse(
    oracle: tuple[list[np.ndarray], dict[str, np.ndarray], list[dict]],
) -> None:
    scans, poses, _ = oracle
    good = map_metrics(aggregate_map(scans, poses["true_poses"]), 0.2)
    bad = map_metrics(aggregate_map(scans, poses["perturbed_poses"]), 0.2)
    assert bad.mme > good.mme and bad.mpv > good.mpv


def test_covariances_equal_np_cov_brute_force() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 1.0, (400, 3)) + 100.0  # far from the origin: conditioning matters
    keep, covs = neighbourhood_covariances(pts, 0.25, 5)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    expected_keep = np.flatnonzero((d <= 0.25).sum(axis=1) > 5)
    assert keep.tolist() == expected_keep.tolist() and len(keep) > 100
    for k, c in zip(keep[::17], covs[::17], strict=True):
        np.testing.assert_allclose(c, np.cov(pts[d[k] <= 0.25].T), rtol=1e-9, atol=1e-14)


def test_count_threshold_is_strictly_greater() -> None:
    rng = np.random.default_rng(1)
    six = rng.normal(0.0, 0.01, (6, 3))
    assert map_metrics(six, 1.0, min_neighbours=5).n_used_mpv == 6
    m = map_metrics(six[:5], 1.0, min_neighbours=5)
    assert m.n_used_mpv == 0 and np.isnan(m.mme) and np.isnan(m.mpv)
    assert m.to_dict()["mme"] is None


def test_hand_computed_mme_mpv_on_one_cluster() -> None:
    # 8 cube corners, all within the radius of each other: every point sees the same Σ
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 3)], dtype=float)
    cov = np.cov(cube.T)  # diag(1, 4, 9) * 8 / 4 / 7 ... computed, not assumed
    m = map_metrics(cube, radius=10.0, min_neighbours=5)
    assert m.mpv == pytest.approx(np.linalg.eigvalsh(cov)[0], abs=1e-15)
    assert m.mme == pytest.approx(0.5 * np.log(np.linalg.det(2 * np.pi * np.e * cov)), abs=1e-12)
    assert m.mpv == pytest.approx(2.0 / 7.0, abs=1e-15)  # var of {0,0,0,0,1,1,1,1} with N-1


def test_planar_points_skipped_in_mme() -> None:
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.uniform(0, 0.1, (20, 2)), np.zeros(20)])
    m = map_metrics(plane, 1.0, 5)
    assert m.n_used_mpv == 20 and m.mpv == pytest.approx(0.0, abs=1e-18)
    assert m.n_used_mme == 0 and np.isnan(m.mme)


def test_aggregate_map_order_and_transform() -> None:
    a = np.array([[1.0, 0.0, 0.0]])
    b = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    rot_z90 = np.array(
        [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0, 0, 0, 1.0]]
    )
    shift = np.eye(4)
    shift[:3, 3] = [0.0, 0.0, 5.0]
    out = aggregate_map([a, b], np.stack([rot_z90, shift]))
    np.testing.assert_allclose(out, [[0.0, 1.0, 0.0], [0.0, 1.0, 5.0], [0.0, 0.0, 6.0]], atol=1e-15)
    with pytest.raises(EvaluationError, match="one"):
        aggregate_map([a, b], np.stack([shift]))


def test_nnd_hand_computed() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    reference = np.array([[0.0, 0.0, 0.1], [1.2, 0.0, 0.0]])
    nnd = nearest_neighbour_distance(points, reference, 0.3, CutoffMode.EXCLUDE)
    assert nnd.mean_m == pytest.approx(0.15, abs=1e-15) and nnd.n_beyond_cutoff == 1
    assert nnd.rmse_m == pytest.approx(np.sqrt((0.1**2 + 0.2**2) / 2), abs=1e-15)
    nnd = nearest_neighbour_distance(points, reference, 0.3, CutoffMode.CLAMP)
    assert nnd.mean_m == pytest.approx(0.2, abs=1e-15) and nnd.n_beyond_cutoff == 1
    m = map_metrics_with_reference(points, reference, "hand", radius=0.5)
    assert m.nnd_m == pytest.approx(0.15) and m.nnd_reference == "hand" and m.n_beyond_cutoff == 1
    assert "reference hand" in m.format_table()


def test_nnd_cutoff_is_exclusive_like_conslam() -> None:
    # ConSLAM keeps a neighbour only if its distance is < the threshold
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    reference = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 2.25]])
    nnd = nearest_neighbour_distance(points, reference, cutoff=0.5)
    assert nnd.n_beyond_cutoff == 1 and nnd.mean_m == 0.25
    all_far = nearest_neighbour_distance(points, reference, cutoff=0.1)
    assert all_far.n_beyond_cutoff == 2 and np.isnan(all_far.mean_m)


def test_bad_inputs() -> None:
    with pytest.raises(EvaluationError, match="N, 3"):
        map_metrics(np.zeros((4, 2)))
    with pytest.raises(EvaluationError, match="finite"):
        map_metrics(np.full((4, 3), np.nan))
    with pytest.raises(EvaluationError, match="radius"):
        map_metrics(np.zeros((4, 3)), radius=0.0)


def test_read_ply_points(tmp_path: Path) -> None:
    import open3d as o3d

    pts = np.random.default_rng(3).normal(size=(50, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    path = tmp_path / "map.ply"
    assert o3d.io.write_point_cloud(path, cloud)
    np.testing.assert_allclose(read_ply_points(path), pts, atol=1e-6)
    with pytest.raises(EvaluationError, match="no such file"):
        read_ply_points(tmp_path / "missing.ply")
    (tmp_path / "bad.ply").write_text("hello\n")
    with pytest.raises(EvaluationError, match="not a PLY"):
        read_ply_points(tmp_path / "bad.ply")
