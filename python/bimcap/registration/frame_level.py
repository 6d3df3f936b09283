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
3. **translation**: every frame keeps its best few x-y-yaw hypotheses, each searched on its
   own about its input pose (so that no single frame decides for the others); the translation
   path is then the cheapest walk through them (:func:`track_translations`): the position
   drift is a random walk (a Gaussian step from frame to frame, growing with the square root of
   the frames between), starts near zero (a Gaussian prior on the first correction), and a
   frame's fit costs the more the lower its score; a frame may also be left out (a fixed
   cost), which is how an alias that fits one frame well but no neighbour is passed over. The
   frames left out, and the heights of frames without a floor fit, are interpolated.

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order, metres, radians inside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bimcap.progress import progress
from bimcap.registration.correlative import Hypothesis, score_volume, top_hypotheses
from bimcap.registration.gravity import level_window
from bimcap.registration.icp import Correction2D, icp_2d_many, rot2
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
    track_step_sigma_m: standard deviation of the translation correction's step from one frame
        to the next (times the square root of the frames between): the drift's random walk
        plus the fits' own noise.
    track_prior_sigma_m: standard deviation of the first frame's translation correction (the
        drift starts small).
    track_score_weight: cost of a fit per unit of score below 1 (the score is the fraction of
        points on the plan); a score 0.1 lower costs as much as a 1.4-sigma step with the
        default of 10.
    track_skip_cost: cost of leaving out a frame that has informative hypotheses: more than a fit
        of the minimum score on the path costs (``track_score_weight × (1 − min_score)`` = 5),
        less than an alias 1 m off the path (about 11 in steps to its two neighbours).
    track_max_step_m: a kept translation further than this from the median of its kept
        neighbours (± 3 frames) is dropped after the path is chosen.
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
    track_step_sigma_m: float = 0.3
    track_prior_sigma_m: float = 1.5
    track_score_weight: float = 10.0
    track_skip_cost: float = 6.0
    track_max_step_m: float = 0.6
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
    n = len(cam_xyz)
    step = np.deg2rad(opt.yaw_step_deg)
    k = int(np.floor(np.deg2rad(opt.yaw_range_deg) / step + 1e-9))
    yaws = np.arange(-k, k + 1) * step
    tilted = _tilt_and_hypotheses(cam_xyz, frame_points, floor_z_of, maps_of, wall_band_m,
                                  ceiling_z_of, icp, yaws, opt, rng)
    path = track_translations(tilted.candidates, opt)
    t_ok, t_frame = _path_translations(tilted.candidates, path, opt)
    yawed = _apply_yaws(cam_xyz, tilted, path, t_ok, t_frame, opt)
    dz = tilted.dz
    if tilted.tilt_ok.any():
        idx = np.flatnonzero(tilted.tilt_ok)
        dz = np.interp(np.arange(n), idx, dz[idx])
    t3 = np.c_[t_frame, dz]
    drift = float(np.median(np.linalg.norm(t3[t_ok], axis=1))) if t_ok.any() else 0.0
    return FrameLevelResult(world_from_world=yawed.world_from_world, tilt_ok=tilted.tilt_ok,
                            yaw_ok=yawed.yaw_ok, yaw_deg=yawed.yaw_deg,
                            tilt_deg=tilted.tilt_deg, t_ok=t_ok, score=yawed.score,
                            constraint=yawed.constraint, translation=t3, drift_m=drift)


@dataclass(frozen=True)
class Candidate:
    """One x-y-yaw hypothesis of a frame against the plan (after ICP).

    Attributes
    ----------
    correction: the 2-D correction (yaw about the camera, translation), metres / radians.
    score: fine score (fraction of points on the plan, 0–1).
    constraint: ICP's translation constraint (smallest eigenvalue share; a bare corridor wall
        has about 0).
    informative: whether its translation may be used (constraint and score high enough).
    """

    correction: Correction2D
    score: float
    constraint: float
    informative: bool


@dataclass(frozen=True)
class _TiltPass:
    """Steps 1-2 of :func:`level_frames` per frame: tilts (N of (4, 4)), tilt_ok (N,),
    tilt_deg (N,), dz (N,) metres (0 without a floor fit) and the x-y-yaw hypotheses."""

    tilts: list[F64]
    tilt_ok: NDArray[np.bool_]
    tilt_deg: F64
    dz: F64
    candidates: list[list[Candidate]]


