"""A realistic random solver problem with known ground truth.

Used by the tests, the benches and ``bimcap solve-demo``.

The world is a rectangular room / corridor of ``size`` (x, y) metres and ``height`` metres: a BIM
with a floor plane (z = 0), a ceiling plane (z = height), four wall segments and square columns.
A camera (640 × 480 pinhole, OpenCV optical frame) walks an elliptic loop at about 1.4 m,
looking along its path with some yaw wobble, pitch and roll. From the ground-truth poses every term
gets observations with noise: G (keypoint matches between frames i and i + k with depths, or
landmark tracks), F / Ce (floor / ceiling points in the camera frame), W / Co (wall / column
points).
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
    """(translation RMSE in m, rotation RMSE in degrees) between two (N, 7) pose arrays.

    No alignment: both arrays are in the same world frame.
    """
    dt = np.linalg.norm(est[:, :3] - gt[:, :3], axis=1)
    rel = Rotation.from_quat(est[:, 3:7]).inv() * Rotation.from_quat(gt[:, 3:7])
    ang = np.degrees(rel.magnitude())
    return float(np.sqrt(np.mean(dt**2))), float(np.sqrt(np.mean(ang**2)))


@dataclass(frozen=True)
class _Building:
    """The synthetic BIM: floor-plan segments with their class and z range, floor / ceiling planes.

    Attributes
    ----------
    segments: (S, 4) x0, y0, x1, y1 in metres (world).
    segment_class: (S,) :class:`Label` of each segment (WALL or COLUMN).
    segment_z: (S, 2) z range of each segment, metres.
    planes: (2, 4) floor and ceiling planes, ``n · p + d = 0``.
    """

    segments: F64
    segment_class: NDArray[np.int32]
    segment_z: F64
    planes: F64

    @property
    def wall_mask(self) -> NDArray[np.bool_]:
        """(S,) which segments are walls."""
        mask: NDArray[np.bool_] = self.segment_class == int(Label.WALL)
        return mask

    @property
    def column_mask(self) -> NDArray[np.bool_]:
        """(S,) which segments are column faces."""
        mask: NDArray[np.bool_] = self.segment_class == int(Label.COLUMN)
        return mask


def _building(cfg: SyntheticConfig) -> _Building:
    """The room's four walls, ``cfg.num_columns`` square columns on its mid line, floor, ceiling."""
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
    return _Building(
        segments=segments,
        segment_class=np.array(cls, dtype=np.int32),
        segment_z=np.tile([0.0, cfg.height], (len(segments), 1)),
        planes=np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, -cfg.height]]),
    )


def _trajectory(cfg: SyntheticConfig, rng: np.random.Generator) -> F64:
    """(N, 7) ground-truth world_from_cam of an elliptic loop at about 1.4 m (TUM order)."""
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
    """(N, 7) ``gt`` with a random-walk drift in translation, yaw and pitch, zero at frame 0."""
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
            [
                self.k[0] * p_in_cam[:, 0] / zs + self.k[2],
                self.k[1] * p_in_cam[:, 1] / zs + self.k[3],
            ],
            axis=1,
        )
        ok &= (
            (uv[:, 0] >= 0) & (uv[:, 0] <= self.w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= self.h - 1)
        )
        return uv, ok


