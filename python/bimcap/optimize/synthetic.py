"""A realistic random solver problem with known ground truth (tests, benches, ``bimcap solve-demo``).

The world is a rectangular room / corridor of ``size`` (x, y) metres and ``height`` metres: a BIM
with a floor plane (z = 0), a ceiling plane (z = height), four wall segments and square columns.
A camera (640 × 480 pinhole, OpenCV optical frame) walks an elliptic loop at about 1.4 m,
looking along its path with some yaw wobble, pitch and roll. From the ground-truth poses every term
gets observations with noise: G (keypoint matches between frames i and i + k with depths, or
landmark tracks), F / Ce (floor / ceiling points in the camera frame), W / Co (wall / column points).
The initial poses are the ground truth with a drift: a random walk in translation and
in yaw / pitch, zero at frame 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bimcap.labels import Label
from bimcap.optimize.problem import Problem

_T = TypeVar("_T", bound=np.generic)
F64 = NDArray[np.float64]

#: cam → world rotation of a camera looking along +x with z up: x_cam → −y, y_cam → −z, z_cam → +x.
_R_BASE = Rotation.from_matrix(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]))


@dataclass
class SyntheticConfig:
    """Size and noise of a synthetic problem. Counts are per frame (G: per frame pair)."""

    num_frames: int = 100
    size: tuple[float, float] = (12.0, 6.0)  #: room x, y extent, metres
    height: float = 3.0  #: floor-to-ceiling, metres
    num_columns: int = 2
    intrinsics: tuple[float, float, float, float] = (500.0, 500.0, 319.5, 239.5)
    image_size: tuple[int, int] = (640, 480)
    max_depth: float = 10.0
    matches_per_pair: int = 60
    pair_offsets: tuple[int, ...] = (1, 2)
    landmarks_per_frame: int = 40  #: new landmarks seeded per frame (LANDMARK observations)
    floor_per_frame: int = 60
    ceiling_per_frame: int = 40
    wall_per_frame: int = 80
    column_per_frame: int = 20
    point_noise: float = 0.01  #: metres, on semantic p_in_cam
    pixel_noise: float = 0.5  #: pixels
    depth_noise: float = 0.01  #: metres
    drift_translation_sigma: float = 0.01  #: metres per frame (random walk)
    drift_yaw_sigma_deg: float = 0.1  #: degrees per frame (random walk)
    drift_pitch_sigma_deg: float = 0.05
    fix_first: bool = True  #: hold frame 0 (drift-free) constant
    seed: int = 0


@dataclass
class SyntheticProblem:
    """A generated problem and its truth.

    Attributes
    ----------
    problem: the solver problem; ``problem.poses`` are the drifted initial poses.
    gt_poses: (N, 7) ground-truth world_from_cam, TUM order.
    gt_track_points: (P, 3) true landmark positions.
    config: what generated it.
    """

    problem: Problem
    gt_poses: F64
    gt_track_points: F64
    config: SyntheticConfig = field(default_factory=SyntheticConfig)


def pose_errors(est: F64, gt: F64) -> tuple[float, float]:
    """(translation RMSE in m, rotation RMSE in degrees) between two (N, 7) pose arrays, no alignment."""
    dt = np.linalg.norm(est[:, :3] - gt[:, :3], axis=1)
    rel = Rotation.from_quat(est[:, 3:7]).inv() * Rotation.from_quat(gt[:, 3:7])
    ang = np.degrees(rel.magnitude())
    return float(np.sqrt(np.mean(dt**2))), float(np.sqrt(np.mean(ang**2)))


def _building(cfg: SyntheticConfig) -> tuple[F64, NDArray[np.int32], F64, F64]:
    lx, ly = cfg.size
    segs = [[0, 0, lx, 0], [lx, 0, lx, ly], [lx, ly, 0, ly], [0, ly, 0, 0]]
    cls = [int(Label.WALL)] * 4
    half = 0.2
    for k in range(cfg.num_columns):
        cx = lx * (k + 1) / (cfg.num_columns + 1)
        cy = ly / 2
        x0, x1, y0, y1 = cx - half, cx + half, cy - half, cy + half
        segs += [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]
        cls += [int(Label.COLUMN)] * 4
    segments = np.array(segs, dtype=np.float64)
    segment_z = np.tile([0.0, cfg.height], (len(segments), 1))
    planes = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, -cfg.height]])
    return segments, np.array(cls, dtype=np.int32), segment_z, planes


def _trajectory(cfg: SyntheticConfig, rng: np.random.Generator) -> F64:
    lx, ly = cfg.size
    n = cfg.num_frames
    phase = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    rx, ry = lx / 2 - 1.5, ly / 2 - 1.0
    x = lx / 2 + rx * np.cos(phase)
    y = ly / 2 + ry * np.sin(phase)
    z = 1.4 + 0.03 * np.sin(7 * phase) + 0.01 * rng.standard_normal(n)
    heading = np.arctan2(ry * np.cos(phase), -rx * np.sin(phase))
    yaw = heading + np.radians(15.0) * np.sin(3 * phase)
    pitch = np.radians(5.0) * np.sin(2 * phase) + np.radians(1.0) * rng.standard_normal(n)
    roll = np.radians(2.0) * rng.standard_normal(n)
    rot = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1)) * _R_BASE
    poses = np.empty((n, 7))
    poses[:, :3] = np.stack([x, y, z], axis=1)
    poses[:, 3:] = rot.as_quat()
    return poses


def _drift(gt: F64, cfg: SyntheticConfig, rng: np.random.Generator) -> F64:
    n = len(gt)
    dt = np.cumsum(cfg.drift_translation_sigma * rng.standard_normal((n, 3)), axis=0)
    dyaw = np.cumsum(np.radians(cfg.drift_yaw_sigma_deg) * rng.standard_normal(n))
    dpitch = np.cumsum(np.radians(cfg.drift_pitch_sigma_deg) * rng.standard_normal(n))
    dt -= dt[0]
    dyaw -= dyaw[0]
    dpitch -= dpitch[0]
    delta = Rotation.from_euler("ZY", np.stack([dyaw, dpitch], axis=1))
    out = gt.copy()
    out[:, :3] += dt
    out[:, 3:] = (delta * Rotation.from_quat(gt[:, 3:])).as_quat()
    return out


class _Camera:
    def __init__(self, cfg: SyntheticConfig) -> None:
        self.k = np.asarray(cfg.intrinsics, dtype=np.float64)
        self.w, self.h = cfg.image_size
        self.max_depth = cfg.max_depth

    def to_cam(self, pose: F64, p_in_world: F64) -> F64:
        p_in_cam: F64 = Rotation.from_quat(pose[3:]).inv().apply(p_in_world - pose[:3])
        return p_in_cam

    def project(self, p_in_cam: F64) -> tuple[F64, NDArray[np.bool_]]:
        z = p_in_cam[:, 2]
        ok = (z > 0.3) & (z < self.max_depth)
        zs = np.where(ok, z, 1.0)
        uv = np.stack(
            [self.k[0] * p_in_cam[:, 0] / zs + self.k[2], self.k[1] * p_in_cam[:, 1] / zs + self.k[3]],
            axis=1,
        )
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= self.w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= self.h - 1)
        return uv, ok


def _sample_surfaces(
    rng: np.random.Generator, count: int, cfg: SyntheticConfig, segments: F64, seg_mask: NDArray[np.bool_]
) -> F64:
    """``count`` world points on the segments selected by ``seg_mask`` (walls or columns)."""
    segs = segments[seg_mask]
    lengths = np.linalg.norm(segs[:, 2:] - segs[:, :2], axis=1)
    idx = rng.choice(len(segs), size=count, p=lengths / lengths.sum())
    t = rng.random(count)
    xy = segs[idx, :2] + t[:, None] * (segs[idx, 2:] - segs[idx, :2])
    z = rng.uniform(0.1, cfg.height - 0.1, count)
    return np.column_stack([xy, z])


def _sample_plane(rng: np.random.Generator, count: int, cfg: SyntheticConfig, z: float) -> F64:
    lx, ly = cfg.size
    return np.column_stack([rng.uniform(0, lx, count), rng.uniform(0, ly, count), np.full(count, z)])


def _visible(
    rng: np.random.Generator, cam: _Camera, pose: F64, candidates: F64, limit: int
) -> tuple[F64, F64]:
    """Up to ``limit`` candidates visible from ``pose``: (p_in_world, p_in_cam)."""
    p_cam = cam.to_cam(pose, candidates)
    _, ok = cam.project(p_cam)
    idx = np.flatnonzero(ok)[:limit]
    return candidates[idx], p_cam[idx]


def make_synthetic_problem(config: SyntheticConfig | None = None, **overrides: object) -> SyntheticProblem:
    """Generate a problem; ``overrides`` replace fields of ``config`` (e.g. ``num_frames=300``)."""
    cfg = config if config is not None else SyntheticConfig()
    if overrides:
        cfg = SyntheticConfig(**{**cfg.__dict__, **overrides})
    rng = np.random.default_rng(cfg.seed)
    segments, segment_class, segment_z, planes = _building(cfg)
    gt = _trajectory(cfg, rng)
    init = _drift(gt, cfg, rng)
    cam = _Camera(cfg)
    n = cfg.num_frames
    wall_mask = segment_class == int(Label.WALL)
    col_mask = segment_class == int(Label.COLUMN)

    sem: dict[str, list[F64]] = {k: [] for k in ("floor", "ceiling", "wall", "column")}
    sem_frame: dict[str, list[NDArray[np.int32]]] = {k: [] for k in sem}
    per_frame = {
        "floor": cfg.floor_per_frame,
        "ceiling": cfg.ceiling_per_frame,
        "wall": cfg.wall_per_frame,
        "column": cfg.column_per_frame,
    }
    for i in range(n):
        for kind, count in per_frame.items():
            if count <= 0:
                continue
            if kind == "floor":
                cand = _sample_plane(rng, 6 * count, cfg, 0.0)
            elif kind == "ceiling":
                cand = _sample_plane(rng, 6 * count, cfg, cfg.height)
            elif kind == "wall":
                cand = _sample_surfaces(rng, 6 * count, cfg, segments, wall_mask)
            else:
                if not col_mask.any():
                    continue
                cand = _sample_surfaces(rng, 20 * count, cfg, segments, col_mask)
            _, p_cam = _visible(rng, cam, gt[i], cand, count)
            sem[kind].append(p_cam + cfg.point_noise * rng.standard_normal(p_cam.shape))
            sem_frame[kind].append(np.full(len(p_cam), i, dtype=np.int32))

    # G: matches between frames i and i + k on all surfaces.
    m_frames, m_uv, m_depth = [], [], []
    for i in range(n):
        for off in cfg.pair_offsets:
            j = i + off
            if j >= n or cfg.matches_per_pair <= 0:
                continue
            cand = np.concatenate(
                [
                    _sample_surfaces(rng, 4 * cfg.matches_per_pair, cfg, segments, wall_mask),
                    _sample_plane(rng, cfg.matches_per_pair, cfg, 0.0),
                    _sample_plane(rng, cfg.matches_per_pair, cfg, cfg.height),
                ]
            )
            pa, pb = cam.to_cam(gt[i], cand), cam.to_cam(gt[j], cand)
            uva, oka = cam.project(pa)
            uvb, okb = cam.project(pb)
            idx = np.flatnonzero(oka & okb)[: cfg.matches_per_pair]
            if not len(idx):
                continue
            uv = np.column_stack([uva[idx], uvb[idx]]) + cfg.pixel_noise * rng.standard_normal((len(idx), 4))
            depth = np.column_stack([pa[idx, 2], pb[idx, 2]]) + cfg.depth_noise * rng.standard_normal((len(idx), 2))
            m_frames.append(np.tile([i, j], (len(idx), 1)).astype(np.int32))
            m_uv.append(uv)
            m_depth.append(depth)

    # G as landmarks: a pool of wall points, each observed by every frame that sees it.
    num_landmarks = cfg.landmarks_per_frame * n
    gt_points = (
        _sample_surfaces(rng, num_landmarks, cfg, segments, wall_mask) if num_landmarks else np.zeros((0, 3))
    )
    t_frame, t_point, t_uv, t_depth = [], [], [], []
    for i in range(n):
        if not len(gt_points):
            break
        p_cam = cam.to_cam(gt[i], gt_points)
        uv, ok = cam.project(p_cam)
        idx = np.flatnonzero(ok)[: 6 * cfg.landmarks_per_frame]
        t_frame.append(np.full(len(idx), i, dtype=np.int32))
        t_point.append(idx.astype(np.int32))
        t_uv.append(uv[idx] + cfg.pixel_noise * rng.standard_normal((len(idx), 2)))
        t_depth.append(p_cam[idx, 2] + cfg.depth_noise * rng.standard_normal(len(idx)))
    track_obs_frame = _cat(t_frame, np.int32, ())
    track_obs_point = _cat(t_point, np.int32, ())
    track_obs_uv = _cat(t_uv, np.float64, (2,))
    track_obs_depth = _cat(t_depth, np.float64, ())
    # Keep only observed landmarks, renumbered; initialise each from its first observation
    # back-projected with the drifted pose (what a front end would do).
    used = np.unique(track_obs_point)
    remap = np.full(len(gt_points), -1, dtype=np.int32)
    remap[used] = np.arange(len(used), dtype=np.int32)
    track_obs_point = remap[track_obs_point]
    gt_points = gt_points[used]
    track_points = np.zeros_like(gt_points)
    if len(track_obs_point):
        first = np.unique(track_obs_point, return_index=True)[1]
        k = np.asarray(cfg.intrinsics)
        obs_uv, obs_d, obs_f = track_obs_uv[first], track_obs_depth[first], track_obs_frame[first]
        p_cam = np.column_stack(
            [(obs_uv[:, 0] - k[2]) / k[0] * obs_d, (obs_uv[:, 1] - k[3]) / k[1] * obs_d, obs_d]
        )
        track_points = Rotation.from_quat(init[obs_f, 3:]).apply(p_cam) + init[obs_f, :3]

    def plane_index(kind: str) -> NDArray[np.int32]:
        count = sum(len(a) for a in sem[kind])
        return np.full(count, 0 if kind == "floor" else 1, dtype=np.int32)

    pose_fixed = np.zeros(n, dtype=np.int32)
    if cfg.fix_first:
        pose_fixed[0] = 1
    problem = Problem(
        poses=init,
        timestamps=np.arange(n, dtype=np.float64) * 0.1,
        pose_fixed=pose_fixed,
        cameras=np.asarray([cfg.intrinsics], dtype=np.float64),
        frame_camera=np.zeros(n, dtype=np.int32),
        match_frames=_cat(m_frames, np.int32, (2,)),
        match_uv=_cat(m_uv, np.float64, (4,)),
        match_depth=_cat(m_depth, np.float64, (2,)),
        track_obs_frame=track_obs_frame,
        track_obs_point=track_obs_point,
        track_obs_uv=track_obs_uv,
        track_obs_depth=track_obs_depth,
        track_points=track_points,
        floor_frame=_cat(sem_frame["floor"], np.int32, ()),
        floor_p_in_cam=_cat(sem["floor"], np.float64, (3,)),
        floor_plane=plane_index("floor"),
        ceiling_frame=_cat(sem_frame["ceiling"], np.int32, ()),
        ceiling_p_in_cam=_cat(sem["ceiling"], np.float64, (3,)),
        ceiling_plane=plane_index("ceiling"),
        planes=planes,
        wall_frame=_cat(sem_frame["wall"], np.int32, ()),
        wall_p_in_cam=_cat(sem["wall"], np.float64, (3,)),
        column_frame=_cat(sem_frame["column"], np.int32, ()),
        column_p_in_cam=_cat(sem["column"], np.float64, (3,)),
        segments=segments,
        segment_class=segment_class,
        segment_z=segment_z,
    )
    return SyntheticProblem(problem=problem, gt_poses=gt, gt_track_points=gt_points, config=cfg)


def _cat(parts: Sequence[NDArray[_T]], dtype: type[_T], tail: tuple[int, ...]) -> NDArray[_T]:
    """The parts stacked along axis 0 as one contiguous ``dtype`` array ((0, *tail) if none)."""
    if not parts:
        return np.zeros((0, *tail), dtype=dtype)
    return np.ascontiguousarray(np.concatenate(parts), dtype=dtype)