@dataclass(frozen=True)
class _YawPass:
    """The kept yaws: world_from_world (N, 4, 4), yaw_ok (N,), yaw_deg (N,), score (N,),
    constraint (N,) of the hypothesis each frame's yaw comes from (0 without one)."""

    world_from_world: F64
    yaw_ok: NDArray[np.bool_]
    yaw_deg: F64
    score: F64
    constraint: F64


def _fit_tilt(floor_pts: F64, cam: F64, floor_z: float | None, opt: FrameLevelOptions
              ) -> tuple[F64, float, float] | None:
    """A frame's tilt about its camera from its (F, 3) floor points: ``(m (4, 4), dz metres,
    tilt degrees)``, or None when there is no fit or it is not kept."""
    if floor_z is None or len(floor_pts) < opt.min_floor_points:
        return None
    spread = np.linalg.eigvalsh(np.cov(floor_pts[:, :2].T))[0]
    lv = level_window(floor_pts, np.zeros((0, 3)), floor_z, None, cam,
                      min_points=opt.min_floor_points)
    tilt = float(np.rad2deg(Rotation.from_matrix(lv.rotation).magnitude()))
    if not (lv.ok and lv.inlier_ratio >= opt.min_inlier_ratio and tilt <= opt.max_tilt_deg
            and np.sqrt(max(spread, 0.0)) >= opt.min_floor_spread_m):
        return None
    m = np.eye(4)
    m[:3, :3] = lv.rotation
    m[:3, 3] = cam - lv.rotation @ cam
    return m, lv.dz, tilt


def _tilt_and_hypotheses(
    cam_xyz: F64,
    frame_points: Callable[[int], dict[str, F64]],
    floor_z_of: Callable[[F64, float], float | None],
    maps_of: Callable[[float | None], PlanMaps],
    wall_band_m: float,
    ceiling_z_of: Callable[[float | None], float | None],
    icp: dict[str, float],
    yaws: F64,
    opt: FrameLevelOptions,
    rng: np.random.Generator,
) -> _TiltPass:
    """Steps 1-2, frame by frame: the tilt from the floor, then the x-y-yaw hypotheses of the
    tilted wall/column points (``yaws`` (Y,) radians)."""
    n = len(cam_xyz)
    tilted = _TiltPass(tilts=[], tilt_ok=np.zeros(n, dtype=bool), tilt_deg=np.zeros(n),
                       dz=np.zeros(n), candidates=[])
    dz_last = 0.0
    for i in progress(range(n), desc="coarse: frames", unit="frame"):
        cam = np.asarray(cam_xyz[i], dtype=np.float64)
        pts = frame_points(i)
        floor_z = floor_z_of(pts["floor"], float(cam[2]))
        m = np.eye(4)
        fit = _fit_tilt(pts["floor"], cam, floor_z, opt)
        if fit is not None:
            m, dz_last, tilt = fit
            tilted.dz[i] = dz_last
            tilted.tilt_ok[i] = True
            tilted.tilt_deg[i] = tilt
        tilted.tilts.append(m)
        points = _plan_points(pts, m, dz_last, floor_z, ceiling_z_of(floor_z), wall_band_m)
        tilted.candidates.append(_frame_candidates(points, cam, floor_z, maps_of, yaws, icp, opt,
                                                   rng))
    return tilted


def _path_translations(candidates: list[list[Candidate]], path: NDArray[np.int64],
                       opt: FrameLevelOptions) -> tuple[NDArray[np.bool_], F64]:
    """Step 3 after the path: ``(t_ok (N,), t_frame (N, 2) metres)``, outliers among the
    kept translations dropped and the others interpolated."""
    n = len(candidates)
    t_frame = np.zeros((n, 2))
    t_ok = path >= 0
    for i in np.flatnonzero(t_ok):
        t_frame[i] = candidates[i][path[i]].correction.t
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
        for c in range(2):
            t_frame[:, c] = np.interp(np.arange(n), idx, t_frame[idx, c])
    return t_ok, t_frame