def _sample_surfaces(
    rng: np.random.Generator,
    count: int,
    cfg: SyntheticConfig,
    segments: F64,
    seg_mask: NDArray[np.bool_],
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
    """``count`` uniform world points on the horizontal plane at height ``z`` within the room."""
    lx, ly = cfg.size
    return np.column_stack(
        [rng.uniform(0, lx, count), rng.uniform(0, ly, count), np.full(count, z)]
    )


def _visible(
    rng: np.random.Generator, cam: _Camera, pose: F64, candidates: F64, limit: int
) -> tuple[F64, F64]:
    """Up to ``limit`` candidates visible from ``pose``: (p_in_world, p_in_cam)."""
    p_cam = cam.to_cam(pose, candidates)
    _, ok = cam.project(p_cam)
    idx = np.flatnonzero(ok)[:limit]
    return candidates[idx], p_cam[idx]


#: The semantic (BIM) terms' kinds, in the order they are sampled per frame.
_SEMANTIC_KINDS: tuple[str, ...] = ("floor", "ceiling", "wall", "column")


@dataclass
class _Semantic:
    """The F / Ce / W / Co samples of all frames, per kind (``"floor"`` ...).

    Attributes
    ----------
    p_in_cam: kind → (M, 3) noisy sample points in the camera frame, metres.
    frame: kind → (M,) frame index of each sample.
    """

    p_in_cam: dict[str, F64]
    frame: dict[str, NDArray[np.int32]]


@dataclass
class _Matches:
    """G as pairwise matches: (M, 2) frames i, j; (M, 4) noisy uv in i, j (px); (M, 2) depth, m."""

    frames: NDArray[np.int32]
    uv: F64
    depth: F64


@dataclass
class _Tracks:
    """G as landmark tracks, restricted to the observed landmarks and renumbered.

    Attributes
    ----------
    obs_frame, obs_point: (T,) frame and landmark of each observation.
    obs_uv: (T, 2) noisy pixel, px.
    obs_depth: (T,) noisy depth, metres.
    points: (P, 3) initial landmark positions (first observation back-projected, drifted pose).
    gt_points: (P, 3) true landmark positions, metres (world).
    """

    obs_frame: NDArray[np.int32]
    obs_point: NDArray[np.int32]
    obs_uv: F64
    obs_depth: F64
    points: F64
    gt_points: F64


def _with_overrides(
    config: SyntheticConfig | None, overrides: dict[str, object]
) -> SyntheticConfig:
    """``config`` (default: :class:`SyntheticConfig()`) with ``overrides`` replacing its fields."""
    cfg = config if config is not None else SyntheticConfig()
    if overrides:
        cfg = SyntheticConfig(**{**cfg.__dict__, **overrides})
    return cfg


def _semantic_candidates(
    rng: np.random.Generator, cfg: SyntheticConfig, building: _Building, kind: str, count: int
) -> F64 | None:
    """World candidates for one frame's ``count`` samples of ``kind``; None if the BIM has none."""
    if kind == "floor":
        return _sample_plane(rng, 6 * count, cfg, 0.0)
    if kind == "ceiling":
        return _sample_plane(rng, 6 * count, cfg, cfg.height)
    if kind == "wall":
        return _sample_surfaces(rng, 6 * count, cfg, building.segments, building.wall_mask)
    if not building.column_mask.any():
        return None
    return _sample_surfaces(rng, 20 * count, cfg, building.segments, building.column_mask)


def _semantic_samples(
    rng: np.random.Generator, cfg: SyntheticConfig, cam: _Camera, gt: F64, building: _Building
) -> _Semantic:
    """Per frame and kind, up to the configured count of visible surface points, with noise."""
    per_frame = {
        "floor": cfg.floor_per_frame,
        "ceiling": cfg.ceiling_per_frame,
        "wall": cfg.wall_per_frame,
        "column": cfg.column_per_frame,
    }
    points: dict[str, list[F64]] = {k: [] for k in _SEMANTIC_KINDS}
    frames: dict[str, list[NDArray[np.int32]]] = {k: [] for k in _SEMANTIC_KINDS}
    for i in range(cfg.num_frames):
        for kind, count in per_frame.items():
            if count <= 0:
                continue
            cand = _semantic_candidates(rng, cfg, building, kind, count)
            if cand is None:
                continue
            _, p_cam = _visible(rng, cam, gt[i], cand, count)
            points[kind].append(p_cam + cfg.point_noise * rng.standard_normal(p_cam.shape))
            frames[kind].append(np.full(len(p_cam), i, dtype=np.int32))
    return _Semantic(
        p_in_cam={k: _cat(v, np.float64, (3,)) for k, v in points.items()},
        frame={k: _cat(v, np.int32, ()) for k, v in frames.items()},
    )


def _pair_matches(
    rng: np.random.Generator,
    cfg: SyntheticConfig,
    cam: _Camera,
    gt: F64,
    building: _Building,
    i: int,
    j: int,
) -> tuple[NDArray[np.int32], F64, F64] | None:
    """Noisy matches of surface points seen by frames ``i`` and ``j``: (frames, uv, depth)."""
    count = cfg.matches_per_pair
    cand = np.concatenate(
        [
            _sample_surfaces(rng, 4 * count, cfg, building.segments, building.wall_mask),
            _sample_plane(rng, count, cfg, 0.0),
            _sample_plane(rng, count, cfg, cfg.height),
        ]
    )
    pa, pb = cam.to_cam(gt[i], cand), cam.to_cam(gt[j], cand)
    uva, oka = cam.project(pa)
    uvb, okb = cam.project(pb)
    idx = np.flatnonzero(oka & okb)[:count]
    if not len(idx):
        return None
    noise_uv = cfg.pixel_noise * rng.standard_normal((len(idx), 4))
    uv = np.column_stack([uva[idx], uvb[idx]]) + noise_uv
    noise_depth = cfg.depth_noise * rng.standard_normal((len(idx), 2))
    depth = np.column_stack([pa[idx, 2], pb[idx, 2]]) + noise_depth
    return np.tile([i, j], (len(idx), 1)).astype(np.int32), uv, depth


def _matches(
    rng: np.random.Generator, cfg: SyntheticConfig, cam: _Camera, gt: F64, building: _Building
) -> _Matches:
    """G: matches between frames i and i + k (k in ``cfg.pair_offsets``) on all surfaces."""
    m_frames, m_uv, m_depth = [], [], []
    n = cfg.num_frames
    for i in range(n):
        for off in cfg.pair_offsets:
            j = i + off
            if j >= n or cfg.matches_per_pair <= 0:
                continue
            found = _pair_matches(rng, cfg, cam, gt, building, i, j)
            if found is None:
                continue
            m_frames.append(found[0])
            m_uv.append(found[1])
            m_depth.append(found[2])
    return _Matches(
        frames=_cat(m_frames, np.int32, (2,)),
        uv=_cat(m_uv, np.float64, (4,)),
        depth=_cat(m_depth, np.float64, (2,)),
    )


def _landmark_observations(
    rng: np.random.Generator, cfg: SyntheticConfig, cam: _Camera, gt: F64, gt_points: F64
) -> tuple[NDArray[np.int32], NDArray[np.int32], F64, F64]:
    """Every frame's noisy observations of the landmarks it sees: (frame, point, uv, depth)."""
    t_frame, t_point, t_uv, t_depth = [], [], [], []
    for i in range(cfg.num_frames):
        if not len(gt_points):
            break
        p_cam = cam.to_cam(gt[i], gt_points)
        uv, ok = cam.project(p_cam)
        idx = np.flatnonzero(ok)[: 6 * cfg.landmarks_per_frame]
        t_frame.append(np.full(len(idx), i, dtype=np.int32))
        t_point.append(idx.astype(np.int32))
        t_uv.append(uv[idx] + cfg.pixel_noise * rng.standard_normal((len(idx), 2)))
        t_depth.append(p_cam[idx, 2] + cfg.depth_noise * rng.standard_normal(len(idx)))
    return (
        _cat(t_frame, np.int32, ()),
        _cat(t_point, np.int32, ()),
        _cat(t_uv, np.float64, (2,)),
        _cat(t_depth, np.float64, ()),
    )


def _initial_track_points(
    cfg: SyntheticConfig,
    init: F64,
    obs_frame: NDArray[np.int32],
    obs_point: NDArray[np.int32],
    obs_uv: F64,
    obs_depth: F64,
    num_points: int,
) -> F64:
    """(P, 3) each landmark's first observation back-projected with the drifted pose (world, m)."""
    if not len(obs_point):
        return np.zeros((num_points, 3))
    first = np.unique(obs_point, return_index=True)[1]
    k = np.asarray(cfg.intrinsics)
    uv, depth, frame = obs_uv[first], obs_depth[first], obs_frame[first]
    p_in_cam = np.column_stack(
        [(uv[:, 0] - k[2]) / k[0] * depth, (uv[:, 1] - k[3]) / k[1] * depth, depth]
    )
    p_in_world: F64 = Rotation.from_quat(init[frame, 3:]).apply(p_in_cam) + init[frame, :3]
    return p_in_world


def _landmark_tracks(
    rng: np.random.Generator,
    cfg: SyntheticConfig,
    cam: _Camera,
    gt: F64,
    init: F64,
    building: _Building,
) -> _Tracks:
    """G as landmarks: a pool of wall points, each observed by every frame that sees it."""
    num_landmarks = cfg.landmarks_per_frame * cfg.num_frames
    gt_points = (
        _sample_surfaces(rng, num_landmarks, cfg, building.segments, building.wall_mask)
        if num_landmarks
        else np.zeros((0, 3))
    )
    obs_frame, obs_point, obs_uv, obs_depth = _landmark_observations(rng, cfg, cam, gt, gt_points)
    # Keep only observed landmarks, renumbered; initialise each from its first observation
    # back-projected with the drifted pose (what a front end would do).
    used = np.unique(obs_point)
    remap = np.full(len(gt_points), -1, dtype=np.int32)
    remap[used] = np.arange(len(used), dtype=np.int32)
    obs_point = remap[obs_point]
    gt_points = gt_points[used]
    points = _initial_track_points(
        cfg, init, obs_frame, obs_point, obs_uv, obs_depth, len(gt_points)
    )
    return _Tracks(
        obs_frame=obs_frame,
        obs_point=obs_point,
        obs_uv=obs_uv,
        obs_depth=obs_depth,
        points=points,
        gt_points=gt_points,
    )


def _assemble_problem(
    cfg: SyntheticConfig,
    init: F64,
    building: _Building,
    semantic: _Semantic,
    matches: _Matches,
    tracks: _Tracks,
) -> Problem:
    """The solver problem of the drifted poses ``init`` and all observations."""
    n = cfg.num_frames
    pose_fixed = np.zeros(n, dtype=np.int32)
    if cfg.fix_first:
        pose_fixed[0] = 1
    sem_p, sem_f = semantic.p_in_cam, semantic.frame
    return Problem(
        poses=init,
        timestamps=np.arange(n, dtype=np.float64) * 0.1,
        pose_fixed=pose_fixed,
        cameras=np.asarray([cfg.intrinsics], dtype=np.float64),
        frame_camera=np.zeros(n, dtype=np.int32),
        match_frames=matches.frames,
        match_uv=matches.uv,
        match_depth=matches.depth,
        track_obs_frame=tracks.obs_frame,
        track_obs_point=tracks.obs_point,
        track_obs_uv=tracks.obs_uv,
        track_obs_depth=tracks.obs_depth,
        track_points=tracks.points,
        floor_frame=sem_f["floor"],
        floor_p_in_cam=sem_p["floor"],
        floor_plane=np.full(len(sem_f["floor"]), 0, dtype=np.int32),
        ceiling_frame=sem_f["ceiling"],
        ceiling_p_in_cam=sem_p["ceiling"],
        ceiling_plane=np.full(len(sem_f["ceiling"]), 1, dtype=np.int32),
        planes=building.planes,
        wall_frame=sem_f["wall"],
        wall_p_in_cam=sem_p["wall"],
        column_frame=sem_f["column"],
        column_p_in_cam=sem_p["column"],
        segments=building.segments,
        segment_class=building.segment_class,
        segment_z=building.segment_z,
    )


def make_synthetic_problem(
    config: SyntheticConfig | None = None, **overrides: object
) -> SyntheticProblem:
    """Generate a problem; ``overrides`` replace fields of ``config`` (e.g. ``num_frames=300``)."""
    cfg = _with_overrides(config, overrides)
    rng = np.random.default_rng(cfg.seed)
    building = _building(cfg)
    gt = _trajectory(cfg, rng)
    init = _drift(gt, cfg, rng)
    cam = _Camera(cfg)
    # The draw order of ``rng`` fixes every sample: semantic points, then matches, then tracks.
    semantic = _semantic_samples(rng, cfg, cam, gt, building)
    matches = _matches(rng, cfg, cam, gt, building)
    tracks = _landmark_tracks(rng, cfg, cam, gt, init, building)
    problem = _assemble_problem(cfg, init, building, semantic, matches, tracks)
    return SyntheticProblem(
        problem=problem, gt_poses=gt, gt_track_points=tracks.gt_points, config=cfg
    )


def _cat(parts: Sequence[NDArray[_T]], dtype: type[_T], tail: tuple[int, ...]) -> NDArray[_T]:
    """The parts stacked along axis 0 as one contiguous ``dtype`` array ((0, *tail) if none)."""
    if not parts:
        return np.zeros((0, *tail), dtype=dtype)
    return np.ascontiguousarray(np.concatenate(parts), dtype=dtype)
