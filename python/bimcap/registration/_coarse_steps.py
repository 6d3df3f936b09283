"""The window steps of :func:`.coarse.coarse_register`, split out of :mod:`.coarse` to keep it
short: the split of the frames into windows, then per window 1. gravity/height, 2. the planar
points, 3. the correlative search and 4. ICP and fine scoring of each hypothesis.

Private to the package (:mod:`.coarse` is the public entry point). Arrays follow
docs/architecture.md: poses ``(N, 7)`` TUM order, metres, radians inside.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import transform_points
from bimcap.labels import Label
from bimcap.registration.correlative import score_volume, top_hypotheses
from bimcap.registration.gravity import LevelResult, level_window
from bimcap.registration.icp import Correction2D, icp_2d, rot2
from bimcap.registration.plan_maps import PlanMaps

if TYPE_CHECKING:
    from bimcap.registration.coarse import CoarseOptions, FloorPlan, SemanticSamples

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

_CLASSES = ("wall", "column", "floor", "ceiling")


@dataclass
class _Candidate:
    """One hypothesis of a window after ICP: its correction, fine score (0-1), inlier ratio and
    translation constraint (NaN without ICP)."""

    correction: Correction2D
    score: float
    inlier_ratio: float
    constraint: float


@dataclass
class _StageClock:
    """Wall-clock seconds per step (``timings``) and the CPU seconds spent building plan maps
    (``maps_cpu``, left out of the per-window CPU time) of one :func:`coarse_register` call."""

    t_start: float
    c_start: float
    timings: dict[str, float]
    maps_cpu: float = 0.0

    @classmethod
    def start(cls) -> _StageClock:
        """Now, with the per-window steps' seconds at 0."""
        timings = dict.fromkeys(("level", "maps", "correlative", "icp", "continuity", "apply"),
                                0.0)
        return cls(t_start=time.perf_counter(), c_start=time.process_time(), timings=timings)

    def finish(self, win_meta: list[dict[str, Any]], n_refined: int) -> dict[str, float]:
        """The timings with the totals, the per-window means and ``frames_refined``."""
        timings = self.timings
        timings["total"] = time.perf_counter() - self.t_start
        timings["cpu_total"] = time.process_time() - self.c_start
        timings["cpu_per_window"] = float(np.mean([m["cpu_seconds"] for m in win_meta]))
        timings["frames_refined"] = float(n_refined)
        timings["per_window"] = float(np.mean([m["seconds"] for m in win_meta]))
        return timings


@dataclass(frozen=True)
class _Windows:
    """The labelled points in the world at the initial poses, split into windows of frames.

    world_pts[c]: (M_c, 3) metres; frames[c]: (M_c,) int32 frame of each point; starts, stops:
    (K,) frame range ``[start, stop)`` of each window; frame_window: (N,) int32; by_win[c],
    bounds[c]: the points of window w are ``by_win[c][bounds[c][w]:bounds[c][w + 1]]``.
    """

    world_pts: dict[str, F64]
    frames: dict[str, I32]
    starts: I64
    stops: I64
    frame_window: I32
    by_win: dict[str, I64]
    bounds: dict[str, I64]

    def indices(self, c: str, w: int) -> I64:
        """(M,) indices into ``world_pts[c]`` of window ``w``'s points of class ``c``."""
        return self.by_win[c][self.bounds[c][w]:self.bounds[c][w + 1]]


@dataclass(frozen=True)
class _YawGrid:
    """The correlative search's yaws (Y,) radians, its half-range and step (radians)."""

    yaws: F64
    yaw_range: float
    step: float


@dataclass(frozen=True)
class _WindowFit:
    """One window after steps 1-4: its levelling, its hypotheses after ICP (deduplicated), the
    plan maps of its storey and ``meta`` (seconds, cpu_seconds, n_points, floor_z, ceiling_z)."""

    level: LevelResult
    candidates: list[_Candidate]
    maps: PlanMaps
    meta: dict[str, Any]


def _weighted_mean(values: F64, p_class: I32, column_weight: float) -> float:
    if len(values) == 0:
        return 0.0
    w = np.where(p_class == Label.COLUMN, column_weight, 1.0)
    return float((values * w).sum() / max(w.sum(), 1e-12))


def _cell_keys(p_xy: F64, p_class: I32, cell: float) -> NDArray[np.int64]:
    """(M,) one int64 key per (grid cell of ``cell`` metres, class) of each point (M, 2)."""
    ij = np.floor(p_xy / cell).astype(np.int64)
    ij -= ij.min(0)
    cls_ = p_class.astype(np.int64)
    cls_ -= cls_.min()
    span = ij.max(0) + 1
    return (ij[:, 0] * span[1] + ij[:, 1]) * (int(cls_.max()) + 1) + cls_


