"""Correlative scan matching of planar points against a floor-plan score map.

For every yaw on a grid the window's points (projected to the floor plane) are rotated about the
pivot and rasterised into a binary occupancy template at the score map's resolution; one
``cv2.matchTemplate`` (cross-correlation, FFT-based for large templates) then gives the summed
score of *every* translation on the grid at once. Occupancy (not counts) equalises the weight
of dense near-range surfaces and far ones. Walls and columns are correlated against their own
class's map (same-class association) and the two are added with a weight.

The result is a score volume over (yaw, ty, tx); its local maxima, after non-maximum
suppression, are the hypotheses handed to ICP and to the trajectory-continuity chain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.distance_field import DistanceField
from bimcap.registration.icp import rot2

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


@dataclass(frozen=True)
class ScoreLayer:
    """Points of one class and the score map they are correlated against.

    Attributes
    ----------
    p_xy: (M, 2) world points (metres) before the correction.
    field: the grid (origin, resolution) of ``score``.
    score: (H, W) float32 score map on that grid, values in [0, 1].
    weight: multiplier of this layer's summed score.
    """

    p_xy: F64
    field: DistanceField
    score: F32
    weight: float = 1.0


@dataclass(frozen=True)
class Hypothesis:
    """One candidate planar correction ``q = R(yaw)(p - pivot) + pivot + t``.

    ``score`` is the weighted mean score per occupied cell, in [0, 1].
    """

    yaw: float
    t: F64
    score: float


def _crop(img: F32, r0: int, r1: int, c0: int, c1: int) -> F32:
    """``img[r0:r1, c0:c1]`` with zeros outside the image."""
    h, w = img.shape
    out = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
    rr0, rr1, cc0, cc1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
    if rr0 < rr1 and cc0 < cc1:
        out[rr0 - r0:rr1 - r0, cc0 - c0:cc1 - c0] = img[rr0:rr1, cc0:cc1]
    return out


def score_volume(
    layers: list[ScoreLayer],
    pivot: NDArray[np.float64],
    yaws: NDArray[np.float64],
    xy_range_m: float,
) -> tuple[F32, float, int]:
    """Score of every (yaw, ty, tx) on the grid.

    All layers must share resolution and origin. Returns ``(volume (Y, 2n+1, 2n+1), res, n)``
    where ``volume[k, j, i]`` is the score of ``yaw = yaws[k]``, ``t = ((i - n) res, (j - n) res)``.
    """
    import cv2

    res = layers[0].field.resolution_m
    origin = layers[0].field.origin_xy
    n = int(round(xy_range_m / res))
    vol = np.zeros((len(yaws), 2 * n + 1, 2 * n + 1), dtype=np.float32)
    for k, yaw in enumerate(yaws):
        r = rot2(float(yaw))
        total = np.zeros((2 * n + 1, 2 * n + 1), dtype=np.float32)
        count = 0.0
        for layer in layers:
            if len(layer.p_xy) == 0 or layer.weight == 0:
                continue
            q = (layer.p_xy - pivot) @ r.T + pivot
            uv = np.round((q - origin) / res).astype(np.int64)
            u0, v0 = uv.min(0)
            u1, v1 = uv.max(0)
            templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
            templ[uv[:, 1] - v0, uv[:, 0] - u0] = 1.0
            img = _crop(layer.score, v0 - n, v1 + n + 1, u0 - n, u1 + n + 1)
            total += layer.weight * cv2.matchTemplate(img, templ, cv2.TM_CCORR)
            count += layer.weight * float(templ.sum())
        if count > 0:
            vol[k] = total / count
    return vol, res, n


def top_hypotheses(
    volume: F32,
    yaws: NDArray[np.float64],
    res: float,
    n: int,
    top_k: int,
    nms_xy_m: float,
    nms_yaw_rad: float,
    min_score: float = 1e-6,
) -> list[Hypothesis]:
    """Up to ``top_k`` local maxima of ``volume`` after greedy non-maximum suppression.

    Two hypotheses are the same if both ``|Δt| < nms_xy_m`` and ``|Δyaw| < nms_yaw_rad``.
    """
    from scipy.ndimage import maximum_filter

    peak = (volume >= maximum_filter(volume, size=(3, 3, 3), mode="nearest")) & (volume > min_score)
    k, j, i = np.nonzero(peak)
    s = volume[k, j, i]
    order = np.argsort(-s, kind="stable")
    chosen: list[Hypothesis] = []
    for o in order:
        yaw = float(yaws[k[o]])
        t = np.array([(i[o] - n) * res, (j[o] - n) * res])
        dup = False
        for h in chosen:
            dyaw = abs(np.arctan2(np.sin(yaw - h.yaw), np.cos(yaw - h.yaw)))
            if dyaw < nms_yaw_rad and np.linalg.norm(t - h.t) < nms_xy_m:
                dup = True
                break
        if not dup:
            chosen.append(Hypothesis(yaw, t, float(s[o])))
            if len(chosen) >= top_k:
                break
    return chosen
