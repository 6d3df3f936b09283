"""Keypoint depths, feature tracks and the solver's geometric observations.

Everything is in undistorted pinhole pixels of ``camera.pinhole()``; depth is z-depth in metres
(0 = none). The outputs are exactly the arrays of the solver's G terms (docs/architecture.md):
``match_frames (M,2) i32, match_uv (M,4) [ua va ub vb], match_depth (M,2)`` for the pairwise
point-consistency / reprojection residuals and ``track_obs_* / track_points`` for the landmark
residual.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from bimcap.features.matching import PairMatches
from bimcap.features.sift import FeatureError
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import transform_points

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


# --------------------------------------------------------------------------- keypoint depth
class DepthEdgePolicy(str, Enum):
    """What to do when the 4 pixels around a keypoint disagree in depth (a depth edge)."""

    INVALID = "invalid"  # no depth for this keypoint (the default: edges are unreliable)
    NEAREST = "nearest"  # the nearest pixel's depth


@dataclass(frozen=True)
class DepthLookupOptions:
    """Validity check of a keypoint's depth.

    Attributes
    ----------
    max_relative_spread: bilinear interpolation only if ``(max − min) <= this × min`` over the
        4 neighbouring pixels, all valid.
    edge_policy: otherwise, the nearest pixel's depth or none.
    min_depth_m, max_depth_m: depths outside this range count as invalid.
    support_returns: how many of the sensor's returns nearest a keypoint (in the image) test its
        depth (:func:`unsupported_depths`).
    max_support_z: a keypoint's depth is dropped when the mean of ``return − depth`` over those
        returns (each at its own pixel) is more than this many standard errors
        (range noise / √``support_returns``) from 0: the depth map there left the returns (a
        plane fitted across a corner). None: no such test.
    min_noise_m: the range noise the test assumes at least, metres (a noise-free scan still
        differs from a depth map by its pixel grid).
    """

    max_relative_spread: float = 0.05
    edge_policy: DepthEdgePolicy = DepthEdgePolicy.INVALID
    min_depth_m: float = 0.1
    max_depth_m: float = 100.0
    support_returns: int = 16
    max_support_z: float | None = 3.0
    min_noise_m: float = 0.01

    def __post_init__(self) -> None:
        if self.support_returns < 1:
            raise FeatureError(f"support_returns must be >= 1, got {self.support_returns}")
        if self.max_support_z is not None and not self.max_support_z > 0:
            raise FeatureError(f"max_support_z must be > 0 or None, got {self.max_support_z}")

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["edge_policy"] = self.edge_policy.value
        return d


def lookup_depth(
    depth: NDArray[np.floating], uv: F64, options: DepthLookupOptions | None = None
) -> F64:
    """Depth at sub-pixel keypoints with a validity check.

    Parameters
    ----------
    depth: (H, W) z-depth in metres, 0 = unknown.
    uv: (N, 2) pixels (origin at the first pixel centre).

    Returns
    -------
    (N,) float64 depth in metres, 0 where none is reliable.
    """
    opts = options or DepthLookupOptions()
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise FeatureError(f"depth must be (H, W), got {d.shape}")
    q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    h, w = d.shape
    valid_d = np.where((d >= opts.min_depth_m) & (d <= opts.max_depth_m), d, 0.0)
    out = np.zeros(len(q))
    inside = (q[:, 0] > -0.5) & (q[:, 0] < w - 0.5) & (q[:, 1] > -0.5) & (q[:, 1] < h - 0.5)
    u0 = np.floor(q[:, 0]).astype(np.int64)
    v0 = np.floor(q[:, 1]).astype(np.int64)
    fu = q[:, 0] - u0
    fv = q[:, 1] - v0
    uc = [np.clip(u0, 0, w - 1), np.clip(u0 + 1, 0, w - 1)]
    vc = [np.clip(v0, 0, h - 1), np.clip(v0 + 1, 0, h - 1)]
    n00 = valid_d[vc[0], uc[0]]
    n10 = valid_d[vc[0], uc[1]]
    n01 = valid_d[vc[1], uc[0]]
    n11 = valid_d[vc[1], uc[1]]
    stack = np.stack([n00, n10, n01, n11], axis=1)
    lo = stack.min(axis=1)
    hi = stack.max(axis=1)
    agree = inside & (lo > 0) & (hi - lo <= opts.max_relative_spread * lo)
    bil = (n00 * (1 - fu) * (1 - fv) + n10 * fu * (1 - fv) + n01 * (1 - fu) * fv + n11 * fu * fv)
    out[agree] = bil[agree]
    if opts.edge_policy is DepthEdgePolicy.NEAREST:
        rest = inside & ~agree
        un = np.clip(np.rint(q[rest, 0]).astype(np.int64), 0, w - 1)
        vn = np.clip(np.rint(q[rest, 1]).astype(np.int64), 0, h - 1)
        out[rest] = valid_d[vn, un]
    return out


def unsupported_depths(
    depth: NDArray[np.floating], measured: NDArray[np.floating], uv: F64, noise_m: float,
    options: DepthLookupOptions | None = None,
) -> NDArray[np.bool_]:
    """Keypoints whose depth the sensor's own returns around them contradict.

    A depth map made from the returns (completed, then smoothed onto planes) can leave them: a
    plane fitted across a corner or to a strip of wall turned 30° puts a whole patch 5–10 cm
    off while each pixel still looks plausible. At every return ``r`` the map's error is seen
    directly as ``measured[r] − depth[r]`` (range noise σ). Over the ``k`` returns nearest a
    keypoint the mean of these differences is ~N(0, σ/√k) where the map follows the returns,
    and the keypoint's depth is not to be trusted where it is further than ``max_support_z``
    standard errors from 0. An interpolating completion passes through its returns (no
    keypoint dropped there); so does any map at a return it did not change.

    Parameters
    ----------
    depth: (H, W) z-depth in metres the keypoints' depths come from, 0 = unknown.
    measured: (H, W) z-depth of the sensor's returns at their pixels, metres, 0 elsewhere.
    uv: (N, 2) keypoint pixels (origin at the first pixel centre).
    noise_m: the returns' range noise σ, metres (at least ``min_noise_m`` is assumed).
    options: ``support_returns`` (k), ``max_support_z``, ``min_noise_m``; None: defaults.

    Returns
    -------
    (N,) bool, True where the depth is contradicted (all False when ``max_support_z`` is None,
    or fewer than k returns have a depth in the map).
    """
    from bimcap import _core

    opts = options or DepthLookupOptions()
    q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    # the maps in their own dtype (float32 from the front end): widening to float64 is exact, so
    # the tests and the differences of the returns' pixels, widened alone, are the same numbers
    d = np.asarray(depth)
    m = np.asarray(measured)
    if d.shape != m.shape or d.ndim != 2:
        raise FeatureError(f"depth {d.shape} and measured {m.shape} must be the same (H, W)")
    if d.dtype not in (np.float32, np.float64) or m.dtype not in (np.float32, np.float64):
        d, m = d.astype(np.float64), m.astype(np.float64)
    out = np.zeros(len(q), dtype=bool)
    k = opts.support_returns
    if opts.max_support_z is None or len(q) == 0:
        return out
    v, u = np.nonzero((m > 0) & (d > 0))
    if len(u) < k:
        return out
    diff = m[v, u].astype(np.float64) - d[v, u].astype(np.float64)
    # the k returns nearest each keypoint, nearest first: scipy's cKDTree's neighbours, found
    # row by row in compiled code (bimcap/raster/pixel_neighbours.h; ties by index)
    row_start = np.zeros(d.shape[0] + 1, np.int64)
    np.cumsum(np.bincount(v, minlength=d.shape[0]), out=row_start[1:])
    idx = _core.nearest_pixels(row_start, u.astype(np.int64), np.ascontiguousarray(q), k)
    bias = diff[idx].mean(axis=1)
    sigma = max(noise_m, opts.min_noise_m)
    return np.asarray(np.abs(bias) > opts.max_support_z * sigma / np.sqrt(k))


# --------------------------------------------------------------------------- tracks
@dataclass
class Tracks:
    """Feature tracks (landmarks) and their observations.

    Attributes
    ----------
    obs_frame: (K,) int32 frame of each observation.
    obs_point: (K,) int32 track (landmark) index of each observation, 0..P-1.
    obs_keypoint: (K,) int32 keypoint index inside its frame.
    """

    obs_frame: I32
    obs_point: I32
    obs_keypoint: I32

    @property
    def num_points(self) -> int:
        return int(self.obs_point.max()) + 1 if len(self.obs_point) else 0


def build_tracks(
    num_keypoints: Sequence[int], pairs: Sequence[PairMatches], min_length: int = 2
) -> Tracks:
    """Tracks as the connected components of the verified-match graph.

    The components are what union-find over all verified matches gives (computed here with
    ``scipy.sparse.csgraph.connected_components``). A component holding two keypoints of the same
    image is inconsistent (two different image points cannot be one landmark) and is dropped
    whole, as COLMAP's track builder does; so are components shorter than ``min_length``.

    Parameters
    ----------
    num_keypoints: keypoints per frame, length N.
    pairs: verified matches with frame indices in ``[0, N)``.
    min_length: minimum observations per track (>= 2).

    Returns
    -------
    Tracks, observations sorted by track then frame.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if min_length < 2:
        raise FeatureError(f"min_length must be >= 2, got {min_length}")
    counts = np.asarray(num_keypoints, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    total = int(offsets[-1])
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    for p in pairs:
        if not (0 <= p.frame_a < len(counts) and 0 <= p.frame_b < len(counts)):
            raise FeatureError(f"pair ({p.frame_a}, {p.frame_b}) outside {len(counts)} frames")
        if len(p.idx) == 0:
            continue
        rows.append(offsets[p.frame_a] + p.idx[:, 0].astype(np.int64))
        cols.append(offsets[p.frame_b] + p.idx[:, 1].astype(np.int64))
    empty = np.zeros(0, np.int32)
    if not rows or total == 0:
        return Tracks(empty, empty.copy(), empty.copy())
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(total, total))
    _, comp = connected_components(graph, directed=False)
    node_frame = np.repeat(np.arange(len(counts)), counts)
    node_kp = np.arange(total) - offsets[node_frame]
    size = np.bincount(comp)
    # Distinct frames per component: count unique (component, frame) pairs.
    key = np.unique(comp.astype(np.int64) * len(counts) + node_frame)
    frames_per = np.bincount(key // len(counts), minlength=len(size))
    good = (size >= min_length) & (frames_per == size)
    keep = good[comp]
    comp_k = comp[keep]
    new_id = np.full(len(size), -1, np.int64)
    new_id[np.flatnonzero(good)] = np.arange(int(good.sum()))
    point = new_id[comp_k]
    frame = node_frame[keep]
    kp = node_kp[keep]
    order = np.lexsort((frame, point))
    return Tracks(
        frame[order].astype(np.int32), point[order].astype(np.int32), kp[order].astype(np.int32)
    )


def consistent_track_observations(
    obs_frame: I32,
    obs_point: I32,
    obs_uv: F64,
    obs_depth: F64,
    camera: Camera,
    world_from_cam: F64,
    max_distance_m: float,
) -> NDArray[np.bool_]:
    """The tracks' analogue of the pairwise distance filter.

    Each observation with depth is back-projected into the world under ``world_from_cam``; it is
    inconsistent if it lies further than ``max_distance_m`` from the per-coordinate median of its
    track's back-projections. Observations without depth are kept.

    Returns
    -------
    (K,) bool, True for observations to keep.
    """
    keep = np.ones(len(obs_point), bool)
    has = np.flatnonzero(obs_depth > 0)
    if len(has) == 0:
        return keep
    p = transform_points(
        world_from_cam[obs_frame[has]],
        camera.backproject(obs_uv[has], obs_depth[has], distorted=False),
    )
    order = np.argsort(obs_point[has], kind="stable")
    pid = obs_point[has][order]
    starts = np.flatnonzero(np.r_[True, pid[1:] != pid[:-1]])
    ends = np.r_[starts[1:], len(pid)]
    centre = np.empty((len(has), 3))
    for a, b in zip(starts, ends, strict=True):
        centre[order[a:b]] = np.median(p[order[a:b]], axis=0)
    far = np.linalg.norm(p - centre, axis=1) > max_distance_m
    keep[has[far]] = False
    return keep


def triangulate_tracks(
    obs_frame: I32,
    obs_point: I32,
    obs_uv: F64,
    obs_depth: F64,
    camera: Camera,
    world_from_cam: F64,
) -> tuple[F64, NDArray[np.bool_]]:
    """Initial landmark positions in the world under the given (initial) poses.

    A landmark is the mean of its observations' back-projections that have depth; one without
    any depth is triangulated linearly (DLT) from its rays. A landmark whose DLT point is behind a
    camera or whose rays are parallel is marked invalid.

    Parameters
    ----------
    obs_frame, obs_point: (K,) int32.
    obs_uv: (K, 2) undistorted pixels.
    obs_depth: (K,) metres, 0 = none.
    camera: pinhole camera of ``obs_uv``.
    world_from_cam: (N, 7) TUM-order poses.

    Returns
    -------
    points: (P, 3) float64 world coordinates.
    valid: (P,) bool.
    """
    num = int(obs_point.max()) + 1 if len(obs_point) else 0
    points = np.zeros((num, 3))
    valid = np.zeros(num, bool)
    if num == 0:
        return points, valid
    rays = camera.rays(obs_uv, distorted=False)
    has_d = obs_depth > 0
    p_world = transform_points(world_from_cam[obs_frame], rays * obs_depth[:, None])
    cnt = np.bincount(obs_point[has_d], minlength=num)
    for k in range(3):
        points[:, k] = np.bincount(obs_point[has_d], weights=p_world[has_d, k], minlength=num)
    with_depth = cnt > 0
    points[with_depth] /= cnt[with_depth, None]
    valid[with_depth] = True
    # Linear triangulation for landmarks without any depth.
    from bimcap.geometry.poses import invert, pose_to_matrix

    cam_from_world = pose_to_matrix(invert(world_from_cam))
    for pid in np.flatnonzero(~with_depth):
        sel = np.flatnonzero(obs_point == pid)
        a_rows = []
        for o in sel:
            m = cam_from_world[obs_frame[o]][:3]
            x, y = rays[o, 0], rays[o, 1]
            a_rows += [x * m[2] - m[0], y * m[2] - m[1]]
        _, s, vt = np.linalg.svd(np.asarray(a_rows))
        xh = vt[-1]
        if abs(xh[3]) < 1e-12 or s[-2] < 1e-9:
            continue
        x3 = xh[:3] / xh[3]
        z = ((cam_from_world[obs_frame[sel]][:, 2, :3] @ x3)
             + cam_from_world[obs_frame[sel]][:, 2, 3])
        if (z > 0).all():
            points[pid] = x3
            valid[pid] = True
    return points, valid


# --------------------------------------------------------------------------- match observations
class RequireDepth(str, Enum):
    """Which matches are kept by whether their keypoints have depth."""

    BOTH = "both"  # FACaP's point-consistency term needs both depths (default)
    ANY = "any"  # reprojection variant: one depth is enough
    NONE = "none"  # keep all; missing depths are 0


@dataclass(frozen=True)
class MatchFilterOptions:
    """The peers' filters on pairwise matches, as options.

    Attributes
    ----------
    min_frame_gap: keep a pair only if ``|i − j| >= min_frame_gap`` (1 keeps every pair).
    max_initial_distance_m: drop a match whose two back-projected points lie further apart in
        the world than this under the initial poses (the paper uses 0.4 m); None disables it.
        Applies only where both keypoints have depth. The runner applies the same threshold to
        track observations (distance to the track's median, :func:`consistent_track_observations`).
    require_depth: depth requirement on the two keypoints.
    """

    min_frame_gap: int = 1
    max_initial_distance_m: float | None = 0.4
    require_depth: RequireDepth = RequireDepth.BOTH

    def __post_init__(self) -> None:
        if self.min_frame_gap < 1:
            raise FeatureError(f"min_frame_gap must be >= 1, got {self.min_frame_gap}")
        if self.max_initial_distance_m is not None and self.max_initial_distance_m <= 0:
            raise FeatureError("max_initial_distance_m must be positive or None")

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["require_depth"] = self.require_depth.value
        return d


@dataclass
class MatchObservations:
    """The solver's pairwise G observations.

    Attributes
    ----------
    match_frames: (M, 2) int32 ``[frame a, frame b]``.
    match_uv: (M, 4) float64 ``[ua, va, ub, vb]`` undistorted pixels.
    match_depth: (M, 2) float64 metres, 0 = none.
    """

    match_frames: I32
    match_uv: F64
    match_depth: F64


def frame_gap_ok(frame_a: NDArray[np.integer], frame_b: NDArray[np.integer],
                 min_gap: int) -> NDArray[np.bool_]:
    """``|frame_a − frame_b| >= min_gap``.

    The peers' code tested ``frame_b − frame_a >= k`` *signed*, which silently drops every pair
    listed with the later frame first; the gap is a distance, so it is compared unsigned here.
    """
    a = np.asarray(frame_a, dtype=np.int64)
    b = np.asarray(frame_b, dtype=np.int64)
    return np.abs(a - b) >= min_gap


def assemble_match_observations(
    pairs: Sequence[PairMatches],
    keypoints_uv: Sequence[F64],
    keypoints_depth: Sequence[F64],
    camera: Camera,
    world_from_cam: F64,
    options: MatchFilterOptions | None = None,
) -> MatchObservations:
    """Flatten verified pair matches into the solver's arrays, applying the filters.

    Parameters
    ----------
    pairs: verified matches.
    keypoints_uv: per frame (Ni, 2) undistorted pixels.
    keypoints_depth: per frame (Ni,) metres, 0 = none.
    camera: the pinhole camera.
    world_from_cam: (N, 7) initial poses (for the distance filter).
    """
    opts = options or MatchFilterOptions()
    frames_l: list[I32] = []
    uv_l: list[F64] = []
    depth_l: list[F64] = []
    for p in pairs:
        if len(p.idx) == 0 or not frame_gap_ok(np.array([p.frame_a]), np.array([p.frame_b]),
                                               opts.min_frame_gap)[0]:
            continue
        ia, ib = p.idx[:, 0], p.idx[:, 1]
        uva = keypoints_uv[p.frame_a][ia]
        uvb = keypoints_uv[p.frame_b][ib]
        da = keypoints_depth[p.frame_a][ia]
        db = keypoints_depth[p.frame_b][ib]
        both = (da > 0) & (db > 0)
        if opts.require_depth is RequireDepth.BOTH:
            keep = both.copy()
        elif opts.require_depth is RequireDepth.ANY:
            keep = (da > 0) | (db > 0)
        else:
            keep = np.ones(len(ia), bool)
        if opts.max_initial_distance_m is not None and both.any():
            pa = transform_points(world_from_cam[p.frame_a],
                                  camera.backproject(uva[both], da[both], distorted=False))
            pb = transform_points(world_from_cam[p.frame_b],
                                  camera.backproject(uvb[both], db[both], distorted=False))
            far = np.linalg.norm(pa - pb, axis=1) > opts.max_initial_distance_m
            keep[np.flatnonzero(both)[far]] = False
        n = int(keep.sum())
        frames_l.append(np.tile(np.array([p.frame_a, p.frame_b], np.int32), (n, 1)))
        uv_l.append(np.concatenate([uva[keep], uvb[keep]], axis=1))
        depth_l.append(np.stack([da[keep], db[keep]], axis=1))
    if not frames_l:
        return MatchObservations(np.zeros((0, 2), np.int32), np.zeros((0, 4)), np.zeros((0, 2)))
    return MatchObservations(
        np.ascontiguousarray(np.concatenate(frames_l), dtype=np.int32),
        np.ascontiguousarray(np.concatenate(uv_l), dtype=np.float64),
        np.ascontiguousarray(np.concatenate(depth_l), dtype=np.float64),
    )