def cell_support(p_xy: F64, p_class: I32, cell: float) -> NDArray[np.int64]:
    """(M,) how many of the points (M, 2) share each point's (grid cell of ``cell`` metres,
    class): a surface seen by many rays fills its cells, a stray return sits alone."""
    if len(p_xy) == 0:
        return np.zeros(0, np.int64)
    _, inverse, counts = np.unique(_cell_keys(p_xy, p_class, cell), return_inverse=True,
                                   return_counts=True)
    return counts[inverse.ravel()]


def _subsample(p_xy: F64, p_class: I32, cell: float | None, cap: int,
               rng: np.random.Generator) -> NDArray[np.int64]:
    """Indices of a thinned point set: with ``cell``, one point per (cell, class) grid cell (for
    occupancy templates; this flattens the noise distribution, so ICP must not use it); then at
    most ``cap`` points drawn uniformly at random (keeps the noise distribution)."""
    keep = np.arange(len(p_xy))
    if len(p_xy) and cell is not None:
        # The first point of each (cell, class), in input order (a 1-D unique of the packed
        # keys, not the row-wise one; the same first occurrences).
        _, keep = np.unique(_cell_keys(p_xy, p_class, cell), return_index=True)
        keep = np.sort(keep)
    if len(keep) > cap:
        keep = np.sort(rng.choice(keep, cap, replace=False))
    return keep


def _pick_height(heights: F64, z: float, below: bool = False) -> float | None:
    if len(heights) == 0:
        return None
    if below:
        cand = heights[heights <= z]
        return float(cand.max()) if len(cand) else float(heights.min())
    return float(heights[np.abs(heights - z).argmin()])


def _storey_top(plan: FloorPlan, floor_z: float) -> float | None:
    """The height (m) a camera standing on the floor at ``floor_z`` must stay below: the highest
    BIM ceiling under the next floor above (that floor when no ceiling lies between); None when
    nothing lies above. The highest, not the lowest, ceiling: a soffit or a dropped ceiling over
    part of a storey does not make the storey low."""
    above = plan.floor_heights[plan.floor_heights > floor_z + 1e-6]
    next_floor = float(above.min()) if len(above) else np.inf
    ceil = plan.ceiling_heights[(plan.ceiling_heights > floor_z + 1e-6)
                                & (plan.ceiling_heights < next_floor)]
    if len(ceil):
        return float(ceil.max())
    return None if not np.isfinite(next_floor) else next_floor


def _pick_floor(plan: FloorPlan, floor_pts_z: F64, cam_z: F64 | float, fallback_z: float
                ) -> float | None:
    """The BIM floor height (m) a window's or a frame's cameras stand on.

    With floor points (``floor_pts_z`` (M,) world z, ``cam_z`` (M,) or scalar: the z of the
    camera that saw each point): the floor nearest their median among the storeys the cameras
    fit in. The cameras' height above their own floor points (median of ``cam_z -
    floor_pts_z``) does not depend on the cameras' z error, which drift makes large (Exp. 2:
    up to 1 m a frame); a storey whose ceiling (:func:`_storey_top`) lies below its floor plus
    that height cannot hold them (Duplex_A's 1.1 m crawl space under the ground floor, which two
    frames' floor points 1 m low made the nearest floor of a window: its walls were then matched
    against the crawl space's plan, 1.6 m off). When no storey fits, every one counts. Without
    floor points: the highest floor at or below ``fallback_z`` (the camera height)."""
    heights = plan.floor_heights
    if len(floor_pts_z) == 0:
        return _pick_height(heights, fallback_z, below=True)
    ref_z = float(np.median(floor_pts_z))
    above_floor = float(np.median(np.asarray(cam_z) - floor_pts_z))
    tops = [_storey_top(plan, float(f)) for f in heights]
    fits = np.array([t is None or t > f + above_floor for f, t in zip(heights, tops, strict=True)],
                    dtype=bool)
    return _pick_height(heights[fits] if fits.any() else heights, ref_z)


