"""Per-frame orientation: tilt and yaw of every single frame against the BIM, before the windows.

The window stage (:mod:`.coarse`) trusts the relative poses inside a window. When the initial
orientations carry independent per-frame errors (a noisy IMU or a per-frame rotation prior,
several degrees of pitch and yaw from one frame to the next), a window's points do not agree
with each other under any single rigid correction, and the window stage rejects it. This pass
takes those errors out first, one frame at a time, rotating each camera about its own centre,
and tracks each frame's translation (the caller decides how much of it to apply):

1. **tilt**: the frame's floor points are fitted to the BIM floor height
   (:func:`.gravity.level_window`, ceiling points are not used: they are the least reliable
   label);
2. **yaw**: the frame's wall and column points, after the tilt, are matched over x, y and yaw
   against the floor plan (:func:`.correlative.score_volume`, then ICP from the best
   hypotheses); a single frame often sees only one or two walls, so its translation may be
   unconstrained, but the direction of the walls fixes the yaw. The yaw is kept when the fit
   has enough points and inliers;
3. **translation**: frames are searched in order about a prediction (the median of the last
   kept translations: the position drift is a random walk); a frame's translation is kept
   when its fit is well constrained, scores well and stays near the prediction, then checked
   against its kept neighbours; the others, and the heights of frames without a floor fit,
   are interpolated.

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order, metres, radians inside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bimcap.registration.correlative import score_volume, top_hypotheses
from bimcap.registration.gravity import level_window
from bimcap.registration.icp import Correction2D, icp_2d, rot2
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass(frozen=True)
class FrameLevelOptions:
    """Settings of :func:`level_frames` (metres, degrees).

    Attributes
    ----------
    yaw_range_deg, yaw_step_deg: the yaw search about each camera.
    xy_range_m: half-width of the translation search (the yaw must be found wherever the
        frame's walls are) for the first frame.
    top_k: hypotheses refined by ICP.
    min_points: wall+column points a frame needs for a yaw.
    min_inlier_ratio: inliers (within ``inlier_m``) the best fit needs for its yaw to be kept.
    min_floor_points: floor points a frame needs for a tilt.
    max_points: random subsample of a frame's wall/column points.
    track_xy_range_m: the translation search once a frame has been placed: the frames are
        searched in order about the last placed frame's translation correction (the drift of
        the position is a random walk), growing with the square root of the frames since it.
    track_max_step_m: a frame's translation is kept only if it moves less than this (times
        the same square root) from that prediction, and if it lies within this of the median
        of its kept neighbours (± 3 frames).
    track_history: the prediction is the median of the last this many kept translations (one
        wrong match does not pull the next frames onto an alias of a repetitive wall).
    min_constraint, min_score: a frame's translation is kept only with this translation
        constraint (not a bare corridor wall) and fine score; the others interpolate.
    max_tilt_deg, min_floor_spread_m: a tilt fit is kept only up to this size and when the
        floor points spread at least this far (standard deviation of the narrow axis).
    """

    yaw_range_deg: float = 25.0
    yaw_step_deg: float = 1.0
    xy_range_m: float = 2.5
    top_k: int = 4
    min_points: int = 40
    min_inlier_ratio: float = 0.5
    min_floor_points: int = 30
    max_points: int = 1500
    track_xy_range_m: float = 1.0
    track_max_step_m: float = 0.6
    track_history: int = 3
    min_constraint: float = 0.02
    min_score: float = 0.5
    max_tilt_deg: float = 20.0
    min_floor_spread_m: float = 0.2


@dataclass(frozen=True)
class FrameLevelResult:
    """Per-frame rotations about the camera centres.

    Attributes
    ----------
    world_from_world: (N, 4, 4) the rotations about each camera centre (no translation).
    tilt_ok: (N,) bool, the tilt was fitted; yaw_ok: (N,) bool, the yaw was kept;
    t_ok: (N,) bool, the translation was kept (the others are interpolated).
    score, constraint: (N,) fine score and ICP translation constraint of each frame's best fit
        (0 without one).
    translation: (N, 3) the tracked translation correction of each frame (x, y from the plan,
        z from the floor; interpolated between the frames that fixed them), metres; not in
        ``world_from_world``: the caller decides how much of it to apply.
    drift_m: median length of the kept frames' translations (how far off the input was).
    yaw_deg: (N,) the kept yaw correction (0 where not kept); tilt_deg: (N,) its tilt size.
    """

    world_from_world: F64
    tilt_ok: NDArray[np.bool_]
    yaw_ok: NDArray[np.bool_]
    yaw_deg: F64
    tilt_deg: F64
    t_ok: NDArray[np.bool_]
    score: F64
    constraint: F64
    translation: F64
    drift_m: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (per-frame lists; the matrices are left out)."""
        return {"tilt_ok": self.tilt_ok.tolist(), "yaw_ok": self.yaw_ok.tolist(),
                "t_ok": self.t_ok.tolist(), "yaw_deg": self.yaw_deg.tolist(),
                "tilt_deg": self.tilt_deg.tolist(), "score": self.score.tolist(),
                "constraint": self.constraint.tolist(),
                "translation": self.translation.tolist(), "drift_m": self.drift_m}


