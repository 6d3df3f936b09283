"""A tiny ray-cast box room for tests and benchmarks of the front end (no simulator needed).

The room is an axis-aligned box ``[0, size_x] × [0, size_y] × [0, height]`` in the world (z up,
metres) with a floor, a ceiling, four walls and one free-standing rectangular column. Open3D's
CPU ``RaycastingScene`` gives, for a camera pose, the exact z-depth and label of every pixel of
the **raw** (possibly distorted) image, and a spinning LiDAR scan (rings of rays) from the LiDAR
origin given by ``cam_from_lidar``. The RGB image has a procedural texture (per-class tint times a
checker/sine pattern of the hit point) so that image-guided methods see edges at class borders.

This is test scaffolding, not the project simulator (``bimcap.sim``): the front end must work on
the simulator's sequences as well; this module only makes the fusion stage testable on its own.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry import Camera, compose, quat_to_rotmat
from bimcap.labels import LABEL_COLORS, Label

F64 = NDArray[np.float64]

#: LiDAR frame (x forward, y left, z up) to camera optical frame (x right, y down, z forward).
R_CAM_FROM_LIDAR_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class BoxRoom:
    """Geometry of the synthetic room (metres, world frame)."""

    size_x: float = 8.0
    size_y: float = 6.0
    height: float = 2.8
    column_center: tuple[float, float] = (5.0, 2.2)
    column_half: tuple[float, float] = (0.25, 0.25)
    round_column: bool = False  #: a cylinder of radius ``column_half[0]`` instead of a box
    #: boxes ``(x0, y0, z0, x1, y1, z1)`` not in the BIM (tables, crates), labelled CLUTTER
    clutter: tuple[tuple[float, float, float, float, float, float], ...] = ()


@dataclass(frozen=True)
class SpinningLidar:
    """A ring LiDAR: ``channels`` beams evenly over ``vertical_fov_deg``, one ray per azimuth
    step."""

    channels: int = 32
    vertical_fov_deg: tuple[float, float] = (-25.0, 25.0)
    azimuth_step_deg: float = 0.2
    max_range_m: float = 100.0
    noise_m: float = 0.0


@dataclass(frozen=True)
class SyntheticFrame:
    """One rendered frame.

    Attributes
    ----------
    image: (H, W, 3) uint8 RGB of the raw camera.
    depth: (H, W) float32 z-depth in metres of the raw image (0 = no hit).
    labels: (H, W) uint8 :class:`Label` ids of the raw image.
    points_in_lidar: (M, 3) float64 LiDAR returns in the LiDAR frame.
    world_from_cam: (7,) TUM-order camera pose.
    cam_from_lidar: (7,) TUM-order extrinsic.
    camera: the raw camera.
    """

    image: NDArray[np.uint8]
    depth: NDArray[np.float32]
    labels: NDArray[np.uint8]
    points_in_lidar: F64
    world_from_cam: F64
    cam_from_lidar: F64
    camera: Camera


def _box_mesh(lo: F64, hi: F64):  # type: ignore[no-untyped-def]
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    mesh.translate(lo)
    return o3d.t.geometry.TriangleMesh.from_legacy(mesh)


class BoxRoomScene:
    """Ray-casting scene of a :class:`BoxRoom`; geometry ids map to labels."""

    def __init__(self, room: BoxRoom | None = None) -> None:
        import open3d as o3d

        self.room = room or BoxRoom()
        r = self.room
        t = 0.2  # slab/wall thickness outside the room
        parts: list[tuple[Label, F64, F64]] = [
            (Label.FLOOR, np.array([-t, -t, -t]), np.array([r.size_x + t, r.size_y + t, 0.0])),
            (Label.CEILING, np.array([-t, -t, r.height]),
             np.array([r.size_x + t, r.size_y + t, r.height + t])),
            (Label.WALL, np.array([-t, -t, 0.0]), np.array([0.0, r.size_y + t, r.height])),
            (Label.WALL, np.array([r.size_x, -t, 0.0]),
             np.array([r.size_x + t, r.size_y + t, r.height])),
            (Label.WALL, np.array([0.0, -t, 0.0]), np.array([r.size_x, 0.0, r.height])),
            (Label.WALL, np.array([0.0, r.size_y, 0.0]),
             np.array([r.size_x, r.size_y + t, r.height])),
        ]
        for box in r.clutter:
            parts.append((Label.CLUTTER, np.array(box[:3], dtype=np.float64),
                          np.array(box[3:], dtype=np.float64)))
        cx, cy = r.column_center
        hx, hy = r.column_half
        if not r.round_column:
            parts.append((Label.COLUMN, np.array([cx - hx, cy - hy, 0.0]),
                          np.array([cx + hx, cy + hy, r.height])))
        self._scene = o3d.t.geometry.RaycastingScene()
        ids = []
        for _, lo, hi in parts:
            ids.append(self._scene.add_triangles(_box_mesh(lo, hi)))
        if r.round_column:
            cyl = o3d.geometry.TriangleMesh.create_cylinder(radius=hx, height=r.height,
                                                            resolution=64, split=4)
            cyl.translate(np.array([cx, cy, r.height / 2.0]))
            ids.append(self._scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(cyl)))
            parts.append((Label.COLUMN, np.zeros(3), np.zeros(3)))
        lut = np.zeros(max(ids) + 2, dtype=np.uint8)
        for (label, _, _), gid in zip(parts, ids, strict=True):
            lut[gid] = int(label)
        self._lut = lut

    def cast(self, origins: F64, directions: F64) -> tuple[F64, NDArray[np.uint8], F64]:
        """Cast rays (M, 3) world origins / directions → (t_hit (M,), labels (M,), hit points
        (M, 3)).

        ``t_hit`` is in units of the direction's length (inf for no hit).
        """
        import open3d as o3d

        rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
        ans = self._scene.cast_rays(o3d.core.Tensor(rays))
        t_hit = ans["t_hit"].numpy().astype(np.float64)
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t_hit)
        labels = np.zeros(len(t_hit), dtype=np.uint8)
        labels[hit] = self._lut[np.clip(gid[hit], 0, len(self._lut) - 1)]
        pts = origins + directions * np.where(hit, t_hit, 0.0)[:, None]
        return t_hit, labels, pts

    def render(
        self,
        camera: Camera,
        world_from_cam: F64,
        cam_from_lidar: F64,
        lidar: SpinningLidar | None = None,
        seed: int = 0,
    ) -> SyntheticFrame:
        """Render the raw image, GT depth and labels, and one LiDAR scan."""
        rng = np.random.default_rng(seed)
        world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
        r_wc = quat_to_rotmat(world_from_cam[3:])
        rays_cam = camera.rays(camera.pixel_grid(), distorted=True)  # z = 1 → t_hit = z-depth
        dirs = rays_cam @ r_wc.T
        origins = np.broadcast_to(world_from_cam[:3], dirs.shape)
        t_hit, labels, pts = self.cast(np.ascontiguousarray(origins), dirs)
        hit = np.isfinite(t_hit)
        depth = np.where(hit, t_hit, 0.0).astype(np.float32).reshape(camera.height, camera.width)
        labels_img = labels.reshape(camera.height, camera.width)
        # procedural texture: class tint × (checker of 0.25 m cells + fine sine) of the hit point
        cell = np.floor(pts / 0.25).astype(np.int64).sum(axis=1) % 2
        fine = 0.5 + 0.5 * np.sin(pts[:, 0] * 23.0) * np.sin(pts[:, 1] * 19.0 + pts[:, 2] * 17.0)
        shade = (0.55 + 0.25 * cell + 0.2 * fine)[:, None]
        rgb = (LABEL_COLORS[labels].astype(np.float64) * shade).clip(0, 255).astype(np.uint8)
        image = rgb.reshape(camera.height, camera.width, 3)

        lidar = lidar or SpinningLidar()
        world_from_lidar = compose(world_from_cam, cam_from_lidar)
        elev = np.deg2rad(np.linspace(*lidar.vertical_fov_deg, lidar.channels))
        azim = np.deg2rad(np.arange(0.0, 360.0, lidar.azimuth_step_deg))
        el, az = np.meshgrid(elev, azim, indexing="ij")
        d_lidar = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)],
                           -1).reshape(-1, 3)
        r_wl = quat_to_rotmat(world_from_lidar[3:])
        d_world = d_lidar @ r_wl.T
        o_world = np.broadcast_to(world_from_lidar[:3], d_world.shape)
        rng_hit, _, _ = self.cast(np.ascontiguousarray(o_world), d_world)
        ok = np.isfinite(rng_hit) & (rng_hit < lidar.max_range_m)
        rr = rng_hit[ok] + (rng.normal(0.0, lidar.noise_m, ok.sum()) if lidar.noise_m > 0 else 0.0)
        points_in_lidar = d_lidar[ok] * rr[:, None]
        return SyntheticFrame(
            image=image,
            depth=depth,
            labels=labels_img,
            points_in_lidar=points_in_lidar,
            world_from_cam=world_from_cam,
            cam_from_lidar=np.asarray(cam_from_lidar, dtype=np.float64),
            camera=camera,
        )


def default_camera(width: int = 1032, height: int = 772, distorted: bool = False) -> Camera:
    """A camera like ConSLAM's at half resolution (fx ≈ 1176 px), optionally with its distortion."""
    dist = (-0.054366, 0.118389, 0.001781, -0.003908, 0.0) if distorted else (0.0,) * 5
    s = width / 1032.0
    return Camera(width, height, 1175.9 * s, 1176.8 * s, 508.4 * s, 394.1 * s, dist)  # type: ignore[arg-type]


