"""The coarse stage's previous implementations of the steps made faster (issue 14), kept as
oracles.

Each ``*_4206b3e`` function is the code as it was at commit 4206b3e, verbatim; the tests check
that the new code gives the same arrays bit for bit, and ``bench/bench_near_probe.py`` times a
hand-back with both in one process (:func:`old_coarse`: a context in which the coarse stage runs
the old code, swapped into its modules).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.correlative import Hypothesis, _crop, top_hypotheses
from bimcap.registration.frame_level import Candidate, FrameLevelOptions
from bimcap.registration.icp import Correction2D, icp_2d, rot2
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
I32 = NDArray[np.int32]


def score_volume_4206b3e(
    p_xy: NDArray[np.float64],
    p_class: NDArray[np.int32],
    view_xy: NDArray[np.float64],
    maps: PlanMaps,
    pivot: NDArray[np.float64],
    yaws: NDArray[np.float64],
    xy_range_m: float,
    column_weight: float = 1.0,
    p_weight: NDArray[np.float64] | None = None,
    y_range_m: float | None = None,
) -> tuple[F32, float, int]:
    """Score of every (yaw, ty, tx) on the coarse grid of ``maps``.

    Parameters
    ----------
    p_xy: (M, 2) world points before the correction; p_class: (M,) 1 wall / 4 column.
    view_xy: (M, 2) ray directions camera → point (any length), before the correction.
    maps: the plan's layered maps; points are rasterised per layer (class × ray direction
        after the yaw) into binary occupancy templates.
    pivot: (2,) the rotation centre; yaws: (Y,) radians; xy_range_m: half-width of the
        translation grid (along x, and along y too unless ``y_range_m`` is given).
    p_weight: (M,) each point's weight in (0, 1] (None: 1); a template cell takes the largest
        weight of its points (with weights of 1, the binary template).
    y_range_m: half-height of the translation grid along y (None: ``xy_range_m``, a square
        grid); a grid as long as the plan's box in each direction, not the square of its
        longer side (Office_A's 50 x 36 m box: 263 x 195 translations instead of 263 x 263).

    Returns
    -------
    ``(volume (Y, 2m+1, 2n+1), res, n)``: ``volume[k, j, i]`` is the weighted mean score per
    occupied cell of ``yaw = yaws[k]``, ``t = ((i - n) res, (j - m) res)``, with ``m =
    round(y_range_m / res)`` (``n`` when ``y_range_m`` is None; ``(volume.shape[1] - 1) // 2``).
    """
    import cv2

    res = maps.coarse[0].resolution_m
    origin = maps.coarse[0].origin_xy
    n = round(xy_range_m / res)
    m = n if y_range_m is None else round(y_range_m / res)
    vol = np.zeros((len(yaws), 2 * m + 1, 2 * n + 1), dtype=np.float32)
    if len(p_xy) == 0:
        return vol, res, n
    rel = p_xy - pivot  # the same arithmetic as ``(p_xy - pivot) @ r.T + pivot`` per yaw
    total = np.empty((2 * m + 1, 2 * n + 1), dtype=np.float32)
    for k, yaw in enumerate(yaws):
        r = rot2(float(yaw))
        q = rel @ r.T + pivot
        layer = maps.layer_of(p_class, view_xy @ r.T)
        uv = np.round((q - origin) / res).astype(np.int64)
        total.fill(0.0)
        count = 0.0
        for lay in np.flatnonzero(np.bincount(layer)):  # the layers present, ascending
            weight = column_weight if lay >= maps.n_bins else 1.0
            if weight == 0:
                continue
            luv = uv[layer == lay]
            u0, v0 = luv.min(0)
            u1, v1 = luv.max(0)
            templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
            if p_weight is None:
                templ[luv[:, 1] - v0, luv[:, 0] - u0] = 1.0
            else:
                np.maximum.at(templ, (luv[:, 1] - v0, luv[:, 0] - u0),
                              p_weight[layer == lay].astype(np.float32))
            count += weight * float(templ.sum())
            if len(maps.rows[lay]) == 0:
                continue  # nothing of this class is visible this way: the points score 0
            img = _crop(maps.coarse_score[lay], v0 - m, v1 + m + 1, u0 - n, u1 + n + 1)
            corr = cv2.matchTemplate(img, templ, cv2.TM_CCORR)
            total += corr if weight == 1.0 else weight * corr
        if count > 0:
            vol[k] = total / count
    return vol, res, n


def frame_candidates_4206b3e(points: tuple[F64, I32], cam: F64, floor_z: float | None,
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
    vol, res, nn = score_volume_4206b3e(p_xy, p_cls, view, maps, pivot, yaws, opt.xy_range_m)
    hyps = top_hypotheses(vol, yaws, res, nn, opt.top_k, 0.3, np.deg2rad(3.0))
    # The input pose is always a hypothesis: the track may then keep it, at its own score,
    # instead of choosing between aliases when the input is already right.
    if not any(np.linalg.norm(h.t) < 0.3 and abs(h.yaw) < np.deg2rad(3.0) for h in hyps):
        hyps.append(Hypothesis(0.0, np.zeros(2), 0.0))

    def associate(q: F64, q_class: I32, v: F64, maps: PlanMaps = maps) -> tuple[F64, F64]:
        return maps.nearest(q, maps.layer_of(q_class, v))

    out = []
    for h in hyps:
        fit = icp_2d(p_xy, p_cls, associate, Correction2D(h.yaw, h.t, pivot), view, **icp)
        corr = fit.correction
        sc, _ = maps.fine_eval(corr.apply(p_xy), maps.layer_of(p_cls, view @ rot2(corr.yaw).T))
        score = float(sc.mean())
        if (fit.inlier_ratio >= opt.min_inlier_ratio
                and abs(corr.yaw) <= np.deg2rad(opt.yaw_range_deg)):
            informative = fit.constraint >= opt.min_constraint and score >= opt.min_score
            out.append(Candidate(corr, score, float(fit.constraint), bool(informative)))
    return out


@contextmanager
def swapped(module: Any, **functions: Callable[..., Any]) -> Iterator[None]:
    """Replace ``module``'s attributes by ``functions`` for the duration of the block."""
    saved = {name: getattr(module, name) for name in functions}
    try:
        for name, fn in functions.items():
            setattr(module, name, fn)
        yield
    finally:
        for name, fn in saved.items():
            setattr(module, name, fn)


@contextmanager
def old_coarse() -> Iterator[None]:
    """The coarse stage as of 4206b3e: its correlative search (:func:`score_volume_4206b3e`) in
    stage 0 and in the windows, stage 0's hypotheses refined one ICP at a time
    (:func:`frame_candidates_4206b3e`)."""
    from bimcap.registration import _coarse_steps, frame_level

    with swapped(frame_level, _frame_candidates=frame_candidates_4206b3e), \
            swapped(_coarse_steps, score_volume=score_volume_4206b3e):
        yield