def _apply_yaws(cam_xyz: F64, tilted: _TiltPass, path: NDArray[np.int64],
                t_ok: NDArray[np.bool_], t_frame: F64, opt: FrameLevelOptions) -> _YawPass:
    """Each frame's yaw about its camera (radians) on top of its tilt."""
    n = len(cam_xyz)
    yawed = _YawPass(world_from_world=np.tile(np.eye(4), (n, 1, 1)),
                     yaw_ok=np.zeros(n, dtype=bool), yaw_deg=np.zeros(n), score=np.zeros(n),
                     constraint=np.zeros(n))
    # Each frame's yaw comes from its hypothesis on the path, or the one nearest to it.
    for i in range(n):
        pick = _yaw_candidate(tilted.candidates[i], int(path[i]) if t_ok[i] else -1, t_frame[i],
                              opt)
        m = tilted.tilts[i]
        if pick is not None:
            cam = np.asarray(cam_xyz[i], dtype=np.float64)
            r = Rotation.from_rotvec([0.0, 0.0, pick.correction.yaw]).as_matrix()
            m = np.r_[np.c_[r, cam - r @ cam], [[0.0, 0.0, 0.0, 1.0]]] @ m
            yawed.yaw_ok[i] = True
            yawed.yaw_deg[i] = float(np.rad2deg(pick.correction.yaw))
            yawed.score[i] = pick.score
            yawed.constraint[i] = pick.constraint
        yawed.world_from_world[i] = m
    return yawed


def _plan_points(pts: dict[str, F64], m: F64, dz: float, floor_z: float | None,
                 ceil_z: float | None, wall_band_m: float) -> tuple[F64, I32]:
    """A frame's wall and column points after its tilt ``m`` and height ``dz``, without those
    within ``wall_band_m`` of the floor or ceiling: ``(xy (M, 2), class (M,))``."""
    from bimcap.labels import Label

    xy, cls_ = [], []
    for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
        q = pts[c] @ m[:3, :3].T + m[:3, 3] + np.array([0.0, 0.0, dz])
        keep = np.ones(len(q), dtype=bool)
        if floor_z is not None and wall_band_m > 0:
            keep &= q[:, 2] > floor_z + wall_band_m
            if ceil_z is not None:
                keep &= q[:, 2] < ceil_z - wall_band_m
        xy.append(q[keep, :2])
        cls_.append(np.full(int(keep.sum()), int(lab), np.int32))
    p_xy = np.concatenate(xy) if xy else np.zeros((0, 2))
    return p_xy, np.concatenate(cls_).astype(np.int32)


def _frame_candidates(points: tuple[F64, I32], cam: F64, floor_z: float | None,
                      maps_of: Callable[[float | None], PlanMaps], yaws: F64,
                      icp: dict[str, float], opt: FrameLevelOptions,
                      rng: np.random.Generator) -> list[Candidate]:
    """The top ``opt.top_k`` x-y-yaw hypotheses of one frame about its input pose, each refined
    by ICP; those with too few inliers or a yaw outside the range are dropped."""
    p_xy, p_cls = points
    if len(p_xy) < opt.min_points:
        return []
    if len(p_xy) > opt.max_points:
        sel = np.sort(rng.choice(len(p_xy), opt.max_points, replace=False))
        p_xy, p_cls = p_xy[sel], p_cls[sel]
    maps = maps_of(floor_z)
    pivot = cam[:2]
    view = p_xy - pivot
    vol, res, nn = score_volume(p_xy, p_cls, view, maps, pivot, yaws, opt.xy_range_m)
    hyps = top_hypotheses(vol, yaws, res, nn, opt.top_k, 0.3, np.deg2rad(3.0))
    # The input pose is always a hypothesis: the track may then keep it, at its own score,
    # instead of choosing between aliases when the input is already right.
    if not any(np.linalg.norm(h.t) < 0.3 and abs(h.yaw) < np.deg2rad(3.0) for h in hyps):
        hyps.append(Hypothesis(0.0, np.zeros(2), 0.0))

    def associate(q: F64, q_class: I32, v: F64, maps: PlanMaps = maps) -> tuple[F64, F64]:
        return maps.nearest(q, maps.layer_of(q_class, v))

    # The hypotheses' ICPs in lock-step (one association call per iteration for all of them;
    # each result the bits of its own :func:`.icp.icp_2d`).
    fits = icp_2d_many(p_xy, p_cls, associate, [Correction2D(h.yaw, h.t, pivot) for h in hyps],
                       view, **icp)
    out = []
    for fit in fits:
        corr = fit.correction
        sc, _ = maps.fine_eval(corr.apply(p_xy), maps.layer_of(p_cls, view @ rot2(corr.yaw).T))
        score = float(sc.mean())
        if (fit.inlier_ratio >= opt.min_inlier_ratio
                and abs(corr.yaw) <= np.deg2rad(opt.yaw_range_deg)):
            informative = fit.constraint >= opt.min_constraint and score >= opt.min_score
            out.append(Candidate(corr, score, float(fit.constraint), bool(informative)))
    return out


