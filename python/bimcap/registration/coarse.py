"""The coarse registration stage: bring drifted frames near their true pose using the BIM alone.

0. (``frame_orientation``, on by default) **per frame** (:mod:`.frame_level`):
   real initial poses carry independent per-frame rotation errors (several degrees from one frame
   to the next) and a translation random walk, so a window's frames are not rigidly consistent.
   Each frame is first rotated about its own camera (tilt from its floor points, yaw from its
   walls), and its translation is tracked frame by frame; the part of that translation beyond
   ``frame_deadband_m`` is applied. If the median tracked translation is below ``frame_gate_m``
   the input is already within the bundle adjustment's reach and is returned unchanged.
   The tracked translation is a proposal of single frames, each of which may fit an alias (a
   mirrored flat, a repeated room): if the windows below are searched from it and none is
   accepted, it is dropped and the windows start again from the input positions (with the
   per-frame rotations); ``CoarseResult.translation_dropped`` records it. Otherwise it stands
   only in the accepted windows: a rejected window's frames drop their own and take the
   accepted windows' interpolated corrections (``frame_translation_per_window``).

Then per window of ``window_frames`` consecutive frames (whose relative poses are trusted: drift is
smooth):

1. **gravity/height** (:mod:`.gravity`): floor and ceiling points fix pitch, roll and z against
   the BIM's floor/ceiling heights;
2. **correlative search** (:mod:`.correlative`): the window's wall and column points, projected
   to the floor plane, are matched over x, y and yaw against robust score maps of the floor
   plan (truncated Gaussians of a distance field, one per class); the top-K local maxima are
   kept;
3. **ICP** (:mod:`.icp`): each hypothesis is refined by robust point-to-segment ICP and scored
   again at fine resolution;
4. **continuity** (:mod:`.continuity`): a Viterbi pass over the windows picks one hypothesis per
   window so that neighbouring corrections agree (this resolves corridors that are ambiguous
   along their axis and symmetric rooms).

Accepted windows' corrections (4×4 world-from-world) are interpolated per frame between window
centres (slerp / lerp), and rejected windows take the interpolation of their accepted
neighbours. Finally (5.) every frame of an accepted window gets a short ICP of its own, which
takes out the drift *inside* a window (kept only when well constrained and small).

Typical use, from the solver problem's arrays (docs/architecture.md)::

    samples = SemanticSamples.from_arrays(wall_frame=..., wall_p_in_cam=..., column_frame=...,
                                          column_p_in_cam=..., floor_frame=..., ...)
    plan = FloorPlan.from_planes(segments, segment_class, segment_z, planes, plane_kind)
    result = coarse_register(world_from_cam, samples, plan, CoarseOptions())
    world_from_cam = result.poses   # the bundle adjustment starts from here

All arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order, points in the OpenCV camera
frame, metres.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix, transform_points
from bimcap.labels import Label
from bimcap.progress import progress
from bimcap.registration._coarse_steps import (
    _CLASSES,
    _Candidate,
    _pick_floor,
    _register_window,
    _split_windows,
    _StageClock,
    _subsample,
    _WindowFit,
    _Windows,
    _yaw_grid,
    _YawGrid,
)
from bimcap.registration.continuity import transition_cost, viterbi_chain
from bimcap.registration.errors import RegistrationInputError
from bimcap.registration.frame_level import (
    FrameLevelOptions,
    FrameLevelResult,
    level_frames,
)
from bimcap.registration.icp import Correction2D, icp_2d
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


# ------------------------------------------------------------------------------------------------
# Inputs.


@dataclass(frozen=True)
class SemanticSamples:
    """Labelled points of every frame in its camera frame (the front end's semantic samples).

    Attributes
    ----------
    wall_frame: (W,) int32 frame index; wall_p_in_cam: (W, 3) metres, OpenCV camera frame.
    column_frame, column_p_in_cam; floor_frame, floor_p_in_cam; ceiling_frame,
    ceiling_p_in_cam: likewise (any may be empty).
    """

    wall_frame: I32
    wall_p_in_cam: F64
    column_frame: I32
    column_p_in_cam: F64
    floor_frame: I32
    floor_p_in_cam: F64
    ceiling_frame: I32
    ceiling_p_in_cam: F64

    @classmethod
    def from_arrays(cls, **arrays: ArrayLike | None) -> SemanticSamples:
        """Build from keyword arrays named as in the solver problem (``wall_frame`` ...);
        a missing or None class is empty. Raises :class:`RegistrationInputError` on bad shapes."""
        known = {f"{c}_{s}" for c in _CLASSES for s in ("frame", "p_in_cam")}
        unknown = sorted(set(arrays) - known)
        if unknown:
            raise RegistrationInputError("unknown array", None, unknown[0])
        out: dict[str, Any] = {}
        for c in _CLASSES:
            fr, p = arrays.get(f"{c}_frame"), arrays.get(f"{c}_p_in_cam")
            fr_a = np.zeros(0, np.int32) if fr is None else np.asarray(fr)
            p_a = np.zeros((0, 3)) if p is None else np.asarray(p, dtype=np.float64)
            if fr_a.ndim != 1 or not (fr_a.size == 0 or np.issubdtype(fr_a.dtype, np.integer)):
                raise RegistrationInputError(f"must be (M,) integers, got {fr_a.shape} "
                                             f"{fr_a.dtype}", None, f"{c}_frame")
            if p_a.ndim != 2 or p_a.shape[1] != 3 or len(p_a) != len(fr_a):
                raise RegistrationInputError(f"must be ({len(fr_a)}, 3), got {p_a.shape}", None,
                                             f"{c}_p_in_cam")
            if not np.isfinite(p_a).all():
                raise RegistrationInputError("contains NaN or inf", None, f"{c}_p_in_cam")
            out[f"{c}_frame"] = fr_a.astype(np.int32)
            out[f"{c}_p_in_cam"] = p_a
        return cls(**out)

    def check_frames(self, n_frames: int) -> None:
        for c in _CLASSES:
            fr = getattr(self, f"{c}_frame")
            if fr.size and (fr.min() < 0 or fr.max() >= n_frames):
                raise RegistrationInputError(f"frame index outside [0, {n_frames})", None,
                                             f"{c}_frame")


@dataclass(frozen=True)
class FloorPlan:
    """The BIM as the coarse stage sees it.

    Attributes
    ----------
    segments: (S, 4) ``x1 y1 x2 y2`` metres.
    segment_class: (S,) int32, ``Label.WALL`` (1) or ``Label.COLUMN`` (4).
    segment_z: (S, 2) the z range each segment applies to, or None (all storeys alike).
    floor_heights: (Lf,) world z of the floors (metres), may be empty.
    ceiling_heights: (Lc,) world z of the ceilings, may be empty.
    """

    segments: F64
    segment_class: I32
    segment_z: F64 | None = None
    floor_heights: F64 = field(default_factory=lambda: np.zeros(0))
    ceiling_heights: F64 = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        seg = np.asarray(self.segments, dtype=np.float64)
        if seg.ndim != 2 or seg.shape[1] != 4 or len(seg) == 0 or not np.isfinite(seg).all():
            raise RegistrationInputError(f"must be finite (S>0, 4), got {seg.shape}", None,
                                         "segments")
        cls_ = np.asarray(self.segment_class).astype(np.int32).reshape(-1)
        if len(cls_) != len(seg) or not np.isin(cls_, (Label.WALL, Label.COLUMN)).all():
            raise RegistrationInputError("must be (S,) of 1 (wall) / 4 (column)", None,
                                         "segment_class")
        object.__setattr__(self, "segments", seg)
        object.__setattr__(self, "segment_class", cls_)
        if self.segment_z is not None:
            z = np.asarray(self.segment_z, dtype=np.float64)
            if z.shape != (len(seg), 2):
                raise RegistrationInputError(f"must be ({len(seg)}, 2), got {z.shape}", None,
                                             "segment_z")
            object.__setattr__(self, "segment_z", z)
        object.__setattr__(self, "floor_heights",
                           np.sort(np.asarray(self.floor_heights, dtype=np.float64).reshape(-1)))
        object.__setattr__(self, "ceiling_heights",
                           np.sort(np.asarray(self.ceiling_heights, dtype=np.float64).reshape(-1)))

    @classmethod
    def from_planes(cls, segments: ArrayLike, segment_class: ArrayLike,
                    segment_z: ArrayLike | None, planes: ArrayLike, plane_kind: ArrayLike
                    ) -> FloorPlan:
        """From the solver arrays: ``planes (Q, 4)`` ``n·p + d`` and their kinds
        (``Label.FLOOR`` / ``Label.CEILING``); only horizontal planes (|n_z| > 0.99) count."""
        pl = np.asarray(planes, dtype=np.float64).reshape(-1, 4)
        kind = np.asarray(plane_kind).reshape(-1)
        if len(kind) != len(pl):
            raise RegistrationInputError(f"must be ({len(pl)},)", None, "plane_kind")
        horiz = np.abs(pl[:, 2]) > 0.99
        height = -pl[:, 3] / np.where(horiz, pl[:, 2], 1.0)
        return cls(np.asarray(segments, dtype=np.float64), np.asarray(segment_class),
                   None if segment_z is None else np.asarray(segment_z, dtype=np.float64),
                   np.unique(height[horiz & (kind == Label.FLOOR)]),
                   np.unique(height[horiz & (kind == Label.CEILING)]))


# ------------------------------------------------------------------------------------------------
# Options and results.


@dataclass(frozen=True)
class CoarseOptions:
    """Settings of :func:`coarse_register` (lengths in metres, angles in degrees).

    Attributes
    ----------
    window_frames: frames per window (their relative poses are trusted).
    xy_range_m, yaw_range_deg: half-widths of the search around the levelled initial pose;
        ``yaw_range_deg = 180`` searches the full circle.
    yaw_step_deg, coarse_resolution_m, coarse_sigma_m: the correlative grid and the width of
        its score (truncated Gaussian of the distance to the plan).
    fine_resolution_m, fine_sigma_m: the maps that score hypotheses after ICP and that find
        the nearest segment for ICP.
    score_truncate: the score is 0 beyond ``score_truncate · sigma`` (clutter, missing walls).
    view_bins: ray-direction bins of the visibility test (:mod:`.plan_maps`); 1 disables it.
    column_weight: weight of column points relative to wall points.
    top_k, nms_xy_m, nms_yaw_deg: hypotheses kept per window and their suppression radius.
    icp_*: the point-to-segment ICP (radius shrinks from start to end; Huber scale).
    inlier_m: a point within this distance of its segment is an inlier.
    max_points_per_window: random subsample for ICP and scoring.
    wall_band_m: wall/column points within this height of the floor or ceiling are ignored.
    plan_cut_height_m: segments apply to a window if their ``segment_z`` range holds
        ``floor + plan_cut_height_m``.
    use_gravity, use_correlative, use_icp, use_continuity, interpolate: stage switches;
        ``use_correlative=False`` leaves a plain local ICP from the initial pose (the
        benchmark's baseline).
    refine_frames, frame_max_points, frame_max_step_m, frame_max_step_deg: after the window
        corrections, each frame of an accepted window gets its own short ICP (radius
        ``icp_radius_end_m · 2`` → ``icp_radius_end_m``), which takes out the drift *inside*
        a window; a frame's fit counts only if it is well constrained, has enough inliers and
        moved less than the step limits.
    frame_smooth: each frame then takes the median of the counted per-frame corrections
        within ± this many frames (drift is smooth; one frame's fit is noisy).
    continuity_weight, continuity_sigma_t_m, continuity_sigma_yaw_deg, continuity_cap,
        score_sigma: the Viterbi chain's costs (:mod:`.continuity`).
    min_points, min_inlier_ratio, min_score, min_constraint: a window is accepted only with
        enough points, inliers and fine score, a translation constraint (not a bare corridor)
        and an optimum inside the search range. On the demo building a right match scores
        0.65-0.9 with 72-97 % inliers (30 % to 3 % clutter) and a wrong one about 0.43 with
        48 %; the defaults sit between.
    seed: seeds the random point subsampling.
    frame_orientation, frame_yaw_range_deg, frame_xy_range_m, frame_min_inlier_ratio,
        frame_translation, frame_deadband_m, frame_gate_m, frame_rotate_when_near: before
        the windows, every frame is rotated about its own camera centre: tilt from its floor
        points, yaw from a correlative search + ICP of its wall/column points (kept when the
        best fit has ``frame_min_inlier_ratio`` inliers); see :mod:`.frame_level`. This takes
        out independent per-frame orientation errors that make a window's frames disagree.
    near_probe_frames, near_probe_m, near_probe_min_tracked: stage 0 first runs on
        ``near_probe_frames`` evenly spaced frames alone; when at least
        ``near_probe_min_tracked`` of them track a translation and its median is below
        ``near_probe_m`` (well inside ``frame_gate_m``) the input is handed back without the
        pass over every frame (about a quarter of its time at 60 frames, a constant cost for
        longer walks). 0: off; off for walks shorter than twice ``near_probe_frames`` and
        with ``frame_rotate_when_near``. On nine worlds of ``bench_generalization.py`` and the
        demo world (fixed point and Exp. 1/2/3, 40 runs) it handed back 18 runs, each one the
        full pass also hands back (full 0.03-0.14 m, probe 0.01-0.14 m); where the full pass
        reads a drift of 0.35 m or more the probe read 0.38 m or more (Exp. 1: 0.67 m or more)
        or could not tell.
    near_probe_yaw_step_deg: the probe's yaw step (stage 0's correlative search runs at
        ``yaw_step_deg``): each frame's hypotheses are refined by ICP, which takes out the
        half step, and the probe only reads the median tracked drift. 2° instead of 1° halves
        the probe's correlation and read the same drift within 0.04 m on the 40 runs above
        (the same 18 hand-backs; 2026-11-27, docs/speed.md).
    frame_translation_per_window: stage 0's tracked translation stands only in accepted
        windows; the frames of rejected windows take, on their stage-0 rotations alone, the
        interpolation of the accepted windows' whole corrections (see
        :func:`_confirmed_translation`; off: they keep their own tracked translation).
    """

    window_frames: int = 10
    xy_range_m: float = 2.0
    yaw_range_deg: float = 20.0
    yaw_step_deg: float = 1.0
    coarse_resolution_m: float = 0.1
    coarse_sigma_m: float = 0.15
    fine_resolution_m: float = 0.025
    fine_sigma_m: float = 0.05
    score_truncate: float = 3.0
    view_bins: int = 4
    column_weight: float = 1.0
    top_k: int = 8
    nms_xy_m: float = 0.3
    nms_yaw_deg: float = 3.0
    icp_iterations: int = 12
    icp_radius_start_m: float = 0.3
    icp_radius_end_m: float = 0.06
    icp_huber_m: float = 0.03
    inlier_m: float = 0.1
    max_points_per_window: int = 3000
    wall_band_m: float = 0.15
    plan_cut_height_m: float = 1.0
    use_gravity: bool = True
    use_correlative: bool = True
    use_icp: bool = True
    use_continuity: bool = True
    interpolate: bool = True
    refine_frames: bool = True
    frame_smooth: int = 3
    frame_max_points: int = 1500
    frame_max_step_m: float = 0.2
    frame_max_step_deg: float = 2.0
    continuity_weight: float = 1.0
    continuity_sigma_t_m: float = 0.3
    continuity_sigma_yaw_deg: float = 3.0
    continuity_cap: float = 50.0
    score_sigma: float = 0.05
    min_points: int = 50
    min_inlier_ratio: float = 0.55
    min_score: float = 0.5
    min_constraint: float = 0.02
    seed: int = 0
    frame_orientation: bool = True
    frame_yaw_range_deg: float = 25.0
    frame_xy_range_m: float = 2.5
    frame_min_inlier_ratio: float = 0.5
    frame_translation: bool = True
    frame_deadband_m: float = 0.3
    frame_gate_m: float = 0.35
    frame_rotate_when_near: bool = False
    near_probe_frames: int = 15
    near_probe_m: float = 0.15
    near_probe_min_tracked: int = 5
    near_probe_yaw_step_deg: float = 2.0
    frame_translation_per_window: bool = True

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`RegistrationInputError` naming the first bad field."""
        positive = ("xy_range_m", "yaw_step_deg", "coarse_resolution_m", "coarse_sigma_m",
                    "fine_resolution_m", "fine_sigma_m", "score_truncate", "nms_xy_m",
                    "nms_yaw_deg", "icp_radius_start_m", "icp_radius_end_m", "icp_huber_m",
                    "inlier_m", "continuity_sigma_t_m",
                    "continuity_sigma_yaw_deg", "continuity_cap", "score_sigma",
                    "frame_max_step_m", "frame_max_step_deg", "frame_xy_range_m",
                    "near_probe_yaw_step_deg")
        for name in ("frame_deadband_m", "frame_gate_m", "near_probe_m", "near_probe_frames",
                     "near_probe_min_tracked"):
            if getattr(self, name) < 0:
                raise RegistrationInputError("must be >= 0", None, name)
        for name, value in asdict(self).items():
            if isinstance(value, float) and not np.isfinite(value):
                raise RegistrationInputError(f"must be finite, got {value}", None, name)
            if name in positive and not value > 0:
                raise RegistrationInputError(f"must be > 0, got {value}", None, name)
        for name in ("window_frames", "top_k", "icp_iterations", "max_points_per_window",
                     "min_points", "view_bins", "frame_max_points"):
            if getattr(self, name) < 1:
                raise RegistrationInputError(f"must be >= 1, got {getattr(self, name)}", None,
                                             name)
        for name in ("yaw_range_deg", "frame_yaw_range_deg"):
            if not 0 <= getattr(self, name) <= 180:
                raise RegistrationInputError("must be in [0, 180]", None, name)
        if not 0 <= self.frame_min_inlier_ratio <= 1:
            raise RegistrationInputError("must be in [0, 1]", None, "frame_min_inlier_ratio")
        for name in ("column_weight", "continuity_weight", "wall_band_m", "frame_smooth"):
            if getattr(self, name) < 0:
                raise RegistrationInputError("must be >= 0", None, name)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class WindowResult:
    """What the coarse stage decided for one window of frames ``[start, stop)``.

    ``yaw_deg``/``t_m``/``pivot`` describe the chosen planar correction
    ``q = R(yaw)(p - pivot) + pivot + t`` (after levelling); ``dz_m``/``tilt_deg`` the levelling.
    ``constraint`` is the ICP's translation constraint (see :class:`.icp.IcpResult`); a
    degenerate window (a corridor seen without ends or doors) is not accepted and takes the
    interpolated correction of its neighbours. ``reason`` says why a window was not accepted
    ("" when it was).
    """

    start: int
    stop: int
    n_points: int
    n_hypotheses: int
    yaw_deg: float
    t_m: tuple[float, float]
    pivot: tuple[float, float]
    dz_m: float
    tilt_deg: float
    score: float
    inlier_ratio: float
    constraint: float
    best_score: float
    accepted: bool
    reason: str
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN, e.g. ``constraint`` without ICP, becomes None)."""
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                for k, v in asdict(self).items()}


@dataclass
class CoarseResult:
    """Output of :func:`coarse_register`.

    Attributes
    ----------
    poses: (N, 7) corrected ``world_from_cam``, TUM order.
    frame_score: (N,) mean fine score of each frame's wall/column points at ``poses`` (0..1).
    frame_inlier_ratio: (N,) fraction of them within ``inlier_m`` of a same-class segment.
    accepted: (N,) bool, the frame's window passed the checks (others were interpolated).
    frame_window: (N,) int32 window index of each frame.
    windows: one :class:`WindowResult` per window.
    frame_level: the per-frame orientation pass (stage 0), None when it was off.
    translation_dropped: stage 0's tracked translation was applied but no window confirmed it,
        so the windows were run again from the input positions (see :func:`coarse_register`).
    near_probe_drift_m: the tracked drift of stage 0 on ``near_probe_frames`` frames
        when that probe handed the input back (``frame_level`` is then None); else None.
    timings: seconds per step (``frame_orientation``, ``level``, ``maps``, ``correlative``,
        ``icp``, ``continuity``, ``apply``, ``total``) and ``per_window`` (mean time of one
        window's levelling, search and ICP, without building the plan maps, which happens once
        per storey); the same as CPU time of this process in ``cpu_total`` and
        ``cpu_per_window`` (all threads; useful on a shared machine). ``refine_frames`` is the
        per-frame ICP's time and ``frames_refined`` the number of frames that kept it.
    """

    poses: F64
    frame_score: F64
    frame_inlier_ratio: F64
    accepted: NDArray[np.bool_]
    frame_window: I32
    windows: list[WindowResult]
    timings: dict[str, float]
    options: CoarseOptions
    frame_level: FrameLevelResult | None = None
    translation_dropped: bool = False
    near_probe_drift_m: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (per-frame arrays as lists)."""
        return {
            "n_frames": len(self.poses),
            "n_windows": len(self.windows),
            "accepted_fraction": float(self.accepted.mean()) if len(self.accepted) else 0.0,
            "poses": self.poses.tolist(),
            "frame_score": self.frame_score.tolist(),
            "frame_inlier_ratio": self.frame_inlier_ratio.tolist(),
            "accepted": self.accepted.astype(bool).tolist(),
            "frame_window": self.frame_window.tolist(),
            "windows": [w.to_dict() for w in self.windows],
            "timings": dict(self.timings),
            "options": self.options.to_dict(),
            "frame_level": None if self.frame_level is None else self.frame_level.to_dict(),
            "translation_dropped": self.translation_dropped,
            "near_probe_drift_m": self.near_probe_drift_m,
        }


