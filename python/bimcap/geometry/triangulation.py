"""Multi-view triangulation of feature tracks at known poses (linear DLT, vectorised).

Each track (landmark) is triangulated from all its observations at once: the homogeneous point
``X`` minimising ``Σ |x_k × (P_k X)|²`` over its rays (the direct linear transform on normalised
image coordinates, every track's 4 × 4 normal matrix solved in one batched eigen-decomposition).
The worst observation of a track is dropped while its reprojection lands further than
``max_reprojection_px`` from it (or behind its camera), and the track re-triangulated from the
rest; a track keeps its point
when at least ``min_observations`` rays remain and they are not nearly parallel
(``min_spread_deg``). Pixels follow bimcap's convention (origin at the first pixel centre) in the
undistorted pinhole camera whose intrinsics are given.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.errors import InputError
from bimcap.geometry.poses import invert, quat_to_rotmat

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass(frozen=True)
class TriangulationOptions:
    """Filters of :func:`triangulate_tracks`.

    Attributes
    ----------
    max_reprojection_px: an observation whose reprojection error exceeds this (pixels) is dropped
        from its track (COLMAP's ``filter_max_reproj_error`` default is 4).
    min_observations: a point needs at least this many observations left (>= 2).
    min_spread_deg: a point needs one observing ray at least this far (degrees) from the mean
        ray direction of its track: nearly parallel rays give a depth that is noise.
    min_depth_m: every kept observation sees its point at least this far in front (z, metres).
    rounds: at most this many re-triangulations, each after dropping every track's worst
        observation when it fails the filters (0: one DLT, then filter).
    """

    max_reprojection_px: float = 2.0
    min_observations: int = 2
    min_spread_deg: float = 0.5
    min_depth_m: float = 0.05
    rounds: int = 5

    def __post_init__(self) -> None:
        if not self.max_reprojection_px > 0:
            raise InputError(f"must be > 0 px, got {self.max_reprojection_px}",
                             field="max_reprojection_px")
        if self.min_observations < 2:
            raise InputError(f"must be >= 2, got {self.min_observations}",
                             field="min_observations")
        if not self.min_spread_deg >= 0 or not self.min_depth_m >= 0 or self.rounds < 0:
            raise InputError("min_spread_deg, min_depth_m and rounds must be >= 0",
                             field="min_spread_deg/min_depth_m/rounds")

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class TriangulatedTracks:
    """The result of :func:`triangulate_tracks`.

    Attributes
    ----------
    points_in_world: (P, 3) float64 metres; NaN where ``valid`` is False.
    valid: (P,) bool, the point passed every filter.
    error_px: (P,) float64 mean reprojection error of the point's kept observations (pixels;
        COLMAP's ``ERROR``); NaN where not valid.
    obs_kept: (K,) bool, the observation belongs to a valid point and passed the filters.
    obs_error_px: (K,) float64 reprojection error of every observation at its track's final
        point (pixels; NaN where the track has no point).
    """

    points_in_world: F64
    valid: NDArray[np.bool_]
    error_px: F64
    obs_kept: NDArray[np.bool_]
    obs_error_px: F64

    def to_dict(self) -> dict[str, object]:
        """Counts and errors for JSON."""
        kept = self.error_px[self.valid]
        return {
            "tracks": len(self.valid),
            "points": int(self.valid.sum()),
            "observations": len(self.obs_kept),
            "observations_kept": int(self.obs_kept.sum()),
            "mean_error_px": float(kept.mean()) if len(kept) else None,
        }


def _check(name: str, arr: NDArray[np.generic], shape: tuple[int, ...]) -> None:
    if arr.shape != shape:
        raise InputError(f"expected shape {shape}, got {arr.shape}", field=name)


def triangulate_tracks(
    intrinsics: ArrayLike,
    world_from_cam: ArrayLike,
    obs_frame: ArrayLike,
    obs_point: ArrayLike,
    obs_uv: ArrayLike,
    num_points: int | None = None,
    options: TriangulationOptions | None = None,
) -> TriangulatedTracks:
    """Triangulate every track at the given poses (module docstring).

    Parameters
    ----------
    intrinsics: (4,) pinhole ``fx fy cx cy`` (pixels) of the undistorted camera.
    world_from_cam: (N, 7) camera poses, TUM order.
    obs_frame: (K,) int frame of each observation, 0..N-1.
    obs_point: (K,) int track of each observation, 0..P-1.
    obs_uv: (K, 2) pixels ``(u, v)``, origin at the first pixel centre.
    num_points: P (default: ``obs_point.max() + 1``).
    options: the filters.

    Returns
    -------
    :class:`TriangulatedTracks`. Raises :class:`bimcap.errors.InputError` naming the array for
    wrong shapes or indices.
    """
    opts = options or TriangulationOptions()
    k = np.asarray(intrinsics, np.float64).reshape(-1)
    poses = np.asarray(world_from_cam, np.float64)
    frame = np.asarray(obs_frame).astype(np.int64)
    point = np.asarray(obs_point).astype(np.int64)
    uv = np.asarray(obs_uv, np.float64)
    _check("intrinsics", k, (4,))
    if poses.ndim != 2 or poses.shape[1] != 7:
        raise InputError(f"expected shape (N, 7), got {poses.shape}", field="world_from_cam")
    n_obs = len(frame)
    _check("obs_frame", frame, (n_obs,))
    _check("obs_point", point, (n_obs,))
    _check("obs_uv", uv, (n_obs, 2))
    p = int(point.max() + 1 if n_obs else 0) if num_points is None else int(num_points)
    if n_obs and (frame.min() < 0 or frame.max() >= len(poses)):
        raise InputError(f"frame indices must lie in 0..{len(poses) - 1}", field="obs_frame")
    if n_obs and (point.min() < 0 or point.max() >= p):
        raise InputError(f"point indices must lie in 0..{p - 1}", field="obs_point")
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(poses))):
        raise InputError("non-finite pixels or poses", field="obs_uv/world_from_cam")

    if n_obs == 0:
        return TriangulatedTracks(np.full((p, 3), np.nan), np.zeros(p, bool), np.full(p, np.nan),
                                  np.zeros(0, bool), np.zeros(0))
    cam_from_world = invert(poses)
    rot = quat_to_rotmat(cam_from_world[:, 3:])
    # Conditioning: solve in a world frame centred on the cameras.
    centre = poses[:, :3].mean(axis=0)
    trans = cam_from_world[:, :3] + np.einsum("nij,j->ni", rot, centre)
    proj = np.concatenate([rot, trans[:, :, None]], axis=2)  # (N, 3, 4) cam_from_(world - c)
    xn = (uv[:, 0] - k[2]) / k[0]
    yn = (uv[:, 1] - k[3]) / k[1]
    pk = proj[frame]
    rows = np.stack([xn[:, None] * pk[:, 2] - pk[:, 0], yn[:, None] * pk[:, 2] - pk[:, 1]], 1)
    rows /= np.linalg.norm(rows, axis=2, keepdims=True)  # (K, 2, 4), each row of unit length
    outer = np.einsum("kri,krj->kij", rows, rows).reshape(n_obs, 16)

    use = np.ones(n_obs, bool)
    for _ in range(opts.rounds + 1):
        x_world, err, depth = _solve(outer, use, point, p, rot, cam_from_world, centre, frame,
                                     uv, k)
        bad = np.where(depth >= opts.min_depth_m, err, np.inf)
        # drop each track's worst observation when it fails, then solve again: one outlier
        # pulls the DLT point off every ray of its track, so dropping all that fail would
        # throw away the good observations with it
        worst = np.full(p, -np.inf)
        np.maximum.at(worst, point[use], bad[use])
        drop = use & (bad == worst[point]) & (bad > opts.max_reprojection_px)
        if not drop.any():
            break
        use &= ~drop
    use &= (err <= opts.max_reprojection_px) & (depth >= opts.min_depth_m)

    count = np.bincount(point[use], minlength=p)
    valid = (count >= opts.min_observations) & np.all(np.isfinite(x_world), axis=1)
    # ray spread: the largest angle between a kept ray and the track's mean ray
    centres = poses[:, :3]
    ray = centres[frame] - np.where(np.isfinite(x_world[point]), x_world[point], 0.0)
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
    mean: F64 = np.stack([np.bincount(point[use], ray[use, i], minlength=p).astype(np.float64)
                          for i in range(3)], 1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    cos = np.clip(np.einsum("ki,ki->k", ray, mean[point]), -1.0, 1.0)
    spread = np.zeros(p)
    np.maximum.at(spread, point[use], np.degrees(np.arccos(cos[use])))
    valid &= spread >= opts.min_spread_deg
    kept = use & valid[point]
    count = np.bincount(point[kept], minlength=p)
    err_sum = np.bincount(point[kept], np.where(kept, err, 0.0)[kept], minlength=p)
    error_px = np.full(p, np.nan)
    error_px[valid] = err_sum[valid] / count[valid]
    x_world[~valid] = np.nan
    return TriangulatedTracks(x_world, valid, error_px, kept, err)


def _solve(outer: F64, use: NDArray[np.bool_], point: NDArray[np.int64], p: int, rot: F64,
           cam_from_world: F64, centre: F64, frame: NDArray[np.int64], uv: F64, k: F64
           ) -> tuple[F64, F64, F64]:
    """One DLT over the observations in ``use``: (P, 3) points (NaN where under-determined), then
    every observation's reprojection error (K,) in pixels and depth (K,) in metres."""
    normal = np.stack([np.bincount(point[use], outer[use, i], minlength=p) for i in range(16)],
                      axis=1).reshape(p, 4, 4)
    count = np.bincount(point[use], minlength=p)
    x_world = np.full((p, 3), np.nan)
    solvable = count >= 2
    if solvable.any():
        _, vecs = np.linalg.eigh(normal[solvable])
        hom = vecs[:, :, 0]  # the eigenvector of the smallest eigenvalue
        w = hom[:, 3]
        ok = np.abs(w) > 1e-12
        sol = np.full((len(hom), 3), np.nan)
        sol[ok] = hom[ok, :3] / w[ok, None] + centre
        x_world[solvable] = sol
    p_in_cam = np.einsum("kij,kj->ki", rot[frame], x_world[point]) + cam_from_world[frame, :3]
    z = p_in_cam[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = k[0] * p_in_cam[:, 0] / z + k[2]
        v = k[1] * p_in_cam[:, 1] / z + k[3]
        err = np.hypot(u - uv[:, 0], v - uv[:, 1])
    err = np.where(np.isfinite(err), err, np.inf)
    depth = np.where(np.isfinite(z), z, -np.inf)
    return x_world, err, depth