def level_frames(
    cam_xyz: F64,
    frame_points: Callable[[int], dict[str, F64]],
    floor_z_of: Callable[[F64, float], float | None],
    maps_of: Callable[[float | None], PlanMaps],
    wall_band_m: float,
    ceiling_z_of: Callable[[float | None], float | None],
    icp: dict[str, float],
    opt: FrameLevelOptions,
    rng: np.random.Generator,
) -> FrameLevelResult:
    """Tilt and yaw of every frame, and a tracked translation (see the module docstring).

    Parameters
    ----------
    cam_xyz: (N, 3) camera centres in the world (metres).
    frame_points: ``i -> {"wall": (W, 3), "column": (C, 3), "floor": (F, 3)}`` frame i's
        points mapped to the world with its initial pose.
    floor_z_of: ``(floor points, camera z) -> BIM floor height`` (or None).
    maps_of: the plan maps of the storey at a floor height.
    wall_band_m: wall points this close to the floor or ceiling are ignored.
    ceiling_z_of: the ceiling height above a floor height (or None).
    icp: keyword settings of :func:`.icp.icp_2d` (radii, iterations, Huber, inlier distance).
    opt: settings; rng: seeds the point subsampling.

    Returns
    -------
    FrameLevelResult
    """
    from bimcap.labels import Label

    n = len(cam_xyz)
    out = np.tile(np.eye(4), (n, 1, 1))
    tilt_ok = np.zeros(n, dtype=bool)
    yaw_ok = np.zeros(n, dtype=bool)
    yaw_deg = np.zeros(n)
    tilt_deg = np.zeros(n)
    step = np.deg2rad(opt.yaw_step_deg)
    k = int(np.floor(np.deg2rad(opt.yaw_range_deg) / step + 1e-9))
    yaws = np.arange(-k, k + 1) * step
    t_pred = np.zeros(2)          # the running translation correction (drift is a random walk)
    t_frame = np.zeros((n, 2))
    t_ok = np.zeros(n, dtype=bool)
    scores = np.zeros(n)
    constraints = np.zeros(n)
    dz = np.zeros(n)              # height corrections (from the floor; interpolated elsewhere)
    dz_pred = 0.0
    last = -1                     # the last frame whose translation was kept
    for i in range(n):
        cam = np.asarray(cam_xyz[i], dtype=np.float64)
        pts = frame_points(i)
        floor_z = floor_z_of(pts["floor"], float(cam[2]))
        m = np.eye(4)
        if floor_z is not None and len(pts["floor"]) >= opt.min_floor_points:
            spread = np.linalg.eigvalsh(np.cov(pts["floor"][:, :2].T))[0]
            lv = level_window(pts["floor"], np.zeros((0, 3)), floor_z, None, cam,
                              min_points=opt.min_floor_points)
            tilt = float(np.rad2deg(Rotation.from_matrix(lv.rotation).magnitude()))
            if (lv.ok and lv.inlier_ratio >= opt.min_inlier_ratio and tilt <= opt.max_tilt_deg
                    and np.sqrt(max(spread, 0.0)) >= opt.min_floor_spread_m):
                m[:3, :3] = lv.rotation
                m[:3, 3] = cam - lv.rotation @ cam
                dz[i] = dz_pred = lv.dz
                tilt_ok[i] = True
                tilt_deg[i] = tilt
        ceil_z = ceiling_z_of(floor_z)
        xy, cls_ = [], []
        for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
            q = pts[c] @ m[:3, :3].T + m[:3, 3] + np.array([0.0, 0.0, dz_pred])
            keep = np.ones(len(q), dtype=bool)
            if floor_z is not None and wall_band_m > 0:
                keep &= q[:, 2] > floor_z + wall_band_m
                if ceil_z is not None:
                    keep &= q[:, 2] < ceil_z - wall_band_m
            xy.append(q[keep, :2] + t_pred)
            cls_.append(np.full(int(keep.sum()), int(lab), np.int32))
        p_xy, p_cls = np.concatenate(xy), np.concatenate(cls_)
        pivot = cam[:2] + t_pred
        best: tuple[float, Correction2D, float] | None = None
        if len(p_xy) >= opt.min_points:
            if len(p_xy) > opt.max_points:
                sel = np.sort(rng.choice(len(p_xy), opt.max_points, replace=False))
                p_xy, p_cls = p_xy[sel], p_cls[sel]
            maps = maps_of(floor_z)
            view = p_xy - pivot
            gap = i - last if last >= 0 else 0
            rng_m = (opt.xy_range_m if last < 0
                     else min(opt.xy_range_m, opt.track_xy_range_m * np.sqrt(gap)))
            vol, res, nn = score_volume(p_xy, p_cls, view, maps, pivot, yaws, rng_m)
            hyps = top_hypotheses(vol, yaws, res, nn, opt.top_k, 0.3, np.deg2rad(3.0))

            def associate(q: F64, q_class: I32, v: F64, maps: PlanMaps = maps
                          ) -> tuple[F64, F64]:
                return maps.nearest(q, maps.layer_of(q_class, v))

            for h in hyps:
                fit = icp_2d(p_xy, p_cls, associate, Correction2D(h.yaw, h.t, pivot), view,
                             **icp)
                corr = fit.correction
                sc, _ = maps.fine_eval(corr.apply(p_xy),
                                       maps.layer_of(p_cls, view @ rot2(corr.yaw).T))
                score = float(sc.mean())
                if (fit.inlier_ratio >= opt.min_inlier_ratio
                        and abs(corr.yaw) <= np.deg2rad(opt.yaw_range_deg)
                        and (best is None or score > best[0])):
                    best = (score, corr, fit.constraint)
        if best is not None:
            score, corr, constraint = best
            r = Rotation.from_rotvec([0.0, 0.0, corr.yaw]).as_matrix()
            m = np.r_[np.c_[r, cam - r @ cam], [[0.0, 0.0, 0.0, 1.0]]] @ m
            yaw_ok[i] = True
            yaw_deg[i] = float(np.rad2deg(corr.yaw))
            scores[i] = score
            constraints[i] = constraint
            if (constraint >= opt.min_constraint and score >= opt.min_score
                    and (last < 0 or np.linalg.norm(corr.t)
                         <= opt.track_max_step_m * np.sqrt(gap))):
                last = i
                t_ok[i] = True
                t_frame[i] = t_pred + corr.t
                recent = np.flatnonzero(t_ok[:i + 1])[-opt.track_history:]
                t_pred = np.median(t_frame[recent], axis=0)
        out[i] = m
    # Translations and heights: trusted frames keep theirs, the others are interpolated
    # between them. A kept translation far from the median of its kept neighbours is a wrong match.
    for i in np.flatnonzero(t_ok):
        near = np.flatnonzero(t_ok[max(i - 3, 0):i + 4]) + max(i - 3, 0)
        near = near[near != i]
        if len(near) >= 2 and (np.linalg.norm(t_frame[i] - np.median(t_frame[near], axis=0))
                               > opt.track_max_step_m):
            t_ok[i] = False
    if t_ok.any():
        idx = np.flatnonzero(t_ok)
        for k in range(2):
            t_frame[:, k] = np.interp(np.arange(n), idx, t_frame[idx, k])
    if tilt_ok.any():
        idx = np.flatnonzero(tilt_ok)
        dz = np.interp(np.arange(n), idx, dz[idx])
    t3 = np.c_[t_frame, dz]
    drift = float(np.median(np.linalg.norm(t3[t_ok], axis=1))) if t_ok.any() else 0.0
    return FrameLevelResult(out, tilt_ok, yaw_ok, yaw_deg, tilt_deg, t_ok, scores, constraints,
                            t3, drift)