# ------------------------------------------------------------------------------------------------
# Internals.


def _ceiling_above(plan: FloorPlan, z: float | None) -> float | None:
    if z is None or not len(plan.ceiling_heights):
        return None
    above = plan.ceiling_heights[plan.ceiling_heights > z]
    return float(above.min()) if len(above) else None


def _level_frames(poses: F64, samples: SemanticSamples, plan: FloorPlan,
                  maps_for: Callable[[float | None], PlanMaps], opt: CoarseOptions,
                  rng: np.random.Generator, frames: I32 | None = None) -> FrameLevelResult:
    """Stage 0: :func:`.frame_level.level_frames` with this stage's settings, on every frame
    or on the frames ``frames`` (K,) alone (its per-frame arrays then have K rows)."""
    sel = np.arange(len(poses)) if frames is None else np.asarray(frames)
    order = {}
    bounds = {}
    for c in ("wall", "column", "floor"):
        fr = getattr(samples, f"{c}_frame")
        order[c] = np.argsort(fr, kind="stable")
        bounds[c] = np.searchsorted(fr[order[c]], np.arange(len(poses) + 1))

    def frame_points(j: int) -> dict[str, F64]:
        i = int(sel[j])
        out = {}
        for c in ("wall", "column", "floor"):
            idx = order[c][bounds[c][i]:bounds[c][i + 1]]
            p = getattr(samples, f"{c}_p_in_cam")[idx]
            out[c] = (transform_points(np.repeat(poses[i:i + 1], len(p), 0), p) if len(p)
                      else np.zeros((0, 3)))
        return out

    def floor_z_of(floor_pts: F64, cam_z: float) -> float | None:
        return _pick_floor(plan, floor_pts[:, 2], cam_z, cam_z)

    fopt = FrameLevelOptions(yaw_range_deg=opt.frame_yaw_range_deg,
                             yaw_step_deg=opt.yaw_step_deg, xy_range_m=opt.frame_xy_range_m,
                             min_points=opt.min_points,
                             min_inlier_ratio=opt.frame_min_inlier_ratio,
                             max_points=opt.frame_max_points)
    icp = {"radius_start_m": opt.icp_radius_start_m, "radius_end_m": opt.icp_radius_end_m,
           "iterations": opt.icp_iterations, "huber_m": opt.icp_huber_m,
           "inlier_m": opt.inlier_m}
    return level_frames(poses[sel, :3], frame_points, floor_z_of, maps_for, opt.wall_band_m,
                        lambda z: _ceiling_above(plan, z), icp, fopt, rng)