def track_translations(candidates: list[list[Candidate]], opt: FrameLevelOptions,
                       lookback: int = 12) -> NDArray[np.int64]:
    """The translation path through the frames' hypotheses: for each frame the index of its
    chosen :class:`Candidate`, or -1 (left out).

    The path minimises ``Σ prior + Σ steps + Σ fits + Σ skips`` over the informative hypotheses:
    ``|t_first|² / 2σ_prior²``; ``|t_j − t_i|² / (2 σ_step² (j − i))`` between consecutive chosen
    frames i < j; ``w (1 − score)`` per chosen hypothesis; ``skip`` per frame with informative
    hypotheses that the path leaves out. A shortest path in a DAG (frames in order, up to
    ``lookback`` informative frames back), so every frame's choice weighs all the others.
    """
    n = len(candidates)
    path = np.full(n, -1, dtype=np.int64)
    frames = [i for i in range(n) if any(c.informative for c in candidates[i])]
    if not frames:
        return path
    opts_t = [np.array([c.correction.t for c in candidates[i] if c.informative]) for i in frames]
    opts_k = [np.array([k for k, c in enumerate(candidates[i]) if c.informative]) for i in frames]
    emit = [opt.track_score_weight * (1.0 - np.array([candidates[i][k].score for k in ks]))
            for i, ks in zip(frames, opts_k, strict=True)]
    m = len(frames)
    cost: list[F64] = []
    back: list[NDArray[np.int64]] = []   # (predecessor position in `frames`, its hypothesis)
    for j in range(m):
        t_j = opts_t[j]
        best = (0.5 * (t_j ** 2).sum(1) / opt.track_prior_sigma_m ** 2 + opt.track_skip_cost * j)
        arg = np.full((len(t_j), 2), -1, dtype=np.int64)
        for i in range(max(0, j - lookback), j):
            gap = frames[j] - frames[i]
            d2 = ((t_j[None, :, :] - opts_t[i][:, None, :]) ** 2).sum(-1)  # (k_i, k_j)
            via = (cost[i][:, None] + 0.5 * d2 / (opt.track_step_sigma_m ** 2 * gap)
                   + opt.track_skip_cost * (j - i - 1))
            g = np.argmin(via, axis=0)
            v = via[g, np.arange(len(t_j))]
            better = v < best
            best = np.where(better, v, best)
            arg[better] = np.stack([np.full(int(better.sum()), i), g[better]], 1)
        cost.append(best + emit[j])
        back.append(arg)
    total = [cost[j] + opt.track_skip_cost * (m - 1 - j) for j in range(m)]
    j = int(np.argmin([t.min() for t in total]))
    h = int(np.argmin(total[j]))
    while j >= 0:
        path[frames[j]] = int(opts_k[j][h])
        j, h = (int(back[j][h, 0]), int(back[j][h, 1]))
    return path


def _yaw_candidate(cands: list[Candidate], chosen: int, t_path: F64,
                   opt: FrameLevelOptions) -> Candidate | None:
    """The hypothesis whose yaw a frame keeps: the one on the path; else the one nearest the
    path's (interpolated) translation, if within ``2 · track_max_step_m``."""
    if chosen >= 0:
        return cands[chosen]
    if not cands:
        return None
    d = [float(np.linalg.norm(c.correction.t - t_path)) for c in cands]
    k = int(np.argmin(d))
    return cands[k] if d[k] <= 2.0 * opt.track_max_step_m else None
