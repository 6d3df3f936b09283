"""A tiny ray-cast test world for the features / front-end tests (not a test module itself).

A box room (6 × 5 × 2.8 m) with one column, rendered with Open3D's ``RaycastingScene`` through a
*distorted* plumb_bob camera: raw RGB images whose texture is 3-D value noise evaluated at the hit
point (view-consistent, so SIFT matches across frames), ground-truth z-depth and label images, and
ground-truth ``world_from_cam`` poses. :class:`SceneSequence` writes them as files and offers the
sequence interface the front end reads (until ``bimcap.dataset`` lands).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix
from bimcap.geometry.trajectory import Trajectory
from bimcap.labels import Label

ROOM = (6.0, 5.0, 2.8)  # x, y, z extent in metres; the floor is z = 0
COLUMN = ((3.8, 3.0), (4.2, 3.4))  # xy corners of a full-height column

#: A small camera with noticeable distortion so that undistortion is exercised.
TEST_CAMERA = Camera(320, 240, 240.0, 241.0, 161.3, 118.7, (-0.08, 0.03, 0.001, -0.0015, 0.0))

_TABLE = np.random.default_rng(1234).random(1 << 20)


def value_noise(p: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """Trilinear value noise in [0, 1] on a lattice of ``cell`` metres at points p (M, 3)."""
    q = p / cell
    i0 = np.floor(q).astype(np.int64)
    f = q - i0
    f = f * f * (3 - 2 * f)  # smoothstep: no lattice creases
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ix, iy, iz = i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz
                h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)
                val = _TABLE[h & ((1 << 20) - 1)]
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                w = w * (f[:, 2] if dz else 1 - f[:, 2])
                out += w * val
    return out


def look_pose(position: tuple[float, float, float], yaw_deg: float,
              pitch_deg: float) -> NDArray[np.float64]:
    """``world_from_cam`` (7,) of an OpenCV camera at ``position`` looking along yaw, pitched
    down."""
    yaw, pitch = np.deg2rad(yaw_deg), np.deg2rad(pitch_deg)
    fwd = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    m = np.eye(4)
    m[:3, :3] = np.stack([right, down, fwd], axis=1)
    m[:3, 3] = position
    return matrix_to_pose(m)


def default_poses(n: int = 6) -> NDArray[np.float64]:
    """(n, 7) a short walk along x, looking at the +y wall and the column, pitched down."""
    return np.stack(
        [
            look_pose((1.8 + 0.12 * k, 1.2 + 0.03 * k, 1.4), 60.0 - 2.0 * k, 22.0)
            for k in range(n)
        ]
    )


@dataclass
class Render:
    image: NDArray[np.uint8]  # (H, W, 3) raw, distorted
    depth: NDArray[np.float32]  # (H, W) z-depth of the raw image, 0 = no hit
    labels: NDArray[np.uint8]  # (H, W)


class Room:
    """The ray-casting scene: six room faces and a column, each with a label."""

    def __init__(self) -> None:
        import open3d as o3d

        self.scene = o3d.t.geometry.RaycastingScene()
        self.labels: dict[int, Label] = {}
        sx, sy, sz = ROOM
        t = 0.1
        boxes = [
            ((0, 0, -t), (sx, sy, 0), Label.FLOOR),
            ((0, 0, sz), (sx, sy, sz + t), Label.CEILING),
            ((-t, 0, 0), (0, sy, sz), Label.WALL),
            ((sx, 0, 0), (sx + t, sy, sz), Label.WALL),
            ((0, -t, 0), (sx, 0, sz), Label.WALL),
            ((0, sy, 0), (sx, sy + t, sz), Label.WALL),
            ((COLUMN[0][0], COLUMN[0][1], 0), (COLUMN[1][0], COLUMN[1][1], sz), Label.COLUMN),
        ]
        for lo, hi, lab in boxes:
            ext = np.subtract(hi, lo)
            mesh = o3d.geometry.TriangleMesh.create_box(*ext)
            mesh.translate(lo)
            gid = self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
            self.labels[int(gid)] = lab

    def render(self, camera: Camera, world_from_cam: NDArray[np.float64]) -> Render:
        import open3d as o3d

        rays_cam = camera.rays(camera.pixel_grid(), distorted=True)  # z = 1 per ray
        m = pose_to_matrix(world_from_cam)
        dirs = rays_cam @ m[:3, :3].T
        origin = np.broadcast_to(m[:3, 3], dirs.shape)
        rays = o3d.core.Tensor(np.concatenate([origin, dirs], axis=1).astype(np.float32))
        ans = self.scene.cast_rays(rays)
        t_hit = ans["t_hit"].numpy().astype(np.float64)  # in units of |dir|: the z-depth
        gid = ans["geometry_ids"].numpy()
        hit = np.isfinite(t_hit)
        depth = np.where(hit, t_hit, 0.0)
        labels = np.zeros(len(depth), np.uint8)
        for g, lab in self.labels.items():
            labels[hit & (gid == g)] = int(lab)
        p = origin + dirs * np.where(hit, t_hit, 0.0)[:, None]
        tex = 0.55 * value_noise(p, 0.035) + 0.3 * value_noise(p, 0.09) + 0.15 * value_noise(p, 0.3)
        gray = np.clip(np.where(hit, 20 + 235 * (tex - 0.2) / 0.6, 0), 0, 255)
        tint = np.array([[1.0, 0.97, 0.92]])
        rgb = np.clip(gray[:, None] * tint, 0, 255).astype(np.uint8)
        shape = (camera.height, camera.width)
        return Render(
            rgb.reshape(*shape, 3), depth.reshape(shape).astype(np.float32), labels.reshape(shape)
        )


#: LiDAR frame (x forward, y left, z up) → camera optical frame, 5 cm above the camera.
CAM_FROM_LIDAR = np.array([0.0, -0.05, 0.0, 0.5, -0.5, 0.5, 0.5])


def lidar_scan(room: Room, world_from_cam: NDArray[np.float64],
               beams: int = 64) -> NDArray[np.float32]:
    """A spinning-LiDAR scan ((M, 4) x y z intensity, LiDAR frame): ``beams`` rings ±25°, 0.4°
    steps."""
    import open3d as o3d

    from bimcap.geometry.poses import compose

    world_from_lidar = pose_to_matrix(compose(world_from_cam, CAM_FROM_LIDAR))
    el = np.deg2rad(np.linspace(-25.0, 25.0, beams))
    az = np.deg2rad(np.arange(0.0, 360.0, 0.4))
    e, a = np.meshgrid(el, az, indexing="ij")
    d_l = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)],
                   axis=-1).reshape(-1, 3)
    d_w = d_l @ world_from_lidar[:3, :3].T
    o = np.broadcast_to(world_from_lidar[:3, 3], d_w.shape)
    ans = room.scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d_w], 1).astype(np.float32)))
    t = ans["t_hit"].numpy().astype(np.float64)
    ok = np.isfinite(t)
    pts = d_l[ok] * t[ok, None]
    return np.concatenate([pts, np.ones((len(pts), 1))], axis=1).astype(np.float32)


@dataclass
class FrameFiles:
    timestamp: float
    image: str
    lidar: str | None
    labels: str | None
    depth: str | None


class SceneSequence:
    """Files of a rendered sequence plus the reader interface of ``bimcap.dataset.Sequence``."""

    def __init__(self, root: Path, camera: Camera, frames: list[FrameFiles],
                 gt: NDArray[np.float64]) -> None:
        self.root = root
        self.camera = camera
        self.frames = frames
        self.gt = gt
        self.cam_from_lidar = CAM_FROM_LIDAR.copy()

    @classmethod
    def write(
        cls,
        root: Path,
        camera: Camera = TEST_CAMERA,
        poses: NDArray[np.float64] | None = None,
        lidar: bool = False,
    ) -> SceneSequence:
        import cv2

        poses = default_poses() if poses is None else poses
        room = Room()
        frames = []
        for k in (root / "images", root / "depth", root / "labels", root / "lidar"):
            k.mkdir(parents=True, exist_ok=True)
        for i, pose in enumerate(poses):
            r = room.render(camera, pose)
            name = f"{i:06d}"
            cv2.imwrite(str(root / "images" / f"{name}.png"), r.image[:, :, ::-1])
            np.save(root / "depth" / f"{name}.npy", r.depth)
            cv2.imwrite(str(root / "labels" / f"{name}.png"), r.labels)
            scan = None
            if lidar:
                scan = f"lidar/{name}.bin"
                (root / scan).write_bytes(lidar_scan(room, pose).astype("<f4").tobytes())
            frames.append(
                FrameFiles(0.1 * i, f"images/{name}.png", scan, f"labels/{name}.png",
                           f"depth/{name}.npy")
            )
        return cls(root, camera, frames, np.asarray(poses))

    def load_lidar(self, index: int) -> NDArray[np.float32]:
        rel = self.frames[index].lidar
        if rel is None:
            raise FileNotFoundError(f"frame {index} has no LiDAR scan")
        return np.fromfile(self.root / rel, dtype="<f4").reshape(-1, 4)

    def load_image(self, index: int) -> NDArray[np.uint8]:
        import cv2

        path = self.root / self.frames[index].image
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"{path}: no such image")
        return np.ascontiguousarray(img[:, :, ::-1])

    def load_depth(self, index: int) -> NDArray[np.float32]:
        return np.load(self.root / str(self.frames[index].depth))

    def load_labels(self, index: int) -> NDArray[np.uint8]:
        import cv2

        return cv2.imread(str(self.root / str(self.frames[index].labels)), cv2.IMREAD_UNCHANGED)

    def trajectory(self, name: str) -> Trajectory:
        return Trajectory(np.array([f.timestamp for f in self.frames]), self.gt)