def _build_maps(plan: FloorPlan, mask: NDArray[np.bool_], opt: CoarseOptions) -> PlanMaps:
    xy = plan.segments.reshape(-1, 2)
    bounds = (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max())
    return PlanMaps.build(plan.segments[mask], plan.segment_class[mask], bounds,
                          opt.xy_range_m + 3.0, opt.view_bins, opt.coarse_resolution_m,
                          opt.coarse_sigma_m, opt.fine_resolution_m, opt.fine_sigma_m,
                          opt.score_truncate)


def _lift(c2: Correction2D) -> F64:
    m3 = c2.matrix()
    m = np.eye(4)
    m[:2, :2] = m3[:2, :2]
    m[:2, 3] = m3[:2, 2]
    return m


def _interpolate(nodes: NDArray[np.float64], mats: list[F64], n_frames: int) -> F64:
    """(N, 4, 4) per-frame corrections interpolated between node frame positions."""
    out = np.tile(np.eye(4), (n_frames, 1, 1))
    if len(nodes) == 0:
        return out
    if len(nodes) == 1:
        out[:] = mats[0]
        return out
    idx = np.arange(n_frames, dtype=np.float64)
    rots = Rotation.from_matrix(np.array([m[:3, :3] for m in mats]))
    slerp = Slerp(nodes, rots)
    clamped = np.clip(idx, nodes[0], nodes[-1])
    out[:, :3, :3] = slerp(clamped).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(clamped, nodes, [m[k, 3] for m in mats])
    return out