def _split_windows(poses: F64, samples: SemanticSamples, opt: CoarseOptions) -> _Windows:
    """All labelled points in the world at ``poses`` (N, 7), once, and their windows."""
    n = len(poses)
    world_pts: dict[str, F64] = {}
    frames: dict[str, I32] = {}
    for c in _CLASSES:
        fr = getattr(samples, f"{c}_frame")
        world_pts[c] = (transform_points(poses[fr], getattr(samples, f"{c}_p_in_cam"))
                        if len(fr) else np.zeros((0, 3)))
        frames[c] = fr
    starts = np.arange(0, n, opt.window_frames)
    if len(starts) > 1 and n - starts[-1] < max(opt.window_frames // 2, 1):
        starts = starts[:-1]  # merge a short tail into the previous window
    stops = np.r_[starts[1:], n]
    frame_window = np.repeat(np.arange(len(starts)), stops - starts).astype(np.int32)
    win_of = {c: frame_window[frames[c]] for c in _CLASSES}
    # Points of window w of class c: by_win[c][bounds[c][w]:bounds[c][w + 1]].
    by_win = {c: np.argsort(win_of[c], kind="stable") for c in _CLASSES}
    bounds = {c: np.searchsorted(win_of[c][by_win[c]], np.arange(len(starts) + 1))
              for c in _CLASSES}
    return _Windows(world_pts=world_pts, frames=frames, starts=starts, stops=stops,
                    frame_window=frame_window, by_win=by_win, bounds=bounds)


def _yaw_grid(opt: CoarseOptions) -> _YawGrid:
    """The yaws of the correlative search: the full circle or ± ``yaw_range_deg``."""
    yaw_range = np.deg2rad(opt.yaw_range_deg)
    step = np.deg2rad(opt.yaw_step_deg)
    if opt.yaw_range_deg >= 180:
        yaws = np.arange(-np.pi, np.pi, step)
    else:
        k = int(np.floor(yaw_range / step + 1e-9))
        yaws = np.arange(-k, k + 1) * step
    return _YawGrid(yaws=yaws, yaw_range=yaw_range, step=step)


def _register_window(w: int, wins: _Windows, poses: F64, plan: FloorPlan,
                     maps_for: Callable[[float | None], PlanMaps], grid: _YawGrid,
                     skip_windows: bool, opt: CoarseOptions, rng: np.random.Generator,
                     clock: _StageClock) -> _WindowFit:
    """Steps 1-4 for window ``w`` (``poses`` (N, 7) the initial poses of all frames)."""
    timings = clock.timings
    f0, f1 = wins.starts[w], wins.stops[w]
    tw, cw = time.perf_counter(), time.process_time()
    maps_before, maps_cpu_before = timings["maps"], clock.maps_cpu
    pivot3 = poses[f0:f1, :3].mean(0)
    idx = {c: wins.indices(c, w) for c in _CLASSES}
    pts = {c: wins.world_pts[c][idx[c]] for c in _CLASSES}
    # 1. gravity and height.
    t0 = time.perf_counter()
    floor_cam_z = poses[wins.frames["floor"][idx["floor"]], 2]
    level, floor_z, ceil_z = _level_step(pts, floor_cam_z, pivot3, plan, opt)
    lm = level.matrix()
    timings["level"] += time.perf_counter() - t0
    # 2. planar points after levelling (with the ray direction camera → point), wall band,
    # and two thinned sets: random for ICP, one per cell for the occupancy templates.
    cam_xyz = {c: poses[wins.frames[c][idx[c]], :3] for c in ("wall", "column")}
    all_xy, all_view, all_cls = _planar_points(pts, cam_xyz, lm, floor_z, ceil_z, opt)
    sel = _subsample(all_xy, all_cls, None, opt.max_points_per_window, rng)
    p_xy, p_view, p_cls = all_xy[sel], all_view[sel], all_cls[sel]
    occ = _subsample(all_xy, all_cls, 0.5 * opt.coarse_resolution_m,
                     10 * opt.max_points_per_window, rng)
    # Plan section of this storey.
    t0 = time.perf_counter()
    c0 = time.process_time()
    maps = maps_for(floor_z)
    clock.maps_cpu += time.process_time() - c0
    timings["maps"] += time.perf_counter() - t0

    pivot = pivot3[:2].copy()
    found: list[_Candidate] = []
    if len(p_xy) >= opt.min_points and len(maps.segments) and not skip_windows:
        # 3. correlative search.
        t0 = time.perf_counter()
        inits = _search_hypotheses(all_xy[occ], all_cls[occ], all_view[occ], maps, pivot, grid,
                                   opt)
        timings["correlative"] += time.perf_counter() - t0
        # 4. ICP and fine scoring of each hypothesis.
        t0 = time.perf_counter()
        found = _refine_hypotheses(p_xy, p_cls, p_view, inits, maps, opt)
        timings["icp"] += time.perf_counter() - t0
    meta = {"seconds": time.perf_counter() - tw - (timings["maps"] - maps_before),
            "cpu_seconds": time.process_time() - cw - (clock.maps_cpu - maps_cpu_before),
            "n_points": len(p_xy), "floor_z": floor_z, "ceiling_z": ceil_z}
    return _WindowFit(level=level, candidates=found, maps=maps, meta=meta)


def _level_step(pts: dict[str, F64], floor_cam_z: F64, pivot3: F64, plan: FloorPlan,
                opt: CoarseOptions) -> tuple[LevelResult, float | None, float | None]:
    """Step 1: the window's levelling about ``pivot3`` (3,) and its BIM floor and ceiling
    heights (metres, None when the plan has none); ``floor_cam_z`` (M,): the z of the camera
    that saw each floor point (:func:`_pick_floor`)."""
    floor_z = _pick_floor(plan, pts["floor"][:, 2], floor_cam_z, float(pivot3[2]))
    ceil_z = None
    if len(plan.ceiling_heights):
        ref_z = float(np.median(pts["floor"][:, 2])) if len(pts["floor"]) else float(pivot3[2])
        above = plan.ceiling_heights[plan.ceiling_heights > (floor_z if floor_z is not None
                                                             else ref_z)]
        ceil_z = float(above.min()) if len(above) else None
    level = (level_window(pts["floor"], pts["ceiling"], floor_z, ceil_z, pivot3)
             if opt.use_gravity else LevelResult.identity(pivot3))
    return level, floor_z, ceil_z


def _planar_points(pts: dict[str, F64], cam_xyz: dict[str, F64], lm: F64,
                   floor_z: float | None, ceil_z: float | None, opt: CoarseOptions
                   ) -> tuple[F64, F64, I32]:
    """Step 2: wall and column points after the levelling ``lm`` (4, 4), without the wall
    band: ``(xy (M, 2), view (M, 2) camera → point, class (M,))``."""
    planar, views, pclass = [], [], []
    for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
        q = pts[c] @ lm[:3, :3].T + lm[:3, 3]
        cam = cam_xyz[c] @ lm[:3, :3].T + lm[:3, 3]
        keep = np.ones(len(q), dtype=bool)
        if floor_z is not None and opt.wall_band_m > 0:
            keep &= q[:, 2] > floor_z + opt.wall_band_m
            if ceil_z is not None:
                keep &= q[:, 2] < ceil_z - opt.wall_band_m
        planar.append(q[keep, :2])
        views.append(q[keep, :2] - cam[keep, :2])
        pclass.append(np.full(int(keep.sum()), int(lab), np.int32))
    return np.concatenate(planar), np.concatenate(views), np.concatenate(pclass)


def _search_hypotheses(occ_xy: F64, occ_cls: I32, occ_view: F64, maps: PlanMaps, pivot: F64,
                       grid: _YawGrid, opt: CoarseOptions) -> list[Correction2D]:
    """Step 3: the top-K x-y-yaw hypotheses about ``pivot`` (2,) from the one-per-cell points
    (``(M, 2)`` metres), or the initial pose alone without the correlative search."""
    if not opt.use_correlative:
        return [Correction2D(0.0, np.zeros(2), pivot)]
    vol, res, nn = score_volume(occ_xy, occ_cls, occ_view, maps, pivot, grid.yaws,
                                opt.xy_range_m, opt.column_weight)
    hyps = top_hypotheses(vol, grid.yaws, res, nn, opt.top_k, opt.nms_xy_m,
                          np.deg2rad(opt.nms_yaw_deg))
    return [Correction2D(h.yaw, h.t, pivot) for h in hyps]


def _refine_hypotheses(p_xy: F64, p_cls: I32, p_view: F64, inits: list[Correction2D],
                       maps: PlanMaps, opt: CoarseOptions) -> list[_Candidate]:
    """Step 4: ICP from each hypothesis (points ``(M, 2)`` metres), fine score and inlier ratio;
    of two that converge to the same correction the better scoring one is kept."""

    def associate(q: F64, q_class: I32, view: F64, maps: PlanMaps = maps) -> tuple[F64, F64]:
        return maps.nearest(q, maps.layer_of(q_class, view))

    found: list[_Candidate] = []
    for init in inits:
        constraint = float("nan")
        if opt.use_icp:
            fit = icp_2d(p_xy, p_cls, associate, init, p_view, opt.icp_radius_start_m,
                         opt.icp_radius_end_m, opt.icp_iterations, opt.icp_huber_m,
                         opt.inlier_m)
            corr, constraint = fit.correction, fit.constraint
        else:
            corr = init
        layer = maps.layer_of(p_cls, p_view @ rot2(corr.yaw).T)
        sc, dist = maps.fine_eval(corr.apply(p_xy), layer)
        cand = _Candidate(correction=corr,
                          score=_weighted_mean(sc, p_cls, opt.column_weight),
                          inlier_ratio=float((dist < opt.inlier_m).mean()),
                          constraint=constraint)
        dup = [k for k, o in enumerate(found)
               if abs(np.angle(np.exp(1j * (o.correction.yaw - corr.yaw))))
               < np.deg2rad(0.5) and np.linalg.norm(o.correction.t - corr.t) < 0.05]
        if dup:
            if cand.score > found[dup[0]].score:
                found[dup[0]] = cand
        else:
            found.append(cand)
    return found