def narrow_ring_rig(noise_m: float, focal_scale: float = 1.5) -> tuple[Camera, SpinningLidar]:
    """The hard settings' rig: the 516×386 camera with its focal length times ``focal_scale``
    (a narrower view) and a VLP-16-like ring LiDAR (16 channels, ±15°) whose ranges have
    ``noise_m`` Gaussian noise (metres)."""
    cam = default_camera(516, 386)
    cam = replace(cam, fx=cam.fx * focal_scale, fy=cam.fy * focal_scale)
    return cam, SpinningLidar(channels=16, vertical_fov_deg=(-15.0, 15.0), noise_m=noise_m)


def look_pose(eye: F64, yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> F64:
    """``world_from_cam`` (7,) of a camera at ``eye`` looking along yaw (about z), pitched down by
    ``pitch_deg`` (positive looks down) and rolled about its optical axis."""
    from scipy.spatial.transform import Rotation

    # camera looking along world +x with z up: optical z = world x, optical x = -world y, y = -z
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rot = (
        Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
        @ Rotation.from_euler("y", pitch_deg, degrees=True).as_matrix()
        @ base
        @ Rotation.from_euler("z", roll_deg, degrees=True).as_matrix()
    )
    q = Rotation.from_matrix(rot).as_quat()
    return np.concatenate([np.asarray(eye, dtype=np.float64), q])


def default_cam_from_lidar() -> F64:
    """LiDAR 8 cm above and 5 cm behind the camera (so that parallax hides some returns)."""
    from bimcap.geometry import rotmat_to_quat

    # p_in_cam = R p_in_lidar + t; LiDAR origin in the camera frame = t
    t = np.array([0.0, -0.08, -0.05])
    return np.concatenate([t, rotmat_to_quat(R_CAM_FROM_LIDAR_AXES)])


def render_default_frames(
    n: int = 3,
    camera: Camera | None = None,
    lidar: SpinningLidar | None = None,
    seed: int = 0,
    room: BoxRoom | None = None,
) -> list[SyntheticFrame]:
    """``n`` frames from varied handheld-like poses in the room (default :class:`BoxRoom`;
    deterministic)."""
    rng = np.random.default_rng(seed)
    scene = BoxRoomScene(room)
    cam = camera or default_camera()
    frames = []
    for i in range(n):
        eye = np.array([1.2 + 0.3 * i, 2.0 + rng.uniform(-0.4, 0.4), 1.45 + rng.uniform(-0.1, 0.1)])
        yaw = rng.uniform(-25.0, 25.0) + (15.0 if i % 2 else 0.0)
        pitch = rng.uniform(5.0, 15.0)
        roll = rng.uniform(-3.0, 3.0)
        frames.append(scene.render(cam, look_pose(eye, yaw, pitch, roll), default_cam_from_lidar(),
                                   lidar, seed + i))
    return frames


__all__ = [
    "BoxRoom",
    "BoxRoomScene",
    "SpinningLidar",
    "SyntheticFrame",
    "default_cam_from_lidar",
    "default_camera",
    "look_pose",
    "render_default_frames",
]