def _refine_frames(per_frame: F64, poses: F64, world_pts: dict[str, F64], frames: dict[str, I32],
                   frame_window: I32, win_maps: list[PlanMaps], win_meta: list[dict[str, Any]],
                   accepted: NDArray[np.bool_], opt: CoarseOptions, rng: np.random.Generator
                   ) -> int:
    """Per-frame ICP on top of the interpolated window corrections, smoothed over
    ``±frame_smooth`` frames (in place); returns the number of frames that were refined."""
    order = {c: np.argsort(frames[c], kind="stable") for c in ("wall", "column")}
    bounds = {c: np.searchsorted(frames[c][order[c]], np.arange(len(poses) + 1))
              for c in ("wall", "column")}
    delta = np.zeros((len(poses), 3))
    good = np.zeros(len(poses), dtype=bool)
    cams = np.full((len(poses), 2), np.nan)
    for i in np.flatnonzero(accepted):
        m = per_frame[i]
        meta = win_meta[frame_window[i]]
        maps = win_maps[frame_window[i]]
        cam = m[:3, :3] @ poses[i, :3] + m[:3, 3]
        xy, cls_ = [], []
        for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
            idx = order[c][bounds[c][i]:bounds[c][i + 1]]
            q = world_pts[c][idx] @ m[:3, :3].T + m[:3, 3]
            keep = np.ones(len(q), dtype=bool)
            if meta["floor_z"] is not None and opt.wall_band_m > 0:
                keep &= q[:, 2] > meta["floor_z"] + opt.wall_band_m
                if meta["ceiling_z"] is not None:
                    keep &= q[:, 2] < meta["ceiling_z"] - opt.wall_band_m
            xy.append(q[keep, :2])
            cls_.append(np.full(int(keep.sum()), int(lab), np.int32))
        p_xy, p_cls = np.concatenate(xy), np.concatenate(cls_)
        cams[i] = cam[:2]
        if len(p_xy) < opt.min_points:
            continue
        sel = _subsample(p_xy, p_cls, None, opt.frame_max_points, rng)
        p_xy, p_cls = p_xy[sel], p_cls[sel]

        def associate(q: F64, q_class: I32, view: F64, maps: PlanMaps = maps
                      ) -> tuple[F64, F64]:
            return maps.nearest(q, maps.layer_of(q_class, view))

        fit = icp_2d(p_xy, p_cls, associate, Correction2D(0.0, np.zeros(2), cam[:2]),
                     p_xy - cam[:2], 2 * opt.icp_radius_end_m, opt.icp_radius_end_m,
                     max(opt.icp_iterations // 2, 3), opt.icp_huber_m, opt.inlier_m)
        corr = fit.correction
        if (fit.inlier_ratio >= opt.min_inlier_ratio and fit.constraint >= opt.min_constraint
                and np.linalg.norm(corr.t) <= opt.frame_max_step_m
                and abs(np.rad2deg(corr.yaw)) <= opt.frame_max_step_deg):
            delta[i] = (corr.yaw, corr.t[0], corr.t[1])
            good[i] = True
    # Drift is smooth and a single frame's fit is noisy: every frame takes the component-wise
    # median of the kept corrections within ±frame_smooth frames (about its own camera).
    kept = 0
    h = opt.frame_smooth
    for i in np.flatnonzero(accepted):
        lo, hi = max(i - h, 0), min(i + h + 1, len(poses))
        near = np.flatnonzero(good[lo:hi]) + lo
        if len(near) == 0 or np.isnan(cams[i]).any():
            continue
        d = np.median(delta[near], axis=0)
        per_frame[i] = _lift(Correction2D(float(d[0]), d[1:], cams[i])) @ per_frame[i]
        kept += 1
    return kept


@dataclass(frozen=True)
class _Oriented:
    """The poses (N, 7) the windows start from, after stage 0 (or the input), and its outcome:
    ``skip_windows`` (the input is already near the plan), ``unchanged`` (poses is the input),
    ``translated`` (the tracked translation beyond the deadband is in ``poses``)."""

    poses: F64
    frame_level: FrameLevelResult | None
    skip_windows: bool
    unchanged: bool
    translated: bool = False
    probe_drift_m: float | None = None
    #: with ``translated``: (N, 3) the tracked translation applied to each frame (metres) and
    #: (N, 7) the poses with stage 0's rotations alone
    applied_translation: F64 | None = None
    rotated_poses: F64 | None = None


def _checked_poses(world_from_cam: ArrayLike) -> F64:
    """The (N, 7) initial poses as float64; raises :class:`RegistrationInputError` if bad."""
    poses = np.asarray(world_from_cam, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 7 or len(poses) == 0 or not np.isfinite(poses).all():
        raise RegistrationInputError(f"must be finite (N>0, 7), got {poses.shape}", None,
                                     "world_from_cam")
    return poses


def _storey_maps(plan: FloorPlan, opt: CoarseOptions, map_cache: dict[Any, PlanMaps]
                 ) -> Callable[[float | None], PlanMaps]:
    """``floor_z -> PlanMaps`` of that storey's plan section, kept in ``map_cache``."""
    plan_key = (plan.segments.tobytes(), plan.segment_class.tobytes(), opt.view_bins,
                opt.coarse_resolution_m, opt.coarse_sigma_m, opt.fine_resolution_m,
                opt.fine_sigma_m, opt.score_truncate, max(opt.xy_range_m, opt.frame_xy_range_m))

    def maps_for(floor_z: float | None) -> PlanMaps:
        """The plan maps of the storey whose floor is at ``floor_z`` (cached)."""
        if plan.segment_z is not None and floor_z is not None:
            zc = floor_z + opt.plan_cut_height_m
            mask = (plan.segment_z[:, 0] <= zc) & (zc <= plan.segment_z[:, 1])
        else:
            mask = np.ones(len(plan.segments), dtype=bool)
        key = (plan_key, None if floor_z is None else round(floor_z, 3),
               np.packbits(mask).tobytes())
        if key not in map_cache:
            map_cache[key] = _build_maps(plan, mask, opt)
        return map_cache[key]

    return maps_for


def _orient_frames(poses: F64, samples: SemanticSamples, plan: FloorPlan,
                   maps_for: Callable[[float | None], PlanMaps], opt: CoarseOptions,
                   rng: np.random.Generator, timings: dict[str, float]) -> _Oriented:
    """Stage 0: per-frame orientation (tilt and yaw about each camera centre) and the part of
    the tracked translation beyond the deadband; a no-op unless ``frame_orientation``."""
    if not (opt.frame_orientation and opt.use_gravity):
        return _Oriented(poses=poses, frame_level=None, skip_windows=False, unchanged=True)
    t0 = time.perf_counter()
    probe = _near_probe(poses, samples, plan, maps_for, opt)
    if probe is not None and probe < opt.near_probe_m:
        timings["frame_orientation"] = time.perf_counter() - t0
        return _Oriented(poses=poses, frame_level=None, skip_windows=True, unchanged=True,
                         probe_drift_m=probe)
    frame_level = _level_frames(poses, samples, plan, maps_for, opt, rng)
    oriented = _apply_frame_level(poses, frame_level, opt, translate=opt.frame_translation)
    timings["frame_orientation"] = time.perf_counter() - t0
    return oriented


def _near_probe(poses: F64, samples: SemanticSamples, plan: FloorPlan,
                maps_for: Callable[[float | None], PlanMaps], opt: CoarseOptions
                ) -> float | None:
    """Stage 0's tracked drift (m) on ``near_probe_frames`` evenly spaced frames, with a
    generator of its own (the full pass's draws stay as they were); None when the probe is off
    or too few of its frames tracked a translation to tell."""
    k = opt.near_probe_frames
    if k == 0 or opt.frame_rotate_when_near or len(poses) < 2 * k:
        return None
    frames = np.unique(np.round(np.linspace(0, len(poses) - 1, k)).astype(np.int64))
    rng = np.random.default_rng([opt.seed, 1])
    probe_opt = replace(opt, yaw_step_deg=opt.near_probe_yaw_step_deg)
    probe = _level_frames(poses, samples, plan, maps_for, probe_opt, rng, frames=frames)
    if int(probe.t_ok.sum()) < opt.near_probe_min_tracked:
        return None
    return probe.drift_m


def _apply_frame_level(poses: F64, frame_level: FrameLevelResult, opt: CoarseOptions,
                       translate: bool) -> _Oriented:
    """Stage 0's corrections applied to the input ``poses`` (N, 7): the per-frame rotations and,
    with ``translate`` (and a tracked drift beyond ``frame_gate_m``), the part of the tracked
    translation beyond ``frame_deadband_m``."""
    m = frame_level.world_from_world.copy()
    near = frame_level.drift_m < opt.frame_gate_m
    translated = translate and not near
    if translated:
        # Soft threshold: the plan and the labels are good only to a few decimetres in
        # places (a frame that sees one door jamb locks onto it), and a consistent offset
        # over many frames is what the bundle adjustment cannot undo.
        t3 = frame_level.translation
        norm = np.linalg.norm(t3, axis=1)
        shrink = np.clip(1.0 - opt.frame_deadband_m / np.maximum(norm, 1e-12), 0.0, 1.0)
        m[:, :3, 3] += t3 * shrink[:, None]
    unchanged = near and not opt.frame_rotate_when_near
    applied, rotated = None, None
    if translated:
        applied = m[:, :3, 3] - frame_level.world_from_world[:, :3, 3]
        rotated = matrix_to_pose(frame_level.world_from_world @ pose_to_matrix(poses))
    if not unchanged:
        poses = matrix_to_pose(m @ pose_to_matrix(poses))
    return _Oriented(poses=poses, frame_level=frame_level, skip_windows=near,
                     unchanged=unchanged, translated=translated, applied_translation=applied,
                     rotated_poses=rotated)


@dataclass(frozen=True)
class _WindowPass:
    """Steps 1-6a from one set of start poses: the windows, their fits, their results, and the
    accepted windows' centre frames and (4, 4) corrections (interpolation nodes)."""

    wins: _Windows
    fits: list[_WindowFit]
    windows: list[WindowResult]
    nodes: list[Any]
    mats: list[F64]


def _window_pass(oriented: _Oriented, samples: SemanticSamples, plan: FloorPlan,
                 maps_for: Callable[[float | None], PlanMaps], grid: _YawGrid,
                 opt: CoarseOptions, rng: np.random.Generator, clock: _StageClock
                 ) -> _WindowPass:
    """Steps 1-6a from ``oriented.poses``: per window gravity, correlative search and ICP, the
    continuity chain over the windows, and each window's acceptance."""
    poses = oriented.poses
    wins = _split_windows(poses, samples, opt)
    fits = [_register_window(w, wins, poses, plan, maps_for, grid, oriented.skip_windows, opt,
                             rng, clock)
            for w in progress(range(len(wins.starts)), desc="coarse: windows", unit="window")]
    t0 = time.perf_counter()
    choice = _choose_hypotheses(fits, poses, wins, opt)
    clock.timings["continuity"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    windows, nodes, mats = _judge_windows(fits, choice, poses, wins, grid, oriented.skip_windows,
                                          opt)
    clock.timings["apply"] += time.perf_counter() - t0
    return _WindowPass(wins=wins, fits=fits, windows=windows, nodes=nodes, mats=mats)


def _choose_hypotheses(fits: list[_WindowFit], poses: F64, wins: _Windows, opt: CoarseOptions
                       ) -> dict[int, int]:
    """Step 5, continuity: window -> index of its chosen hypothesis (windows with any), by
    score alone or by the Viterbi chain over neighbouring windows' corrections."""
    cands = [f.candidates for f in fits]
    starts, stops = wins.starts, wins.stops
    active = [w for w in range(len(starts)) if cands[w]]
    choice = {w: int(np.argmax([c.score for c in cands[w]])) for w in active}
    if opt.use_continuity and opt.continuity_weight > 0 and len(active) > 1:
        unary = [-np.array([c.score for c in cands[w]]) / opt.score_sigma for w in active]
        pair = []
        for a, b in itertools.pairwise(active):
            boundary = 0.5 * (poses[stops[a] - 1, :2] + poses[starts[b], :2])
            gap = max((starts[b] - stops[a]) / opt.window_frames + 1.0, 1.0)
            cost = transition_cost([c.correction for c in cands[a]],
                                   [c.correction for c in cands[b]], boundary,
                                   opt.continuity_sigma_t_m * np.sqrt(gap),
                                   np.deg2rad(opt.continuity_sigma_yaw_deg) * np.sqrt(gap),
                                   opt.continuity_cap)
            pair.append(opt.continuity_weight * cost)
        labels, _ = viterbi_chain(unary, pair)
        choice = {w: int(lab) for w, lab in zip(active, labels, strict=True)}
    return choice


def _rejection_reason(cand: _Candidate, grid: _YawGrid, opt: CoarseOptions) -> str:
    """Why a window's chosen hypothesis is not accepted ("" when it is)."""
    corr = cand.correction
    edge_t = opt.xy_range_m - opt.coarse_resolution_m
    edge_yaw = grid.yaw_range - 0.5 * grid.step
    if cand.inlier_ratio < opt.min_inlier_ratio:
        return f"inlier ratio {cand.inlier_ratio:.2f} < {opt.min_inlier_ratio}"
    if cand.score < opt.min_score:
        return f"score {cand.score:.2f} < {opt.min_score}"
    if cand.constraint < opt.min_constraint:
        return f"degenerate (translation constraint {cand.constraint:.3f})"
    if opt.use_correlative and (np.abs(corr.t).max() > edge_t or
                                (opt.yaw_range_deg < 180 and abs(corr.yaw) > edge_yaw)):
        return "optimum at the edge of the search range"
    return ""


def _judge_windows(fits: list[_WindowFit], choice: dict[int, int], poses: F64, wins: _Windows,
                   grid: _YawGrid, skip_windows: bool, opt: CoarseOptions
                   ) -> tuple[list[WindowResult], list[Any], list[F64]]:
    """Step 6a: each window's result; the accepted ones' centre frames and (4, 4) corrections
    (planar correction after levelling) as interpolation nodes."""
    windows: list[WindowResult] = []
    nodes, mats = [], []
    for w, (f0, f1) in enumerate(zip(wins.starts, wins.stops, strict=True)):
        fit = fits[w]
        lv = fit.level
        tilt = float(np.rad2deg(Rotation.from_matrix(lv.rotation).magnitude()))
        common = {"start": int(f0), "stop": int(f1), "n_points": fit.meta["n_points"],
                  "dz_m": lv.dz, "tilt_deg": tilt, "seconds": fit.meta["seconds"]}
        if not fit.candidates:
            few = fit.meta["n_points"] < opt.min_points
            reason = ("input already near the plan" if skip_windows
                      else "too few points" if few else "no hypothesis")
            windows.append(WindowResult(
                **common, n_hypotheses=0, yaw_deg=0.0, t_m=(0.0, 0.0),
                pivot=tuple(poses[f0:f1, :2].mean(0)), score=0.0, inlier_ratio=0.0,
                constraint=0.0, best_score=0.0, accepted=False, reason=reason))
            continue
        cand = fit.candidates[choice[w]]
        corr = cand.correction
        reason = _rejection_reason(cand, grid, opt)
        accepted = reason == ""
        windows.append(WindowResult(
            **common, n_hypotheses=len(fit.candidates), yaw_deg=float(np.rad2deg(corr.yaw)),
            t_m=(float(corr.t[0]), float(corr.t[1])),
            pivot=(float(corr.pivot[0]), float(corr.pivot[1])), score=cand.score,
            inlier_ratio=cand.inlier_ratio, constraint=cand.constraint,
            best_score=max(c.score for c in fit.candidates), accepted=accepted, reason=reason))
        if accepted:
            nodes.append(0.5 * (f0 + f1 - 1))
            mats.append(_lift(corr) @ lv.matrix())
    return windows, nodes, mats


def _apply_windows(windows: list[WindowResult], nodes: list[Any], mats: list[F64], n: int,
                   opt: CoarseOptions) -> tuple[F64, NDArray[np.bool_]]:
    """Step 6b: (N, 4, 4) per-frame corrections (interpolated between accepted windows, or the
    window's own without ``interpolate``) and (N,) whether a frame's window was accepted."""
    per_frame = _interpolate(np.asarray(nodes), mats, n)
    accepted_frames = np.zeros(n, dtype=bool)
    for wr in windows:
        if wr.accepted:
            accepted_frames[wr.start:wr.stop] = True
            if not opt.interpolate:
                per_frame[wr.start:wr.stop] = mats[nodes.index(0.5 * (wr.start + wr.stop - 1))]
    return per_frame, accepted_frames


def _confirmed_translation(world: F64, accepted: NDArray[np.bool_], oriented: _Oriented,
                           wp: _WindowPass) -> F64:
    """Stage 0's tracked translation kept only where a window confirms it.

    ``world`` (N, 4, 4): the output poses, each frame's window correction applied to the poses
    the windows started from (with the tracked translation). A frame's tracked translation is
    its own fit, which may lock onto an alias (on Duplex_A 250 frames, Exp. 2, runs of 15-20
    frames were tracked 1.3-2.4 m off, to a look-alike room); only a window whose points, seen
    together, register there confirms it. The frames of a rejected window therefore drop it and
    take, on their stage-0 rotations alone, the interpolation of the accepted windows' whole
    corrections (window correction after the window's mean tracked translation); the frames of
    accepted windows are kept. Without a translation from stage 0 or an accepted window,
    ``world`` is returned as it is."""
    if (not oriented.translated or oriented.applied_translation is None
            or oriented.rotated_poses is None or not wp.nodes or accepted.all()):
        return world
    moved = np.tile(np.eye(4), (len(wp.mats), 1, 1))
    for k, node in enumerate(wp.nodes):
        wr = next(w for w in wp.windows if w.accepted and 0.5 * (w.start + w.stop - 1) == node)
        moved[k, :3, 3] = oriented.applied_translation[wr.start:wr.stop].mean(0)
    whole = _interpolate(np.asarray(wp.nodes), [m @ t for m, t in zip(wp.mats, moved,
                                                                        strict=True)],
                         len(world))
    out = world.copy()
    rejected = ~accepted
    out[rejected] = whole[rejected] @ pose_to_matrix(oriented.rotated_poses[rejected])
    return out


def _frame_fit(out_poses: F64, samples: SemanticSamples, wins: _Windows,
               win_maps: list[PlanMaps], opt: CoarseOptions) -> tuple[F64, F64]:
    """Per-frame fit at the output poses (N, 7): ``(fine score (N,), inlier ratio (N,))`` of
    each frame's wall/column points (column points weighted by ``column_weight``)."""
    n = len(out_poses)
    frames = wins.frames
    frame_score = np.zeros(n)
    frame_inl = np.zeros(n)
    for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
        fr = frames[c]
        if not len(fr):
            continue
        q = transform_points(out_poses[fr], getattr(samples, f"{c}_p_in_cam"))[:, :2]
        view = q - out_poses[fr, :2]
        cls_ = np.full(len(fr), int(lab), np.int32)
        wt = 1.0 if lab == Label.WALL else opt.column_weight
        for w in range(len(wins.starts)):
            m = wins.indices(c, w)
            if len(m) == 0:
                continue
            sc, dist = win_maps[w].fine_eval(q[m], win_maps[w].layer_of(cls_[m], view[m]))
            np.add.at(frame_score, fr[m], wt * sc)
            np.add.at(frame_inl, fr[m], wt * (dist < opt.inlier_m))
    count = np.zeros(n)
    for c, lab in (("wall", Label.WALL), ("column", Label.COLUMN)):
        np.add.at(count, frames[c], 1.0 if lab == Label.WALL else opt.column_weight)
    frame_score = np.where(count > 0, frame_score / np.maximum(count, 1e-12), 0.0)
    frame_inl = np.where(count > 0, frame_inl / np.maximum(count, 1e-12), 0.0)
    return frame_score, frame_inl


# ------------------------------------------------------------------------------------------------
# The stage.


def coarse_register(
    world_from_cam: ArrayLike,
    samples: SemanticSamples,
    plan: FloorPlan,
    options: CoarseOptions | None = None,
    maps_cache: dict[Any, PlanMaps] | None = None,
) -> CoarseResult:
    """Coarse registration of a trajectory to the floor plan (see the module docstring).

    Parameters
    ----------
    world_from_cam: (N, 7) initial poses, TUM order ``[tx ty tz qx qy qz qw]``.
    samples: the labelled points of every frame, camera frame.
    plan: segments and floor/ceiling heights of the BIM.
    options: settings; default :class:`CoarseOptions`.
    maps_cache: optional dict in which the plan's raster maps are kept, to reuse them in later
        calls with the same ``plan`` and the same map settings (benchmarks, several sequences
        in one building); keyed by the plan's and the options' relevant values.

    Returns
    -------
    CoarseResult
    """
    opt = CoarseOptions() if options is None else options
    clock = _StageClock.start()
    input_poses = _checked_poses(world_from_cam)
    n = len(input_poses)
    samples.check_frames(n)
    rng = np.random.default_rng(opt.seed)
    timings = clock.timings
    maps_for = _storey_maps(plan, opt, {} if maps_cache is None else maps_cache)
    # 0. per-frame orientation (tilt and yaw about each camera centre).
    oriented = _orient_frames(input_poses, samples, plan, maps_for, opt, rng, timings)
    grid = _yaw_grid(opt)
    # 1.-6a. per window: gravity and height, planar points, correlative search, ICP; continuity
    # (one hypothesis per window); acceptance.
    wp = _window_pass(oriented, samples, plan, maps_for, grid, opt, rng, clock)
    reverted = False
    searched = any(w.n_hypotheses > 0 for w in wp.windows)
    if oriented.translated and searched and not wp.nodes and oriented.frame_level is not None:
        # The tracked translation is a proposal from single frames, each of which may have
        # locked onto an alias (a mirrored flat, a repeated room): it stands only where the
        # window search confirms it (some window's points, seen together, register there).
        # Refuted (windows were searched and none was accepted), it is dropped: the windows
        # start again from the input positions with the per-frame rotations alone.
        oriented = _apply_frame_level(input_poses, oriented.frame_level, opt, translate=False)
        wp = _window_pass(oriented, samples, plan, maps_for, grid, opt, rng, clock)
        reverted = True
    poses, wins, fits = oriented.poses, wp.wins, wp.fits
    win_maps, win_meta = [f.maps for f in fits], [f.meta for f in fits]
    # 6b. interpolate and apply.
    t0 = time.perf_counter()
    per_frame, accepted_frames = _apply_windows(wp.windows, wp.nodes, wp.mats, n, opt)
    timings["apply"] += time.perf_counter() - t0
    # 7. per-frame ICP inside the accepted windows.
    t0 = time.perf_counter()
    n_refined = 0
    if opt.refine_frames and opt.use_icp and accepted_frames.any():
        n_refined = _refine_frames(per_frame, poses, wins.world_pts, wins.frames,
                                   wins.frame_window, win_maps, win_meta, accepted_frames, opt,
                                   rng)
    timings["refine_frames"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if oriented.unchanged and not accepted_frames.any():
        out_poses = input_poses.copy()  # bit for bit: no pose round trip
    else:
        world = per_frame @ pose_to_matrix(poses)
        if opt.frame_translation_per_window:
            world = _confirmed_translation(world, accepted_frames, oriented, wp)
        out_poses = matrix_to_pose(world)
    frame_score, frame_inl = _frame_fit(out_poses, samples, wins, win_maps, opt)
    timings["apply"] += time.perf_counter() - t0
    return CoarseResult(poses=out_poses, frame_score=frame_score,
                        frame_inlier_ratio=frame_inl, accepted=accepted_frames,
                        frame_window=wins.frame_window, windows=wp.windows,
                        timings=clock.finish(win_meta, n_refined), options=opt,
                        frame_level=oriented.frame_level, translation_dropped=reverted,
                        near_probe_drift_m=oriented.probe_drift_m)
