"""Correlative scan matching of planar points against a floor-plan score map.

For every yaw on a grid the window's points (projected to the floor plane) are rotated about the
pivot and rasterised into a binary occupancy template at the score map's resolution; one
``cv2.matchTemplate`` (cross-correlation, FFT-based for large templates) then gives the summed
score of *every* translation on the grid at once. Occupancy (not counts) equalises the weight
of dense near-range surfaces and far ones. Points are correlated against the map of their own
class and ray direction (:class:`bimcap.registration.plan_maps.PlanMaps`: same-class association,
no matching onto faces that cannot be seen), and the layers are added with a per-class weight.

The result is a score volume over (yaw, ty, tx); its local maxima, after non-maximum
suppression, are the hypotheses handed to ICP and to the trajectory-continuity chain.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.icp import rot2
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
_T = TypeVar("_T")
_R = TypeVar("_R")


def map_threads(fn: Callable[[_T], _R], items: Iterable[_T], num_threads: int) -> list[_R]:
    """``[fn(x) for x in items]``, in that order, on a pool of ``num_threads`` threads (1 or
    fewer: in this thread, one after the other). For work that releases the GIL (OpenCV,
    NumPy's large array operations) and whose items are independent."""
    items = list(items)
    if num_threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(num_threads, len(items))) as pool:
        return list(pool.map(fn, items))


@dataclass(frozen=True)
class Hypothesis:
    """One candidate planar correction ``q = R(yaw)(p - pivot) + pivot + t``.

    ``score`` is the weighted mean score per occupied cell, in [0, 1].
    """

    yaw: float
    t: F64
    score: float


def _crop(img: F32, r0: int, r1: int, c0: int, c1: int) -> F32:
    """``img[r0:r1, c0:c1]`` with zeros outside the image (a view when it lies inside)."""
    h, w = img.shape
    if r0 >= 0 and c0 >= 0 and r1 <= h and c1 <= w:
        return img[r0:r1, c0:c1]
    out = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
    rr0, rr1, cc0, cc1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
    if rr0 < rr1 and cc0 < cc1:
        out[rr0 - r0:rr1 - r0, cc0 - c0:cc1 - c0] = img[rr0:rr1, cc0:cc1]
    return out


