"""Tests of the sensor simulator (bimcap.sim: simulator, render, lidar, walk, texture, clutter)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import compose, invert, pose_to_matrix, transform_points
from bimcap.geometry.trajectory import read_tum
from bimcap.labels import Label
from bimcap.sim.clutter import box_mesh, cylinder_mesh
from bimcap.sim.lidar import LidarConfig, LidarSimulator
from bimcap.sim.render import MeshPart, Renderer, World
from bimcap.sim.simulator import (
    CONSLAM_CAM_FROM_LIDAR,
    CONSLAM_CAM_FROM_LIDAR_3X4,
    CONSLAM_CAMERA,
    SimError,
    SimulatorConfig,
    corridor_building,
    simulate_world,
)
from bimcap.sim.texture import TextureBank
from bimcap.sim.walk import FreeSpace, WalkConfig, camera_rotation, plan_walk


@pytest.fixture(scope="module")
def building() -> tuple[list[MeshPart], list[np.ndarray], np.ndarray]:
    return corridor_building(rooms_per_side=2)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory, building) -> Path:
    parts, polys, doors = building
    out = tmp_path_factory.mktemp("sim") / "seq"
    simulate_world(parts, out, SimulatorConfig.small(frames=6), seed=3, free_polygons=polys,
                   doors_xy=doors)
    return out


def _manifest(seq: Path) -> dict:
    return json.loads((seq / "manifest.json").read_text())


# ------------------------------------------------------------------------------ conventions
def test_conslam_extrinsic_lidar_z_is_camera_up() -> None:
    r_cl = pose_to_matrix(CONSLAM_CAM_FROM_LIDAR)[:3, :3]
    # the 3x4 matrix is orthonormal to 1e-6, and the pose reproduces it
    np.testing.assert_allclose(r_cl, CONSLAM_CAM_FROM_LIDAR_3X4[:, :3], atol=1e-5)
    # LiDAR z maps to camera -y (up when level), LiDAR x to camera +z (forward)
    assert r_cl @ np.array([0, 0, 1.0]) == pytest.approx([0, -1, 0], abs=2e-3)
    assert r_cl @ np.array([1.0, 0, 0]) == pytest.approx([0.0576, 0, 0.9983], abs=2e-3)


def test_camera_rotation_convention() -> None:
    r = camera_rotation(np.array([np.pi / 2]), np.array([0.0]), np.array([0.0]))[0]
    # yaw 90°: forward = +y world, right = +x world, down = -z world
    np.testing.assert_allclose(r[:, 2], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(r[:, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r[:, 1], [0, 0, -1], atol=1e-12)
    up = camera_rotation(np.array([0.0]), np.array([0.3]), np.array([0.0]))[0]
    assert up[2, 2] == pytest.approx(np.sin(0.3))  # positive pitch looks up


def test_default_camera_is_conslam_at_half_resolution() -> None:
    cam = SimulatorConfig().camera
    assert (cam.width, cam.height) == (1032, 772)
    assert cam.fx == pytest.approx(2351.85909 / 2)
    assert cam.dist == CONSLAM_CAMERA.dist


# ---------------------------------------------------------------------------------- render
def _room_world() -> World:
    parts = []
    for name, lab, lo, hi in [
        ("floor", Label.FLOOR, (-50, -50, -0.2), (50, 50, 0)),
        ("ceil", Label.CEILING, (-50, -50, 3), (50, 50, 3.2)),
        ("wall", Label.WALL, (4.0, -5, 0), (4.2, 5, 3)),
    ]:
        v, f = box_mesh(np.array(lo, float), np.array(hi, float))
        parts.append(MeshPart(name, lab, v, f))
    return World.from_parts(parts)


def test_render_depth_and_labels_hand_computed() -> None:
    """Camera at (0, 0, 1.5) looking along +x at a wall at x = 4: depth 4 m on the horizon row."""
    world = _room_world()
    cam = Camera(80, 60, 50.0, 50.0, 39.5, 29.5, (-0.05, 0.1, 0.001, -0.004, 0.0))
    r = camera_rotation(np.array([0.0]), np.array([0.0]), np.array([0.0]))[0]
    from bimcap.geometry.poses import rotmat_to_quat

    pose = np.r_[0.0, 0.0, 1.5, rotmat_to_quat(r)]
    frame = Renderer(world, cam, TextureBank.bake(0)).render(pose, np.random.default_rng(0))
    # the principal point row: wall, z-depth exactly 4 (the ray has z = 1 in the camera)
    assert frame.labels[30, 40] == Label.WALL
    assert frame.depth[30, 40] == pytest.approx(4.0, abs=1e-4)
    # bottom rows see the floor, top rows the ceiling; a floor pixel's depth from the
    # distorted ray: p = ray * z must lie on z_world = 0
    assert frame.labels[59, 40] == Label.FLOOR and frame.labels[0, 40] == Label.CEILING
    ray = cam.rays(np.array([[40.0, 59.0]]), distorted=True)[0]
    assert frame.depth[59, 40] * ray[1] == pytest.approx(1.5, abs=1e-4)
    assert frame.rgb.dtype == np.uint8 and frame.rgb.shape == (60, 80, 3)


def test_slab_is_floor_from_above_and_ceiling_from_below() -> None:
    v, f = box_mesh(np.zeros(3), np.array([1.0, 1.0, 0.2]))
    w = World.from_parts([MeshPart("slab", Label.FLOOR, v, f)])
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert set(w.tri_label[n[:, 2] > 0]) == {Label.FLOOR}
    assert set(w.tri_label[n[:, 2] < 0]) == {Label.CEILING}


def test_cylinder_mesh_is_closed() -> None:
    _v, f = cylinder_mesh((0.0, 0.0), 0.0, 1.0, 0.5, segments=12)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # every edge shared by exactly two triangles


# ----------------------------------------------------------------------------------- lidar
def test_lidar_pattern_and_noise() -> None:
    cfg = LidarConfig()
    d = cfg.directions()
    assert d.shape == (1800 * 16, 3)
    elev = np.rad2deg(np.arcsin(d[:16, 2]))
    np.testing.assert_allclose(elev, np.arange(-15, 16, 2), atol=1e-4)
    # level LiDAR at height 1.5 in the room: the horizontal beams hit the wall at x = 4 → 4 m
    world = _room_world()
    sim = LidarSimulator(world, LidarConfig(dropout=0.0))
    pts = sim.scan(np.array([0, 0, 1.5, 0, 0, 0, 1.0]), np.random.default_rng(0))
    fwd = (np.abs(pts[:, 1]) < 0.01) & (np.abs(pts[:, 2]) < 0.3) & (pts[:, 0] > 0)
    assert fwd.sum() >= 1
    # the points straight ahead: x is range·cos(elev) ≈ 4 within 4σ of the 3 cm noise
    rng_fwd = np.linalg.norm(pts[fwd, :3], axis=1)
    cos_el = np.sqrt(1.0 - (pts[fwd, 2] / rng_fwd) ** 2)
    assert np.all(np.abs(rng_fwd * cos_el - 4.0) < 0.12)
    # noise statistics of the floor returns behind the LiDAR (away from the wall at x = 4):
    # the floor is 1.5 m below, so a beam of elevation e has true range 1.5 / sin(-e) and meets
    # the floor at cos(incidence) = sin(-e); the residuals follow the model's sigma(r, incidence)
    down = (pts[:, 2] < -0.2) & (pts[:, 0] < 0)
    r = np.linalg.norm(pts[down, :3], axis=1)
    sin_el = -pts[down, 2] / r
    resid = r - 1.5 / sin_el  # true range to the floor plane
    sigma = LidarConfig().range_sigma(1.5 / sin_el, sin_el)
    assert sigma.min() >= 0.03 and sigma.max() > 2 * sigma.min()  # more at grazing incidence
    assert 0.9 < np.std(resid / sigma) < 1.1
    assert abs(np.mean(resid / sigma)) < 0.05


# ------------------------------------------------------------------------------------ walk
def test_walk_never_collides_and_respects_height(building) -> None:
    parts, polys, doors = building
    world = World.from_parts(parts)
    free = FreeSpace.from_polygons(world, polys, 0.0, doors)
    cfg = WalkConfig()
    walk = plan_walk(free, 90.0, np.random.default_rng(5), cfg)
    t = np.arange(0.0, walk.duration, 0.05)
    poses = walk.poses(t)
    dist = world.distance(poses[:, :3])
    assert dist.min() > 0.3
    h = poses[:, 2]
    assert h.min() >= 1.2 and h.max() <= 1.7
    # it walks at about 1 m/s and visits rooms on both sides of the corridor (|y| > 1.3)
    speed = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1) / 0.05
    assert 0.6 < speed.mean() < 1.2
    assert (poses[:, 1] > 1.5).any() and (poses[:, 1] < -1.5).any()
    # yaw rate limited
    yaw_rate = np.rad2deg(np.abs(np.diff(walk.yaw))) / (walk.t[1] - walk.t[0])
    assert yaw_rate.max() <= cfg.max_yaw_rate_dps + 1e-6


def test_walk_from_meshes_without_polygons(building) -> None:
    parts, _, _ = building
    world = World.from_parts(parts)
    from bimcap.sim.walkable import free_space_from_world

    free = free_space_from_world(world)
    assert free.z_floor == pytest.approx(0.0)
    walk = plan_walk(free, 40.0, np.random.default_rng(1))
    poses = walk.poses(np.arange(0.0, walk.duration, 0.1))
    assert world.distance(poses[:, :3]).min() > 0.3


def test_too_narrow_space_is_a_clear_error() -> None:
    v, f = box_mesh(np.array([-1.0, -1.0, -0.2]), np.array([1.0, 1.0, 0.0]))
    world = World.from_parts([MeshPart("f", Label.FLOOR, v, f)])
    corridor = [np.array([[0, 0], [5, 0], [5, 0.6], [0, 0.6]], float)]
    free = FreeSpace.from_polygons(world, corridor, 0.0)
    with pytest.raises(SimError, match="too narrow"):
        plan_walk(free, 10.0, np.random.default_rng(0))


# ------------------------------------------------------------------------------- sequence
def test_sequence_layout(sequence: Path) -> None:
    m = _manifest(sequence)
    assert m["format"] == "bimcap-sequence" and m["version"] == 1
    assert len(m["frames"]) == 6
    for fr in m["frames"]:
        for key in ("image", "lidar", "labels", "depth"):
            assert (sequence / fr[key]).is_file()
    gt = read_tum(sequence / m["poses"]["gt"])
    assert len(gt) == 6
    np.testing.assert_allclose(gt.timestamps, [fr["timestamp"] for fr in m["frames"]])
    scan = np.fromfile(sequence / m["frames"][0]["lidar"], "<f4").reshape(-1, 4)
    assert 20000 < len(scan) <= 28800
    assert scan[:, 3].min() >= 0 and scan[:, 3].max() <= 255


def test_lidar_wall_return_lands_on_wall_pixel_with_matching_depth(sequence: Path) -> None:
    """Project each frame's LiDAR returns with the manifest's calibration into the raw image."""
    import cv2

    m = _manifest(sequence)
    cam = Camera.from_dict(m["camera"])
    cam_from_lidar = np.array(m["cam_from_lidar"])
    checked = 0
    for fr in m["frames"]:
        pts = np.fromfile(sequence / fr["lidar"], "<f4").reshape(-1, 4)[:, :3]
        p_cam = transform_points(cam_from_lidar, pts)
        uv, front = cam.project(p_cam)  # distorted: the raw image
        ok = front & cam.in_image(uv, margin=2.0)
        labels = cv2.imread(str(sequence / fr["labels"]), cv2.IMREAD_UNCHANGED)
        depth = np.load(sequence / fr["depth"])
        pix = np.rint(uv[ok]).astype(int)
        lab = labels[pix[:, 1], pix[:, 0]]
        gt_depth = depth[pix[:, 1], pix[:, 0]]
        z = p_cam[ok, 2]
        # wall pixels whose 3x3 neighbourhood is all wall (away from edges, where rounding to the
        # nearest pixel may pick the other surface)
        interior = np.ones(len(pix), bool)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                interior &= labels[pix[:, 1] + dv, pix[:, 0] + du] == Label.WALL
        wall = (lab == Label.WALL) & interior
        if wall.sum() < 20:
            continue
        resid = z[wall] - gt_depth[wall]
        # range noise 3 cm (σ) plus the sub-pixel rounding on oblique walls
        assert np.median(np.abs(resid)) < 0.04
        assert np.mean(np.abs(resid) < 0.12) > 0.95
        # and most in-image returns land on a surface of the same depth (any class)
        checked += 1
    assert checked >= 3


def test_neighbouring_frames_give_consistent_sift_matches(sequence: Path) -> None:
    import cv2

    m = _manifest(sequence)
    cam = Camera.from_dict(m["camera"])
    gt = read_tum(sequence / m["poses"]["gt"])
    sift = cv2.SIFT_create()
    good_pairs = 0
    for a in range(len(m["frames"]) - 1):
        b = a + 1
        img = [cv2.imread(str(sequence / m["frames"][k]["image"]), cv2.IMREAD_GRAYSCALE)
               for k in (a, b)]
        kp_a, des_a = sift.detectAndCompute(img[0], None)
        kp_b, des_b = sift.detectAndCompute(img[1], None)
        if des_a is None or des_b is None:
            continue
        knn = cv2.BFMatcher().knnMatch(des_a, des_b, k=2)
        good = [p[0] for p in knn if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
        if len(good) < 30:
            continue
        uv_a = np.array([kp_a[g.queryIdx].pt for g in good])
        uv_b = np.array([kp_b[g.trainIdx].pt for g in good])
        depth_a = np.load(sequence / m["frames"][a]["depth"])
        d = depth_a[np.rint(uv_a[:, 1]).astype(int), np.rint(uv_a[:, 0]).astype(int)]
        keep = d > 0
        p_a = cam.backproject(uv_a[keep], d[keep], distorted=True)
        b_from_a = compose(invert(gt.poses[b]), gt.poses[a])
        uv_pred, front = cam.project(transform_points(b_from_a, p_a))
        err = np.linalg.norm(uv_pred - uv_b[keep], axis=1)
        assert np.median(err[front]) < 2.0
        assert np.mean(err[front] < 5.0) > 0.7
        good_pairs += 1
    assert good_pairs >= 3


def test_same_seed_same_files(tmp_path: Path, building) -> None:
    parts, polys, doors = building
    cfg = SimulatorConfig.small(frames=3)

    def digest(seq: Path) -> dict[str, str]:
        return {
            str(p.relative_to(seq)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(seq.rglob("*")) if p.is_file()
        }

    runs = []
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        simulate_world(parts, tmp_path / name, cfg, seed, polys, doors)
        runs.append(digest(tmp_path / name))
    assert runs[0] == runs[1]
    assert runs[0]["images/000000.png"] != runs[2]["images/000000.png"]


def test_refuses_to_overwrite_a_sequence(sequence: Path, building) -> None:
    parts, polys, doors = building
    with pytest.raises(SimError, match="already holds a sequence"):
        simulate_world(parts, sequence, SimulatorConfig.small(frames=1), 0, polys, doors)


@pytest.mark.slow
def test_worker_processes_do_not_change_the_files(tmp_path: Path, building) -> None:
    """Frames rendered by two spawned worker processes are byte-identical to in-process ones."""
    parts, polys, doors = building
    digests = []
    for workers in (1, 2):
        cfg = SimulatorConfig.small(frames=2, workers=workers)
        out = tmp_path / f"w{workers}"
        simulate_world(parts, out, cfg, 11, polys, doors)
        digests.append({
            str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file()
        })
    assert digests[0] == digests[1]


def test_clutter_stays_off_the_path_and_is_labelled(building) -> None:
    from scipy.spatial import cKDTree

    from bimcap.sim.clutter import place_clutter

    parts, polys, doors = building
    world = World.from_parts(parts)
    free = FreeSpace.from_polygons(world, polys, 0.0, doors)
    walk = plan_walk(free, 30.0, np.random.default_rng(2))
    placed = place_clutter(free, walk.path_xy, np.random.default_rng(3), density_per_m2=0.15)
    assert len(placed) >= 5
    tree = cKDTree(walk.path_xy)
    for obj in placed:
        assert obj.part.label == Label.CLUTTER
        # every vertex of the object is clear of the walking path by its margin
        d, _ = tree.query(obj.part.vertices[:, :2])
        assert d.min() >= 0.5
        assert obj.part.vertices[:, 2].min() == pytest.approx(0.0)  # stands on the floor
    # pairwise separation
    centres = np.array([o.center_xy for o in placed])
    radii = np.array([o.radius for o in placed])
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    assert (dist >= radii[:, None] + radii[None] + 0.2 - 1e-9).all()


def test_georeferenced_world_renders_like_the_one_at_the_origin() -> None:
    """The room moved to a georeferenced position (northing 5.4·10⁶ m, where float32 steps by
    0.5 m) and turned by 37°, seen from the moved pose: the same depth, labels and LiDAR ranges
    as at the origin (the world casts its rays relative to its own origin)."""
    from bimcap.geometry.poses import rotmat_to_quat

    c, s = np.cos(np.deg2rad(37.0)), np.sin(np.deg2rad(37.0))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([512_345.6, 5_401_234.5, 212.3])
    near = _room_world()
    parts = []
    for name, lab, lo, hi in [
        ("floor", Label.FLOOR, (-50, -50, -0.2), (50, 50, 0)),
        ("ceil", Label.CEILING, (-50, -50, 3), (50, 50, 3.2)),
        ("wall", Label.WALL, (4.0, -5, 0), (4.2, 5, 3)),
    ]:
        v, f = box_mesh(np.array(lo, float), np.array(hi, float))
        parts.append(MeshPart(name, lab, v @ rot.T + shift, f))
    far = World.from_parts(parts)
    assert np.allclose(far.world_vertices(), near.vertices @ rot.T + shift, atol=1e-4)
    cam = Camera(80, 60, 50.0, 50.0, 39.5, 29.5, (-0.05, 0.1, 0.001, -0.004, 0.0))
    r = camera_rotation(np.array([0.3]), np.array([-0.1]), np.array([0.0]))[0]
    pose_near = np.r_[0.3, 0.7, 1.5, rotmat_to_quat(r)]
    pose_far = np.r_[rot @ pose_near[:3] + shift, rotmat_to_quat(rot @ r)]
    f_near = Renderer(near, cam, TextureBank.bake(0)).render(pose_near, np.random.default_rng(0))
    f_far = Renderer(far, cam, TextureBank.bake(0)).render(pose_far, np.random.default_rng(0))
    assert np.abs(f_far.depth - f_near.depth).max() < 1e-3
    assert (f_far.labels == f_near.labels).mean() > 0.999
    lidar = LidarConfig(dropout=0.0, range_noise_m=0.0, range_noise_per_m=0.0)
    scan_near = LidarSimulator(near, lidar).scan(pose_near, np.random.default_rng(0))
    scan_far = LidarSimulator(far, lidar).scan(pose_far, np.random.default_rng(0))
    assert len(scan_near) == len(scan_far)
    assert np.abs(np.linalg.norm(scan_far[:, :3], axis=1)
                  - np.linalg.norm(scan_near[:, :3], axis=1)).max() < 1e-3
