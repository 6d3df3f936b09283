"""Windows of frames that the bundle adjustment left off the plan by a rigid shift.

A stretch of the walk that the coarse stage did not place (its windows rejected, its frames
given the interpolation of their neighbours' corrections) can start the bundle adjustment
decimetres off. Where the plan repeats at a short period across the walk (the two faces of a
wall, parallel walls a wall's thickness apart) the robust BIM terms then hold the stretch in a
local minimum one period away, and the G term's robust loss gives up the matches that link it
to its placed neighbours (on Duplex_A 250 frames, Exp. 2: frames 89-117 13-15 cm and
118-154 46-49 cm off in y, their x, z and yaw right, with 200-300 matches across either end).
The strain is spread over a few frames, so the motion check (a break of 0.5 m) does not see it.

:func:`window_shifts` looks at the solved trajectory window by window (``window_frames``
consecutive frames): the planar translation of the window's wall and column samples that fits
the plan best (the truncated-Gaussian score of the coarse stage's maps, by class and face seen,
:class:`bimcap.registration.plan_maps.PlanMaps`), searched over ``±xy_range_m``. A window that
the solve placed scores best at no shift; a window held one period off scores clearly higher
at the shift that takes it back. The windows whose best shift is at least ``min_shift_m`` and
whose score rises by ``min_gain`` (relative) are moved by it (their frames' positions, rotations
kept); the caller solves again from there and keeps the solve only when the BIM agrees
(``bimcap.pipeline.refine``).

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order ``world_from_cam``; the problem's
arrays as ``bimcap.optimize.Problem.arrays()``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import transform_points
from bimcap.labels import Label
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class WindowShiftOptions:
    """Settings of :func:`window_shifts`.

    Attributes
    ----------
    window_frames: consecutive frames judged together.
    xy_range_m: the search range of the shift in x and in y (metres, ±).
    step_m, fine_step_m: the search grid, then a finer grid ±``step_m`` around its best.
    sigma_m: width of the truncated-Gaussian score (metres; 0 beyond 3 σ).
    resolution_m: pixel of the plan's distance fields (metres).
    view_bins: ray-direction bins of the visibility test (a ray scores only on faces it can
        hit from their free side, :mod:`bimcap.registration.plan_maps`).
    plan_cut_height_m: a window's plan section holds the segments whose ``segment_z`` range
        holds the window's median camera height minus ``camera_height_m`` plus this.
    camera_height_m: assumed height of the camera over its floor (metres).
    min_shift_m: a shift shorter than this is no shift (metres).
    min_gain: the relative rise of the window's score that the shift must bring.
    min_points: a window with fewer wall and column samples is not judged.
    max_points: samples drawn per window (at random, ``seed``).
    """

    window_frames: int = 10
    xy_range_m: float = 0.6
    step_m: float = 0.05
    fine_step_m: float = 0.01
    sigma_m: float = 0.03
    resolution_m: float = 0.02
    view_bins: int = 4
    plan_cut_height_m: float = 1.0
    camera_height_m: float = 1.5
    min_shift_m: float = 0.05
    min_gain: float = 0.05
    min_points: int = 200
    max_points: int = 2000
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("window_frames", "xy_range_m", "step_m", "fine_step_m", "sigma_m",
                     "resolution_m", "view_bins", "max_points"):
            if not getattr(self, name) > 0:
                raise ValueError(f"WindowShiftOptions.{name} must be > 0, got "
                                 f"{getattr(self, name)!r}")


@dataclass(frozen=True)
class WindowShift:
    """One window's verdict.

    Attributes
    ----------
    start, stop: its frames ``[start, stop)``.
    n_points: samples scored.
    score, best_score: mean score of its samples where they are and at the best shift.
    shift_m: the best shift ``(dx, dy)`` (metres, world frame).
    moved: whether the window is moved by it.
    """

    start: int
    stop: int
    n_points: int
    score: float
    best_score: float
    shift_m: tuple[float, float]
    moved: bool

    def to_dict(self) -> dict[str, Any]:
        return {"start": self.start, "stop": self.stop, "n_points": self.n_points,
                "score": self.score, "best_score": self.best_score,
                "shift_m": list(self.shift_m), "moved": self.moved}


@dataclass
class WindowShiftResult:
    """What :func:`window_shifts` found.

    Attributes
    ----------
    windows: every judged window (:class:`WindowShift`).
    poses: (N, 7) the input poses with the moved windows' positions shifted.
    moved: the frames moved, ascending.
    """

    windows: list[WindowShift] = field(default_factory=list)
    poses: F64 = field(default_factory=lambda: np.zeros((0, 7)))
    moved: list[int] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"moved": list(self.moved),
                "windows": [w.to_dict() for w in self.windows if w.moved]}


def _samples(arrays: dict[str, Any]) -> tuple[NDArray[np.int64], F64, NDArray[np.int32]]:
    """Every wall and column sample of ``arrays``: (frame (M,), p_in_cam (M, 3), class (M,))."""
    frames, points, classes = [], [], []
    for term, label in (("wall", Label.WALL), ("column", Label.COLUMN)):
        fr = arrays.get(f"{term}_frame")
        if fr is None or not len(fr):
            continue
        frames.append(np.asarray(fr, np.int64))
        points.append(np.asarray(arrays[f"{term}_p_in_cam"], np.float64).reshape(-1, 3))
        classes.append(np.full(len(fr), int(label), np.int32))
    if not frames:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int32)
    return np.concatenate(frames), np.concatenate(points), np.concatenate(classes)


def _grid(half: float, step: float) -> F64:
    """(K, 2) the shifts of a square grid ``±half`` at ``step`` (0 included)."""
    g = step * np.arange(-np.floor(half / step + 1e-9), np.floor(half / step + 1e-9) + 1)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _best_shift(maps: PlanMaps, q_xy: F64, layer: NDArray[np.int64], opt: WindowShiftOptions
                ) -> tuple[F64, float]:
    """The shift (2,) of ``q_xy`` (M, 2) with the highest mean score, and that score; ties go
    to the shortest shift."""
    best, best_score = np.zeros(2), -np.inf
    for shifts in (_grid(opt.xy_range_m, opt.step_m), None):
        if shifts is None:
            shifts = best + _grid(opt.step_m, opt.fine_step_m)
            shifts = shifts[np.abs(shifts).max(1) <= opt.xy_range_m + 1e-9]
        scores = np.array([maps.fine_score_at(q_xy + s, layer).mean() for s in shifts])
        top = scores.max()
        cand = np.flatnonzero(scores >= top - 1e-12)
        k = cand[np.argmin(np.linalg.norm(shifts[cand], axis=1))]
        if scores[k] > best_score:
            best, best_score = shifts[k].copy(), float(scores[k])
    return best, best_score


def window_shifts(arrays: dict[str, Any], poses: F64,
                  options: WindowShiftOptions | None = None) -> WindowShiftResult:
    """The windows of ``poses`` that a rigid planar shift puts clearly better on the plan.

    Parameters
    ----------
    arrays: a problem's arrays: ``segments`` (S, 4), ``segment_class`` (S,), optional
        ``segment_z`` (S, 2), and the wall / column samples (``*_frame``, ``*_p_in_cam``).
    poses: (N, 7) ``world_from_cam``, TUM order (the solved trajectory).
    options: :class:`WindowShiftOptions`.

    Returns
    -------
    :class:`WindowShiftResult` (``poses`` a copy, shifted where a window is moved).
    """
    opt = WindowShiftOptions() if options is None else options
    poses = np.asarray(poses, np.float64)
    out = WindowShiftResult(poses=poses.copy())
    seg = np.asarray(arrays.get("segments", np.zeros((0, 4))), np.float64).reshape(-1, 4)
    seg_class = np.asarray(arrays.get("segment_class", np.zeros(0)), np.int32)
    seg_z = arrays.get("segment_z")
    frame, p_in_cam, p_class = _samples(arrays)
    if not len(seg) or not len(frame):
        return out
    xy = seg.reshape(-1, 2)
    bounds = (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
              float(xy[:, 1].max()))
    cache: dict[bytes, PlanMaps] = {}
    rng = np.random.default_rng(opt.seed)
    n = len(poses)
    for f0 in range(0, n, opt.window_frames):
        f1 = min(f0 + opt.window_frames, n)
        idx = np.flatnonzero((frame >= f0) & (frame < f1))
        if len(idx) < opt.min_points:
            continue
        if len(idx) > opt.max_points:
            idx = np.sort(rng.choice(idx, opt.max_points, replace=False))
        mask = np.ones(len(seg), dtype=bool)
        if seg_z is not None and len(seg_z):
            cut = float(np.median(poses[f0:f1, 2])) - opt.camera_height_m + opt.plan_cut_height_m
            z = np.asarray(seg_z, np.float64).reshape(-1, 2)
            mask = (z[:, 0] <= cut) & (cut <= z[:, 1])
        if not mask.any():
            continue
        key = np.packbits(mask).tobytes()
        if key not in cache:
            cache[key] = PlanMaps.build(seg[mask], seg_class[mask], bounds,
                                        opt.xy_range_m + 1.0, opt.view_bins,
                                        10 * opt.resolution_m, 5 * opt.sigma_m,
                                        opt.resolution_m, opt.sigma_m, 3.0)
        maps = cache[key]
        q = transform_points(poses[frame[idx]], p_in_cam[idx])[:, :2]
        layer = maps.layer_of(p_class[idx], q - poses[frame[idx], :2])
        score = float(maps.fine_score_at(q, layer).mean())
        shift, best = _best_shift(maps, q, layer, opt)
        moved = bool(np.linalg.norm(shift) >= opt.min_shift_m
                     and best >= (1.0 + opt.min_gain) * score)
        out.windows.append(WindowShift(start=f0, stop=f1, n_points=len(idx), score=score,
                                       best_score=best, shift_m=(float(shift[0]),
                                                                 float(shift[1])),
                                       moved=moved))
        if moved:
            out.poses[f0:f1, :2] += shift
            out.moved.extend(range(f0, f1))
    return out