def score_volume(
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
    num_threads: int = 1,
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
    num_threads: threads that share the yaws (1: this thread only); the same volume, bit for
        bit, with any number.

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
    n_layers = maps.n_layers
    weights = [column_weight if lay >= maps.n_bins else 1.0 for lay in range(n_layers)]

    def yaws_from(k0: int, k1: int) -> None:
        """``vol[k0:k1]``: each point's layer and cell per yaw in one pass, then the points
        grouped by (yaw, layer) with one sort, the groups' cell ranges with one reduction (the
        per-yaw, per-layer masks and minima cost more than the correlation on a 1500-point
        frame). Every value is that of the loop over yaws and layers: the same products per
        yaw, the same templates, added in ascending layer order (whatever ``k0, k1``)."""
        ks = np.arange(k0, k1)
        total = np.empty((2 * m + 1, 2 * n + 1), dtype=np.float32)
        q = np.empty((len(ks), len(p_xy), 2))
        view = np.empty((len(ks), len(p_xy), 2))
        for j, k in enumerate(ks):
            r = rot2(float(yaws[k]))
            q[j] = rel @ r.T + pivot
            view[j] = view_xy @ r.T
        layer = maps.layer_of(np.tile(p_class, len(ks)), view.reshape(-1, 2))
        key = layer + n_layers * np.repeat(np.arange(len(ks)), len(p_xy))
        uv = np.round((q.reshape(-1, 2) - origin) / res).astype(np.int64)
        order = np.argsort(key, kind="stable")
        key, uv = key[order], uv[order]
        first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        lo = np.minimum.reduceat(uv, first, axis=0).tolist()
        hi = np.maximum.reduceat(uv, first, axis=0).tolist()
        bounds = np.r_[first, len(key)].tolist()
        group_key = key[first].tolist()
        g = 0
        for j, k in enumerate(ks):
            total.fill(0.0)
            count = 0.0
            while g < len(group_key) and group_key[g] // n_layers == j:
                lay = group_key[g] % n_layers  # the layers present, ascending
                a, b = bounds[g], bounds[g + 1]
                (u0, v0), (u1, v1) = lo[g], hi[g]
                g += 1
                weight = weights[lay]
                if weight == 0:
                    continue
                luv = uv[a:b]
                templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
                if p_weight is None:
                    templ[luv[:, 1] - v0, luv[:, 0] - u0] = 1.0
                else:
                    np.maximum.at(templ, (luv[:, 1] - v0, luv[:, 0] - u0),
                                  p_weight[order[a:b] % len(p_xy)].astype(np.float32))
                count += weight * float(templ.sum())
                if len(maps.rows[lay]) == 0:
                    continue  # nothing of this class is visible this way: the points score 0
                img = _crop(maps.coarse_score[lay], v0 - m, v1 + m + 1, u0 - n, u1 + n + 1)
                corr = cv2.matchTemplate(img, templ, cv2.TM_CCORR)
                total += corr if weight == 1.0 else weight * corr
            if count > 0:
                vol[k] = total / count

    # The yaws a block at a time (about 2^19 points in all); with ``num_threads`` > 1, blocks of
    # at most a quarter of each thread's share, on a pool of threads (``cv2.matchTemplate``,
    # most of the time, runs without the GIL): each yaw's slice of the volume is computed by
    # one call, the same bits whichever thread computes it and however the yaws are blocked.
    block = max(1, (1 << 19) // len(p_xy))
    if num_threads > 1:
        block = min(block, max(1, -(-len(yaws) // (4 * num_threads))))
    starts = range(0, len(yaws), block)
    map_threads(lambda k0: yaws_from(k0, min(k0 + block, len(yaws))), starts, num_threads)
    return vol, res, n


def top_hypotheses(
    volume: F32,
    yaws: NDArray[np.float64],
    res: float,
    n: int,
    top_k: int,
    nms_xy_m: float,
    nms_yaw_rad: float,
    diverse_yaw_rad: float = np.deg2rad(10.0),
    min_score: float = 1e-6,
    first_cells: int = 1 << 14,
) -> list[Hypothesis]:
    """Up to ``top_k`` local maxima of ``volume`` after greedy non-maximum suppression.

    Two hypotheses are the same if both ``|Δt| < nms_xy_m`` and ``|Δyaw| < nms_yaw_rad``.
    Half of the places go first to the best peak of each distinct yaw mode (peaks at least
    ``diverse_yaw_rad`` apart), so that a scene that is ambiguous along one axis (a corridor)
    cannot fill the list with translated copies of one yaw and crowd out the yaw that a
    neighbouring window needs (a symmetric room's unflipped pose).

    The local maxima are looked for among the ``first_cells`` best cells first, eight times
    more whenever the selection runs out of them: the same peaks as a maximum filter of the
    whole volume, in the same order.

    ``volume`` (Y, 2m+1, 2n+1) as :func:`score_volume` returns it: ``n`` is the half-width of
    its x axis; that of its y axis is read from its shape (``m = n`` for a square grid).
    """
    # The selection reads the peaks best first and stops when its list is full: find the peaks
    # among the ``m`` best cells only, and take more cells when the selection runs out of them
    # (the peaks >= the m-th best value are exactly the head of the full sorted list; a
    # maximum filter of the whole volume cost 0.4 s per search on a 50 x 36 m plan).
    flat = volume.ravel()
    m_y = (volume.shape[1] - 1) // 2
    m = min(flat.size, max(int(first_cells), 1))
    while True:
        tau = _mth_largest(flat, m) if m < flat.size else -np.inf
        complete = tau <= min_score
        idx = np.flatnonzero((flat >= tau) & (flat > min_score))
        k, j, i = np.unravel_index(idx, volume.shape)
        s = flat[idx]
        peak = _local_max(volume, k, j, i, s)
        k, j, i, s = k[peak], j[peak], i[peak], s[peak]
        order = np.argsort(-s, kind="stable")
        yaw_all = yaws[k[order]]
        t_all = np.c_[(i[order] - n) * res, (j[order] - m_y) * res]
        s_all = s[order]
        chosen = _choose(yaw_all, t_all, top_k, nms_xy_m, nms_yaw_rad, diverse_yaw_rad, complete)
        if chosen is not None:
            break
        m = min(flat.size, 8 * m)
    chosen.sort(key=lambda o: -s_all[o])
    return [Hypothesis(float(yaw_all[o]), t_all[o].copy(), float(s_all[o])) for o in chosen]


def _mth_largest(flat: F32, m: int, sample_every: int = 0) -> float:
    """The ``m``-th largest value of ``flat`` (1-D, finite), ``np.partition``'s
    ``flat[flat.size - m]`` after the partition, with a partition of a small part only: a
    strided sample (every ``sample_every``-th value; 0: about 64 ``m`` values in all) gives a
    value ``q`` whose share of the sample above it is about 2 ``m`` of the whole, and when at
    least ``m`` values of ``flat`` are ``>= q`` the ``m``-th largest is among them (the ``m``
    largest values are all ``>= q``). Otherwise the whole array is partitioned."""
    step = sample_every if sample_every > 0 else max(1, flat.size // (64 * m))
    if step > 1:
        sample = flat[::step]
        k = (2 * m) // step + 1
        if k < sample.size:
            q = sample[np.argpartition(sample, sample.size - k)[sample.size - k]]
            sub = flat[flat >= q]
            if sub.size >= m:
                return float(np.partition(sub, sub.size - m)[sub.size - m])
    return float(np.partition(flat, flat.size - m)[flat.size - m])


def _local_max(volume: F32, k: NDArray[np.int64], j: NDArray[np.int64], i: NDArray[np.int64],
               s: F32) -> NDArray[np.bool_]:
    """(C,) whether each cell ``(k, j, i)`` of ``volume`` (value ``s``) is at least every
    neighbour of its 3 x 3 x 3 neighbourhood, indices clipped at the borders (as
    ``scipy.ndimage.maximum_filter(volume, 3, mode="nearest")``)."""
    shape = volume.shape
    out = np.ones(len(s), dtype=bool)
    for dk in (-1, 0, 1):
        k2 = np.clip(k + dk, 0, shape[0] - 1)
        for dj in (-1, 0, 1):
            j2 = np.clip(j + dj, 0, shape[1] - 1)
            for di in (-1, 0, 1):
                if dk or dj or di:
                    out &= s >= volume[k2, j2, np.clip(i + di, 0, shape[2] - 1)]
    return out


def _choose(yaw_all: NDArray[np.float64], t_all: NDArray[np.float64], top_k: int,
            nms_xy_m: float, nms_yaw_rad: float, diverse_yaw_rad: float, complete: bool
            ) -> list[int] | None:
    """The two passes of :func:`top_hypotheses` over peaks sorted best first (yaws (P,),
    translations (P, 2)); None when a pass runs out of peaks and the list is not ``complete``
    (more peaks, all worse, may follow)."""

    def wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.abs(np.arctan2(np.sin(a), np.cos(a)))

    chosen: list[int] = []
    need = max(top_k // 2, 1)
    for o in range(len(yaw_all)):  # pass 1: one per yaw mode
        if len(chosen) >= need:
            break
        if not chosen or wrap(yaw_all[chosen] - yaw_all[o]).min() >= diverse_yaw_rad:
            chosen.append(o)
    if len(chosen) < need and not complete:
        return None
    for o in range(len(yaw_all)):  # pass 2: fill with the best remaining distinct peaks
        if len(chosen) >= top_k:
            break
        if o in chosen:
            continue
        c = np.asarray(chosen, dtype=np.int64)
        same = ((wrap(yaw_all[c] - yaw_all[o]) < nms_yaw_rad)
                & (np.linalg.norm(t_all[c] - t_all[o], axis=1) < nms_xy_m))
        if not same.any():
            chosen.append(o)
    if len(chosen) < top_k and not complete:
        return None
    return chosen

